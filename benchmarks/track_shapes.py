"""A shape per track (``real complete --fuse all|past:K --track-shape``): consistency, fidelity and accuracy.

**Real scene** (default: the shared nuScenes scene-0523, 40 LIDAR_TOP keyframes), boxes from two sources:

* ``labels``: the annotated vehicle boxes (their instance tokens are the track ids);
* ``detections``: :func:`spotlights.tracking.simulate.simulate_detections` from those labels (10% of the detectable
  boxes missed, 10% false positives with low scores, 0.15 m / 3 degree / 5% size noise, seed 0; as
  ``benchmarks/tracker.py``), the vehicle classes kept (any score), tracked by
  :func:`spotlights.tracking.track_boxes` with its default settings (tracker ids).

Each is completed in eight ways, as ``real complete``'s frame loop does (no files): ``frame`` (``--fuse none``:
every frame alone), ``past:5`` and ``all`` (``--fuse``), ``shape all`` and ``shape past:5`` (``--fuse ...
--track-shape``), and ``all``, ``shape all``, ``shape past:5`` with ``refined`` boxes (``--refine-boxes``). Tracks are let through with any gap between their frames (a tracker's
track may skip more than ``--max-gap``'s 2 s). On the observations (frame, box) with a track id completed by all
of them: **consistency** between consecutive completions of each track (:func:`spotlights.metrics.consistency.
track_consistency`: two-sided unsquared Chamfer ``cd``; each completion a seeded 2,048-point subset, in the box
frame of its (unturned) box; track-normalised by the mean half diagonal, and in metres; mean over the tracks,
``all_objects``) and **fidelity** (:func:`spotlights.metrics.consistency.fidelity`: each frame's own points to the
completion, that box's unit frame; mean over each track's observations, then over the tracks). CPU seconds of each
frame loop (this process, one torch thread).

**Simulated sequences with ground-truth shapes** (:func:`spotlights.data.synthetic.sequences.simulate_sequence`,
the paper split's ``--split`` cars, ``--frames`` at ``--hz``, ``hdl32e``; as ``benchmarks/track_sequences.py``)
with their **true boxes**: accuracy and completeness (metres, true box frame, against ``--gt-points`` points on
the mesh) of each frame completed alone (``frame``) and of the track's one shape (``shape all``), and the
representation's floor (the mesh's own depths on the model's rig, decoded: ``truth_floor`` of
``benchmarks/track_sequences.py``). ``gap_closed`` = (frame - shape) / (frame - floor).

``--maker-box own`` makes each shape in the making frame's own box instead of one of the track's median size (the
comparison; ``--skip-sequences``: true boxes have one size)::

    OMP_NUM_THREADS=1 nice -n 10 python benchmarks/track_shapes.py --maker-box own --skip-sequences \
        --json docs/results/tracking/track_shapes_own_box.json

Usage::

    OMP_NUM_THREADS=1 nice -n 10 python benchmarks/track_shapes.py --json docs/results/tracking/track_shapes.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from spotlights.completion.detections import TrackedReader
from spotlights.completion.frame import SceneConfig, complete_scene
from spotlights.completion.fusion import TrackPlan
from spotlights.data.real.base import CLASSES, Frame
from spotlights.data.real.nuscenes import NuScenesReader
from spotlights.data.tracks import parse_window
from spotlights.learning.inference import load_completer
from spotlights.metrics.consistency import aggregate, fidelity, track_consistency
from spotlights.tracking.detections import filter_detections
from spotlights.tracking.simulate import DetectorModel, nuscenes_ground_truth, simulate_detections
from spotlights.tracking.tracker import track_boxes

HERE = Path(__file__).resolve().parent
SHARED = Path(os.environ.get("SPOTLIGHTS_SHARED", HERE.parents[1] / "shared")) / "data"
NUSCENES = SHARED / "lidar" / "nuscenes"
MESHES = SHARED / "meshes" / "apolloscape-cars"
MODES = (
    "frame",
    "past:5",
    "all",
    "shape all",
    "shape past:5",
    "all refined",
    "shape all refined",
    "shape past:5 refined",
)
SAMPLE = 2048


def sample(points: np.ndarray) -> np.ndarray:
    """A seeded subset of at most :data:`SAMPLE` rows (the same rows of the same array every time)."""
    if len(points) <= SAMPLE:
        return points
    return points[np.sort(np.random.default_rng(0).choice(len(points), SAMPLE, replace=False))]


def complete_all(reader, keys, completer, mode: str, config: SceneConfig) -> tuple[dict, float, int | None]:
    """{(frame key, box index): (frame's box, scan-frame completion, own points, timestamp s)} of the tracked
    boxes completed in ``mode``, the loop's CPU seconds and, with a shape per track, the tracks split by size."""
    out: dict = {}
    c0 = time.process_time()
    plan = None
    if mode != "frame":
        words = mode.split()
        window = parse_window(next(w for w in words if w not in ("shape", "refined")))
        plan = TrackPlan(window, config, "refined" in words, max_gap_s=None, track_shape="shape" in words)
        plan.build(reader, keys)
    for key in keys:
        frame = reader.load(key) if plan is None else (plan.take(key) or reader.load(key))
        boxes, extra = (frame.boxes, None) if plan is None else plan.frame_inputs(key, frame.boxes)
        result = complete_scene(frame.points, boxes, completer, config, extra_points=extra)
        if plan is not None:
            plan.place_shapes(key, result)
            plan.record(key, result)
        for o in result.completed:
            if o.box.track_id:
                out[(key, o.index)] = (o.box, o.completion, result.points[o.input_indices], frame.timestamp)
    splits = None if plan is None or plan.shapes is None else plan.n_size_splits
    return out, time.process_time() - c0, splits


def scores(rows: list) -> dict:
    """Consistency (2,048-point Chamfer, box frame) and fidelity of observations ``rows`` (box, completion, own
    points, timestamp)."""
    comps, keys, ts, classes, radii, fid = [], [], [], [], [], []
    for box, comp, own, t in rows:
        r = box.radius
        comps.append(sample(box.to_object(comp)) / r)
        keys.append(box.track_id)
        ts.append(t)
        classes.append(box.cls)
        radii.append(r)
        fid.append(fidelity(box.to_unit(own), box.to_unit(comp)))
    tracks = track_consistency(comps, keys, ts, classes, radii, per_observation={"fidelity": fid})
    agg = aggregate(tracks)["all_objects"]
    return dict(
        consistency_cd=agg["cd"],
        consistency_cd_m=agg["cd_m"],
        fidelity=agg["fidelity"],
        fidelity_mean_over_observations=float(np.nanmean(fid)),
        n_tracks=agg["n_objects"],
        n_pairs=agg["n_pairs"],
    )


def real_scene(args, completer, config) -> dict:
    base = NuScenesReader(Path(args.data))
    keys = base.frame_keys()
    truth, counts = nuscenes_ground_truth(base)
    model = DetectorModel()
    dets, _ = simulate_detections(truth, counts, model, seed=args.seed)
    dets, _ = filter_detections(dets, 0.0, CLASSES)
    tracked = track_boxes(dets)
    readers = {
        "labels": base,
        "detections": TrackedReader(base, {(f.sequence, f.frame_id): f.boxes for f in tracked}, "simulated"),
    }
    report: dict = {}
    for source, reader in readers.items():
        kept, cpu, splits = {}, {}, {}
        for mode in MODES:
            kept[mode], cpu[mode], splits[mode] = complete_all(reader, keys, completer, mode, config)
            print(f"{source} {mode}: {len(kept[mode])} completions, {cpu[mode]:.1f} CPU s", file=sys.stderr, flush=True)
        common = sorted(set.intersection(*(set(v) for v in kept.values())))
        per = {mode: scores([kept[mode][k] for k in common]) | {"cpu_s": cpu[mode]} for mode in MODES}
        for mode in MODES:
            per[mode] |= {"n_completed": len(kept[mode])}
            if splits[mode] is not None:
                per[mode]["n_size_splits"] = splits[mode]
        ref = per["frame"]
        for mode in MODES:
            per[mode]["consistency_over_frame"] = per[mode]["consistency_cd"] / ref["consistency_cd"]
            per[mode]["fidelity_over_frame"] = per[mode]["fidelity"] / ref["fidelity"]
        report[source] = dict(n_observations=len(common), modes=per)
    report["detector_model"] = dataclasses.asdict(model) | {"seed": args.seed}
    return report


class MemoryReader:
    """Frames held in memory, read like a generic dataset (timestamps in seconds)."""

    format = "generic"
    root = ""

    def __init__(self, frames: dict) -> None:
        self.frames = frames

    def frame_keys(self) -> list:
        return list(self.frames)

    def load(self, key) -> Frame:
        return self.frames[key]


def sequences(args, completer, config) -> dict:
    sys.path.insert(0, str(HERE))
    from spotlights.geometry.distances import accuracy, completeness
    from spotlights.learning.fused import paper_split_meshes
    from track_sequences import simulated_sequence, truth_floor

    meshes = paper_split_meshes(args.meshes, args.split)[: args.n]
    rig = getattr(completer, "rig", None)
    rows = []
    for i, m in enumerate(meshes):
        mesh, seq, gt = simulated_sequence(m, i, args.seed, "hdl32e", args.frames, args.hz, args.gt_points)
        name = f"seq{i:04d}"
        frames = {
            (name, f"{k:04d}"): Frame(name, f"{k:04d}", f["timestamp"], f["points"], [f["true_box"]])
            for k, f in enumerate(seq["frames"])
        }
        reader = MemoryReader(frames)
        keys = reader.frame_keys()
        row: dict = {"mesh": m.name}
        for mode in ("frame", "shape all"):
            kept, _, _ = complete_all(reader, keys, completer, mode, config)
            acc, comp = [], []
            for box, c, _, _ in kept.values():
                pred = box.to_object(c)  # the true box: its object frame is the truth's
                acc.append(accuracy(pred, gt))
                comp.append(completeness(pred, gt))
            row[mode] = dict(n=len(acc), accuracy_m=float(np.mean(acc)), completeness_m=float(np.mean(comp)))
        if rig is not None:
            fa, fc = truth_floor(mesh, seq["center_in_mesh"], seq["frames"][0]["true_box"].size, rig, gt)
            row["floor"] = dict(accuracy_m=fa, completeness_m=fc)
        rows.append(row)
        print(f"{m.name}: {json.dumps({k: v for k, v in row.items() if k != 'mesh'})}", file=sys.stderr, flush=True)
    mean = {
        mode: {k: float(np.mean([r[mode][k] for r in rows])) for k in ("accuracy_m", "completeness_m")}
        for mode in ("frame", "shape all", "floor")
        if all(mode in r for r in rows)
    }
    out = dict(meshes=[r["mesh"] for r in rows], frames=args.frames, hz=args.hz, per_mesh=rows, mean=mean)
    if "floor" in mean:
        for k in ("accuracy_m", "completeness_m"):
            f, s, lo = mean["frame"][k], mean["shape all"][k], mean["floor"][k]
            out[f"gap_closed_{k[:-2]}"] = (f - s) / (f - lo) if f != lo else None
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(NUSCENES), help="the nuScenes folder (default: the shared scene)")
    ap.add_argument("--checkpoint", default="default")
    ap.add_argument("--precision", default="fp32")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--meshes", default=str(MESHES))
    ap.add_argument("--split", default="test", choices=("train", "val", "test"))
    ap.add_argument("--n", type=int, default=7, help="simulated sequences (one per car of --split)")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--hz", type=float, default=2.0, help="frame rate (2: nuScenes keyframes)")
    ap.add_argument("--gt-points", type=int, default=20000)
    ap.add_argument(
        "--maker-box",
        default="median",
        choices=("median", "own"),
        help="the box a frame that makes a shape is completed in: the track's median size (the library's) or its "
        "own box (the comparison)",
    )
    ap.add_argument(
        "--fit",
        action="store_true",
        help="every completion fitted to its input's evidence (`--fit`: SceneConfig(fit=True)); with a shape per "
        "track, the shape's completion is fitted to the whole fused track",
    )
    ap.add_argument("--skip-real", action="store_true")
    ap.add_argument("--skip-sequences", action="store_true")
    ap.add_argument("--json", required=True)
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    if args.maker_box == "own":  # the comparison: the shape made in the making frame's own box
        from spotlights.completion.shapes import TrackShapes

        TrackShapes.maker_box = lambda self, tr, pos: None
    completer = load_completer(args.checkpoint, precision=args.precision)
    config = SceneConfig(fit=args.fit)
    report: dict = dict(
        command="OMP_NUM_THREADS=1 nice -n 10 python benchmarks/track_shapes.py "
        + " ".join(sys.argv[1:] if argv is None else argv),
        checkpoint=args.checkpoint,
        model=completer.model_name,
        precision=args.precision,
        maker_box=args.maker_box,
        fit=args.fit,
        torch_threads=1,
        sample_points=SAMPLE,
    )
    if not args.skip_real:
        report["nuscenes"] = real_scene(args, completer, config)
    if not args.skip_sequences:
        report["sequences"] = sequences(args, completer, config)
    report["targets"] = dict(consistency_over_frame=0.3, fidelity_over_frame=1.1, gap_closed_accuracy=0.5)
    text = json.dumps(report, indent=1, default=float)
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text + "\n", encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
