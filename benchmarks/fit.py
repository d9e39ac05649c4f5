"""Evidence fitting at inference (``--fit``): accuracy and completeness on synthetic test sets, fidelity on real
observations, CPU seconds per scan, with and without the fit, one thread.

Synthetic sets (``--synthetic NAME=FILE.h5``, a ``spotlights dataset build`` file): the first ``--max-views``
views of every model of ``--split``, completed by the default model as ``spotlights evaluate`` does (no box
clip), each with the dataset's sensor origin; scored against the dense ground truth (accuracy, completeness,
CD-L1, F@0.01) and fidelity to the partial. Real sets (``--real NAME=FILE.h5``, a ``spotlights real extract``
file): every observation completed as ``real complete`` does (:func:`spotlights.learning.inference.complete_in_boxes`:
each box clipped, every class by the one model), fidelity per observation -> mean per track (an untracked
observation is its own track) -> per class -> mean over classes (``average``), and the mean over observations.
Consistency at equal density as ``real evaluate`` scores it: each completion voxel-downsampled (cell 0.1, unit
frame), two-sided Chamfer of consecutive observations of a track (object frame / the track's mean box radius) ->
track -> class -> mean over classes. CPU: ``time.process_time`` of the completion calls (the fit: evidence, steps and gate), per scan::

    spotlights dataset build --meshes ../shared/data/meshes/apolloscape-cars --views 20 --split 64/8/7 \\
        --rig box-128x128-ellipsoid-s1 --seed 0 --out cars20.h5
    spotlights dataset build --meshes ../shared/data/meshes/kenney-vehicles,manifest=src/spotlights/assets/manifests/kenney-vehicles.csv,split=test \\
        --views 20 --rig box-128x128-ellipsoid-s1 --seed 0 --out kenney20.h5
    spotlights real extract ../shared/data/lidar/nuscenes --format nuscenes \\
        --classes car,truck,caravan,trailer,bus,construction,emergency --out nuscenes.h5
    spotlights real extract ../shared/data/lidar/argoverse2 --format av2 \\
        --classes car,truck,caravan,trailer,bus,construction,emergency --out av2.h5
    OMP_NUM_THREADS=1 python benchmarks/fit.py --synthetic apollo-test=cars20.h5 kenney=kenney20.h5 \\
        --real nuscenes=nuscenes.h5 av2=av2.h5 --max-views 10 \\
        --frame ../shared/data/lidar/kitti-object/training-fov-cropped 002155 --json docs/results/fit/fit.json

The settings were chosen on the validation cars (``--split val --max-views 3``, the rows of ``--variant``)::

    OMP_NUM_THREADS=1 python benchmarks/fit.py --synthetic apollo-val=cars20.h5 --split val --max-views 3 \\
        --variant steps16:steps=16 --variant rings0:rings=0 --variant rings2:rings=2 \\
        --variant large-steps:learning_rate=0.01,code_learning_rate=0.01 --json docs/results/fit/fit_val.json

``--frame ROOT ID``: also a whole KITTI frame completed with and without the fit (``complete_scene``, the class
model as fallback), median wall and CPU seconds of ``--repeats`` runs, one thread.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from spotlights.data.real.extract import read_observations
from spotlights.geometry.sampling import voxel_downsample
from spotlights.learning.data import TorchCompletionDataset
from spotlights.learning.fit import FitSettings, fit_completions
from spotlights.learning.inference import complete_in_boxes, load_completer
from spotlights.metrics.completion import evaluate_completions
from spotlights.metrics.consistency import aggregate, fidelity, track_consistency

BATCH = 16
VOXEL = 0.1
"""Cell side (unit frame) of the equal-density consistency, as ``real evaluate``'s default."""


def _r(x: float) -> float:
    return round(float(x), 5)


def synthetic(completer, path: str, split: str, max_views: int, fits: dict) -> dict:
    """The rows ``without`` and one per entry of ``fits`` ({row name: FitSettings})."""
    ds = TorchCompletionDataset(path, split, rig=False, max_views=max_views, partials_in_memory=True)
    dense = ds.gt_dense()
    clouds: dict = {"without": [], **{k: [] for k in fits}}
    cpu = dict.fromkeys(clouds, 0.0)
    kept: dict = {k: [] for k in fits}
    parts: list = []
    for batch in DataLoader(ds, batch_size=BATCH, shuffle=False):
        part = batch["partial"].numpy()
        parts += list(part)
        ext = ds.extents[batch["model"].numpy()]
        t0 = time.process_time()
        with torch.inference_mode():
            clouds["without"] += completer.complete(part, extents=ext)
        cpu["without"] += time.process_time() - t0
        for name, settings in fits.items():
            t0 = time.process_time()
            res = fit_completions(completer, part, ext, batch["sensor_origin"].numpy(), settings=settings)
            cpu[name] += time.process_time() - t0
            clouds[name] += res.clouds
            kept[name] += list(res.fitted)
    out: dict = {"scans": len(parts), "models": int(len(np.unique(ds.sample_models)))}
    for name, preds in clouds.items():
        per = evaluate_completions(preds, ds.sample_models, dense, 0.01, True, {})
        out[name] = {m: _r(np.nanmean(per[m])) for m in ("accuracy", "completeness", "chamfer_l1", "fscore")}
        out[name]["fidelity"] = _r(np.nanmean([fidelity(p, c) if len(c) else np.nan for p, c in zip(parts, preds)]))
        out[name]["cpu_s_per_scan"] = _r(cpu[name] / len(parts))
        if name in kept:
            out[name]["fit_kept_share"] = _r(np.mean(kept[name]))
    return out


def parse_variant(text: str) -> tuple[str, FitSettings]:
    """``NAME:key=value,key=value`` -> (NAME, FitSettings with those fields; ints stay ints)."""
    name, _, items = text.partition(":")
    fields: dict = {}
    for item in filter(None, items.split(",")):
        key, value = item.split("=", 1)
        fields[key] = int(value) if value.lstrip("-").isdigit() else float(value)
    return name, FitSettings(**fields)


def _class_average(fid: np.ndarray, tracks: list, classes: list) -> tuple[dict, float]:
    per_track: dict = defaultdict(list)
    for v, t, c in zip(fid, tracks, classes):
        per_track[(c, t)].append(v)
    per_class: dict = defaultdict(list)
    for (c, _), vals in per_track.items():
        per_class[c].append(np.mean(vals))
    cls = {c: _r(np.mean(v)) for c, v in sorted(per_class.items())}
    return cls, _r(np.mean(list(cls.values())))


def real(completer, path: str, settings: FitSettings) -> dict:
    obs = read_observations(path)
    n = len(obs)
    tracks = [f"{s}/{t}" if t else f"obs{i}" for i, (s, t) in enumerate(zip(obs.sequence, obs.track_id))]
    out: dict = {"observations": n, "classes": dict(sorted({c: obs.cls.count(c) for c in set(obs.cls)}.items()))}
    kept: list = []
    for name, fit in (("without", None), ("with", settings)):
        comps: list = []
        cpu = 0.0
        for s in range(0, n, BATCH):
            rows = slice(s, s + BATCH)
            t0 = time.process_time()
            comps += complete_in_boxes(
                completer,
                obs.partial[rows],
                obs.box_size[rows],
                sensor_origins=obs.sensor_origin[rows],
                classes=obs.cls[rows],
                fit=fit,
                fitted=kept if fit is not None else None,
            )
            cpu += time.process_time() - t0
        fid = np.array([fidelity(p, c) if len(c) else np.nan for p, c in zip(obs.partial, comps)])
        per_class, average = _class_average(fid, tracks, obs.cls)
        radii = np.linalg.norm(obs.box_size, axis=1) / 2.0
        voxels = [voxel_downsample(c, VOXEL) if len(c) else c for c in comps]
        agg = aggregate(track_consistency(voxels, tracks, obs.timestamp, obs.cls, radii))
        out[name] = {
            "fidelity_average": average,
            "fidelity_per_class": per_class,
            "fidelity_mean_over_observations": _r(np.nanmean(fid)),
            "consistency_voxel_average": _r(agg["average"]["cd"]),
            "consistency_voxel_per_class": {c: _r(e["cd"]) for c, e in agg["classes"].items() if e["cd"] is not None},
            "tracks_scored": agg["all_objects"]["n_objects"],
            "cpu_s_per_scan": _r(cpu / n),
        }
    out["fit_kept_share"] = _r(np.mean(kept))
    out["sensor_known_share"] = _r(np.mean(np.all(np.isfinite(obs.sensor_origin), axis=1)))
    return out


def frame(root: str, frame_id: str, settings: FitSettings, repeats: int) -> dict:
    """A whole KITTI frame (``root``/velodyne_reduced, label_2, calib) completed by :func:`complete_scene` with and
    without the fit (the default model, the class model as fallback, as ``complete``): median wall and CPU seconds
    of ``repeats`` runs after a warm-up, one thread."""
    import statistics

    from spotlights.completion.frame import SceneConfig, complete_scene
    from spotlights.data.real.boxfiles import read_box_file
    from spotlights.data.real.scans import read_scan

    base = Path(root)
    points = read_scan(base / "velodyne_reduced" / f"{frame_id}.bin")
    boxes = read_box_file(base / "label_2" / f"{frame_id}.txt", calib=base / "calib" / f"{frame_id}.txt").boxes
    completer, fallback = load_completer("default", device="cpu"), load_completer("classes", device="cpu")
    out: dict = {"frame": f"kitti-object/training-fov-cropped {frame_id}"}
    for name, config in (("without", SceneConfig()), ("with", SceneConfig(fit=True, fit_steps=settings.steps))):
        wall, cpu = [], []
        for k in range(repeats + 1):
            t0, c0 = time.perf_counter(), time.process_time()
            result = complete_scene(points, boxes, completer, config, fallback=fallback, fallback_name="classes")
            if k:  # the first run warms up
                wall.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
        out[name] = {
            "completed": len(result.completed),
            "fitted": sum(bool(o.fitted) for o in result.completed),
            "wall_s": _r(statistics.median(wall)),
            "cpu_s": _r(statistics.median(cpu)),
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--synthetic", nargs="*", default=[], metavar="NAME=FILE.h5")
    ap.add_argument("--real", nargs="*", default=[], metavar="NAME=FILE.h5")
    ap.add_argument("--split", default="test")
    ap.add_argument("--max-views", type=int, default=10)
    ap.add_argument("--steps", type=int, default=FitSettings().steps)
    ap.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="NAME:KEY=VALUE,...",
        help="synthetic sets: also the fit with these FitSettings fields (row 'NAME')",
    )
    ap.add_argument("--frame", nargs=2, default=None, metavar=("KITTI_ROOT", "FRAME"))
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", required=True)
    args = ap.parse_args()
    torch.set_num_threads(1)
    completer = load_completer("default", device="cpu")
    settings = FitSettings(steps=args.steps)
    result: dict = {
        "checkpoint": "default",
        "threads": 1,
        "fit": {k: getattr(settings, k) for k in settings.__dataclass_fields__},
        "synthetic": {},
        "real": {},
    }
    result["synthetic_views_per_model"] = args.max_views
    result["synthetic_split"] = args.split
    result["variants"] = list(args.variant)
    for item in args.synthetic:
        name, path = item.split("=", 1)
        fits = {"with": settings, **dict(parse_variant(v) for v in args.variant)}
        result["synthetic"][name] = synthetic(completer, path, args.split, args.max_views, fits)
        print(name, json.dumps(result["synthetic"][name]), flush=True)
    for item in args.real:
        name, path = item.split("=", 1)
        result["real"][name] = real(completer, path, settings)
        print(name, json.dumps(result["real"][name]), flush=True)
    if args.frame is not None:
        result["frame"] = frame(args.frame[0], args.frame[1], settings, args.repeats)
        print("frame", json.dumps(result["frame"]), flush=True)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
