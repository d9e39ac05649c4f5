"""Benchmark of the encode path (issue 2).

Measured side by side in one run (the machine is shared and noisy, so compare
ratios, not absolute numbers):

* the whole ``MeshProbe.encode`` path (rig rays, Embree call, chord test,
  normalisation to depths) against a bare ``embreex`` scene call on the same
  rays and the same BVH, for 2,048 / 8,192 / 32,768 rays on a ~5k-face car and a
  ~190k-face chair (PartNet) -- BVH build excluded from both, reported apart;
* Open3D's ``RaycastingScene`` (multi-threaded Embree) on the same rays, when
  Open3D is installed;
* encoding all 79 ApolloScape cars at 32 x 64 / 60 degrees (loading included,
  reported apart), with 1 and 2 worker processes.

Timings are medians of round-robin repeats (each repeat times every\nengine once), so a load change on the shared machine hits all of them alike.

Usage: ``python benchmarks/encode.py [--repeat 20] [--json docs/results/bench_encode.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from spotlights.geometry import MeshProbe, load_mesh, make_rig
from spotlights.geometry.encode import encode_mesh_files

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("SPOTLIGHTS_SHARED", ROOT.parent / "shared")) / "data" / "meshes"
CAR = SHARED / "apolloscape-cars" / "sedan" / "037-CAR02.ply"
BIG = SHARED / "categories" / "chair" / "partnet_chair_40096_7f539a84.ply"
RIGS = {2048: (32, 64), 8192: (64, 128), 32768: (128, 256)}


def interleaved(fns: dict, repeat: int) -> dict:
    """Median wall time (s) of each callable, timed round-robin so load changes hit all alike.

    Each repeat runs every callable once, in an order rotated per repeat; one warm-up first.
    """
    for fn in fns.values():
        fn()
    names = list(fns)
    times = {n: [] for n in names}
    for r in range(repeat):
        for n in names[r % len(names):] + names[: r % len(names)]:
            t0 = time.perf_counter()
            fns[n]()
            times[n].append(time.perf_counter() - t0)
    return {n: statistics.median(t) for n, t in times.items()}


def bench_mesh(path: Path, repeat: int) -> list[dict]:
    mesh = load_mesh(path)
    t0 = time.perf_counter()
    probe = MeshProbe(mesh)
    build = time.perf_counter() - t0
    scene = probe.caster._scene
    probe2 = MeshProbe(mesh, workers=2)  # one query split over 2 processes (>= PARALLEL_MIN_RAYS rays)
    try:
        import open3d as o3d

        o3d_scene = o3d.t.geometry.RaycastingScene()
        o3d_scene.add_triangles(
            o3d.core.Tensor(probe.normalization.to_unit(mesh.vertices).astype(np.float32)),
            o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
        )
    except ImportError:
        o3d_scene = None
    rows = []
    for n_rays, (n, m) in RIGS.items():
        rig = make_rig(n, m, 60)
        o32 = rig.origins.astype(np.float32)
        d32 = rig.directions.astype(np.float32)
        fns = {"path": lambda: probe.encode(rig), "bare": lambda: scene.run(o32, d32, output=1),
               "path2": lambda: probe2.encode(rig)}
        if o3d_scene is not None:
            rays = o3d.core.Tensor(np.concatenate([o32, d32], axis=1))
            fns["open3d"] = lambda: o3d_scene.cast_rays(rays)["t_hit"].numpy()
        t = interleaved(fns, repeat)
        row = {
            "mesh": path.name, "faces": int(len(mesh.faces)), "rays": n_rays, "bvh_build_s": build,
            "encode_path_mrays_s": n_rays / t["path"] / 1e6, "bare_embree_mrays_s": n_rays / t["bare"] / 1e6,
            "path_over_bare": t["bare"] / t["path"],
            "encode_path_2proc_mrays_s": n_rays / t["path2"] / 1e6,
        }
        if "open3d" in t:
            row["open3d_mrays_s"] = n_rays / t["open3d"] / 1e6
            row["path_over_open3d"] = t["open3d"] / t["path"]
            row["path2_over_open3d"] = t["open3d"] / t["path2"]
        rows.append(row)
    return rows


def bench_cars(workers: int) -> dict:
    files = sorted((SHARED / "apolloscape-cars").glob("*/*.ply"))
    rig = make_rig(32, 64, 60)
    t0 = time.perf_counter()
    meshes = [load_mesh(f) for f in files]
    t_load = time.perf_counter() - t0
    from spotlights.geometry import encode_meshes

    t0 = time.perf_counter()
    encode_meshes(meshes, rig)
    t_encode = time.perf_counter() - t0
    t0 = time.perf_counter()
    depths = encode_mesh_files(files, [rig], workers=workers)
    t_files = time.perf_counter() - t0
    return {"meshes": len(files), "workers": workers, "load_s": t_load, "encode_loaded_s": t_encode,
            "load_and_encode_files_s": t_files, "mean_hit_ratio": float((depths[rig.name] > 0).mean())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--json", default=str(ROOT / "docs" / "results" / "bench_encode.json"))
    args = ap.parse_args()
    if not CAR.exists():
        print(f"shared data not found under {SHARED}; set SPOTLIGHTS_SHARED", file=sys.stderr)
        return 2
    rows = bench_mesh(CAR, args.repeat) + (bench_mesh(BIG, args.repeat) if BIG.exists() else [])
    print(f"{'mesh':34s} {'faces':>7s} {'rays':>6s} {'path Mr/s':>9s} {'bare Mr/s':>9s} {'path/bare':>9s} "
          f"{'2proc Mr/s':>10s} {'o3d Mr/s':>9s}")
    for r in rows:
        print(f"{r['mesh']:34s} {r['faces']:7d} {r['rays']:6d} {r['encode_path_mrays_s']:9.2f} "
              f"{r['bare_embree_mrays_s']:9.2f} {r['path_over_bare']:9.2f} {r['encode_path_2proc_mrays_s']:10.2f} "
              f"{r.get('open3d_mrays_s', float('nan')):9.2f}")
    cars = [bench_cars(w) for w in (1, 2)]
    for c in cars:
        print(f"79 cars, 32x64/60deg, workers={c['workers']}: load {c['load_s']:.2f} s, encode (loaded) "
              f"{c['encode_loaded_s']:.2f} s, load+encode from files {c['load_and_encode_files_s']:.2f} s")
    out = {"python": platform.python_version(), "cpus": os.cpu_count(), "machine": platform.machine(),
           "repeat": args.repeat, "rays": rows, "cars": cars}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2))
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
