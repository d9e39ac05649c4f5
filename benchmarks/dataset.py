"""Benchmark of the synthetic dataset build: samples/s, where the time goes, disk size.

Two measurements in one run (the machine is shared: the load average is printed
before and after; compare ratios, not absolute numbers across runs):

1. **Stage profile** (one process, one car): seconds per view spent drawing the
   pose and building the window's rays, in the Embree call, on returns (ground,
   dropout, noise), and resampling to 256 points; seconds per model for the ground
   truth (2,048 + 16,384 surface samples and each rig); seconds per shard write.
2. **Real build** of ``--models`` cars x ``--views`` views with ``--workers``
   processes through :func:`spotlights.data.synthetic.build_dataset` (the CLI's
   code path), split into the parallel units phase and the HDF5 consolidation.

From (2) it extrapolates the paper-scale set (79 models x 2,000 views = 158,000
samples): time = 158,000 / (samples/s of the units phase) + 158,000 / (samples/s
of the consolidation), and the file size from the bytes per sample.

Usage: ``python benchmarks/dataset.py [--models 5] [--views 200] [--workers 2] [--json out.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from spotlights.data.lidar import LidarSimulator
from spotlights.data.synthetic import (BuildConfig, save_npz_atomic, build_dataset, discover_models, load_model,
                                       model_ground_truth, simulate_views)
from spotlights.timing import StageTimer

ROOT = Path(__file__).resolve().parents[1]
CARS = Path(os.environ.get("SPOTLIGHTS_SHARED", ROOT.parent / "shared")) / "data" / "meshes" / "apolloscape-cars"
PAPER_MODELS, PAPER_VIEWS = 79, 2000


def pick_models(root: Path, n: int) -> list[str]:
    """``n`` mesh files spread evenly over the sorted list (so every category is represented)."""
    entries, _ = discover_models(root)
    idx = np.linspace(0, len(entries) - 1, n).round().astype(int)
    return [entries[i].file for i in idx]


def stage_profile(root: Path, file: str, cfg: BuildConfig, views: int) -> dict:
    entries, _ = discover_models(root)
    entry = next(e for e in entries if e.file == file)
    model = load_model(root, entry)
    t0 = time.perf_counter()
    gt = model_ground_truth(model, cfg)
    t_gt = time.perf_counter() - t0
    sim = LidarSimulator(model.vertices, model.faces, cfg.sensor_model)
    simulate_views(sim, model, cfg, range(5))  # warm-up
    tm = StageTimer()
    with tm("views"):
        arrays = simulate_views(sim, model, cfg, range(views), tm)
    t_views = tm.seconds["views"]
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        save_npz_atomic(Path(tmp) / "shard.npz", arrays)
        t_write = time.perf_counter() - t0
    per = {k: tm.seconds[k] / views * 1e3 for k in ("rays", "cast", "returns", "resample")}
    per["other"] = t_views / views * 1e3 - sum(per.values())
    return {
        "model": file, "views": views, "ms_per_view": t_views / views * 1e3, "ms_per_view_by_stage": per,
        "draws_per_view": float(arrays["n_draws"].sum()) / views, "mean_rays_per_view": float(arrays["n_rays"].mean()),
        "mean_returns_per_view": float(arrays["n_raw"].mean()),
        "ground_truth_s_per_model": t_gt, "rigs": cfg.rigs and [r.name for r in cfg.rigs],
        "shard_write_ms_per_view": t_write / views * 1e3, "gt_hit_ratio": float((gt["depths"][0] > 0).mean()),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", type=Path, default=CARS)
    ap.add_argument("--models", type=int, default=5)
    ap.add_argument("--views", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--rig", action="append", default=["64x32@60", "256x64@60"], help="extra rigs (as the ablation)")
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    ap.add_argument("--keep", type=Path, default=None, help="keep the built file here instead of a temporary folder")
    args = ap.parse_args(argv)
    if not args.meshes.exists():
        print(f"benchmark skipped: {args.meshes} is not available", file=sys.stderr)
        return 0
    load_before = os.getloadavg()
    files = pick_models(args.meshes, args.models)
    cfg = BuildConfig(meshes=str(args.meshes), views=args.views, extra_rigs=list(args.rig)).validate()
    print(f"machine: {os.cpu_count()} cores, load average {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}")
    prof = stage_profile(args.meshes, files[0], cfg, min(args.views, 300))
    print(f"stage profile ({prof['model']}, {prof['views']} views, 1 process): {prof['ms_per_view']:.2f} ms/view = "
          + ", ".join(f"{k} {v:.2f}" for k, v in prof["ms_per_view_by_stage"].items())
          + f" ms; {prof['mean_rays_per_view']:.0f} rays and {prof['mean_returns_per_view']:.0f} returns per view, "
          f"{prof['draws_per_view']:.3f} draws/view; shard write {prof['shard_write_ms_per_view']:.3f} ms/view; "
          f"ground truth {prof['ground_truth_s_per_model']:.2f} s/model ({', '.join(prof['rigs'])})")

    work = Path(tempfile.mkdtemp(prefix="spotlights-bench-"))
    try:
        sub = work / "meshes"
        for f in files:
            (sub / f).parent.mkdir(parents=True, exist_ok=True)
            (sub / f).symlink_to((args.meshes / f).resolve())
        n = len(files)
        split = f"{max(n - 2, 1)}/{1 if n > 1 else 0}/{1 if n > 2 else 0}"
        bcfg = BuildConfig(meshes=str(sub), views=args.views, split=split, extra_rigs=list(args.rig))
        out = (args.keep or work / "bench.h5")
        t0 = time.perf_counter()
        rep = build_dataset(bcfg, out, workers=args.workers, overwrite=True, progress=False, log=lambda m: None)
        wall = time.perf_counter() - t0
        samples = rep.n_samples
        with __import__("h5py").File(out, "r") as h:
            partial_bytes = h["samples/partial"].id.get_storage_size()
            model_bytes = sum(h[k].id.get_storage_size() for k in ("models/gt_points", "models/gt_dense"))
            model_bytes += sum(h[f"rigs/{r}/depths"].id.get_storage_size() for r in h["rigs"])
        size = rep.file_size
        per_sample = (size - model_bytes) / samples
        rate_units = samples / rep.seconds_units
        rate_cons = samples / rep.seconds_consolidate
        full = PAPER_MODELS * PAPER_VIEWS
        est = full / rate_units + full / rate_cons
        est_size = per_sample * full + model_bytes / n * PAPER_MODELS
        load_after = os.getloadavg()
        res = {
            "machine": {"cores": os.cpu_count(), "load_before": load_before, "load_after": load_after},
            "stage_profile": prof,
            "build": {
                "models": n, "views": args.views, "samples": samples, "workers": args.workers,
                "rigs": [r.name for r in bcfg.validate().rigs], "wall_s": wall,
                "units_s": rep.seconds_units, "consolidate_s": rep.seconds_consolidate,
                "samples_per_s_units": rate_units, "samples_per_s_consolidate": rate_cons,
                "samples_per_s_overall": samples / wall, "file_bytes": size,
                "partial_bytes_stored": partial_bytes, "bytes_per_sample": per_sample,
                "partial_compression_ratio": samples * 256 * 3 * 4 / partial_bytes,
            },
            "paper_scale_estimate": {"samples": full, "minutes": est / 60, "file_gib": est_size / 2**30},
        }
        b = res["build"]
        print(f"build {n} models x {args.views} views, {args.workers} workers: {wall:.1f} s wall "
              f"(units {rep.seconds_units:.1f} s = {rate_units:.0f} samples/s, consolidation {rep.seconds_consolidate:.1f} s "
              f"= {rate_cons:.0f} samples/s); file {size / 2**20:.1f} MiB, {per_sample:.0f} B/sample "
              f"(partials compress {b['partial_compression_ratio']:.2f}x)")
        print(f"paper scale ({PAPER_MODELS} x {PAPER_VIEWS} = {full} samples): ~{est / 60:.1f} min, ~{est_size / 2**30:.2f} GiB "
              f"(load average now {load_after[0]:.2f})")
        if args.json:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(res, indent=1))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
