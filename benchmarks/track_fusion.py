"""Track-level completion (``real complete --fuse ...``): speed after the model loads, and how far refinement moves boxes.

For one dataset (default: the shared nuScenes scene-0523, 40 keyframes) and one model, in one process:

1. load the model (not timed);
2. **single frames** (``--fuse none``, today's path): read every frame, crop and complete every vehicle;
3. **fused**: build the track plan (read every frame, crop each tracked vehicle, refine the boxes with
   ``--refine-boxes``), then per frame read it, fuse each vehicle's window and complete it;
4. on the observations of Table 2's classes (car, truck, trailer) completed by both: consistency between
   consecutive completions of a track at equal density (voxel 0.1, unit frame: ``real evaluate``'s headline)
   and fidelity to each frame's own points (unit frame), single vs fused.

Both loops do what ``real complete`` does minus writing files and pictures, and are timed in wall-clock
seconds and in CPU seconds of this process (``time.process_time``: on a shared machine the wall clock
measures the queue for the CPU as much as the work). Frames per second = frames / seconds. Also: the
refinement's statuses and the share of vehicle boxes whose refined box moved more than 0.3 m.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/track_fusion.py --fuse past:5 --refine-boxes --threads 1 \\
        --json docs/results/real/track_fusion_nuscenes.json
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import time
from pathlib import Path

import numpy as np

from spotlights.data.real import open_reader
from spotlights.data.tracks import parse_window
from spotlights.experiments.scene import SceneConfig, complete_scene
from spotlights.experiments.tracks import TrackPlan
from spotlights.geometry.sampling import voxel_downsample
from spotlights.learning.inference import load_completer
from spotlights.metrics.consistency import aggregate, fidelity, track_consistency

DEFAULT_SOURCE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "lidar" / "nuscenes"


TABLE2 = ("car", "truck", "trailer")


def consistency_of(rows) -> dict:
    """Consistency between consecutive completions of each track at equal density (voxel 0.1 in the unit frame,
    ``real evaluate``'s headline), class average and over all objects, and fidelity to each frame's own points
    (unit frame, mean over observations)."""
    comps = [voxel_downsample(r[0], 0.1) for r in rows]
    tracks = track_consistency(
        comps, [r[3] for r in rows], [r[4] for r in rows], [r[2] for r in rows], [r[1] for r in rows]
    )
    agg = aggregate(tracks, classes=TABLE2)
    fid = [fidelity(r[5], r[0]) for r in rows]
    return dict(
        consistency_voxel_average=agg["average"]["cd"],
        consistency_voxel_all_objects=agg["all_objects"]["cd"],
        n_tracks=agg["all_objects"]["n_objects"],
        n_pairs=agg["all_objects"]["n_pairs"],
        fidelity_own_points=float(np.nanmean(fid)),
    )


def timed(fn):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", default=str(DEFAULT_SOURCE))
    ap.add_argument("--format", default="nuscenes")
    ap.add_argument("--checkpoint", default="default")
    ap.add_argument("--fuse", default="past:5")
    ap.add_argument("--refine-boxes", action="store_true")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    ap.add_argument("--precision", default="fp32", help="model forward: fp32 (default) or bf16")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    reader = open_reader(args.source, args.format)
    keys = reader.frame_keys()
    config = SceneConfig()
    completer = load_completer(args.checkpoint, precision=args.precision)

    kept = {"single": {}, "fused": {}}

    def keep(mode, key, frame, result):
        for o in result.completed:
            b = o.used_box
            if not b.track_id or b.cls not in TABLE2:
                continue
            own = b.normalization().to_unit(result.points[o.input_indices])
            kept[mode][(key, o.index)] = (
                o.completion_unit,
                b.radius,
                b.cls,
                (key[0], b.track_id),
                frame.timestamp,
                own,
            )

    def single():
        n = 0
        for key in keys:
            frame = reader.load(key)
            result = complete_scene(frame.points, frame.boxes, completer, config)
            keep("single", key, frame, result)
            n += len(result.completed)
        return n

    def fused():
        plan = TrackPlan(parse_window(args.fuse), config, refine=args.refine_boxes).build(reader, keys)
        n = 0
        for key in keys:
            frame = reader.load(key)
            boxes, extra = plan.frame_inputs(key, frame.boxes)
            result = complete_scene(frame.points, boxes, completer, config, extra_points=extra)
            plan.record(key, result)
            keep("fused", key, frame, result)
            n += len(result.completed)
        return plan, n

    n_single, w_single, c_single = timed(single)
    (plan, n_fused), w_fused, c_fused = timed(fused)
    both = sorted(set(kept["single"]) & set(kept["fused"]))
    quality = {mode: consistency_of([kept[mode][k] for k in both]) for mode in kept}
    summ = plan.summary()
    rows = [r for tr in summ["tracks"] for r in tr["frames"]]
    statuses = collections.Counter(r["status"] for r in rows)
    moved = [r for r in rows if r["moved_m"] > 0.3]
    report = dict(
        source=args.source,
        format=args.format,
        checkpoint=args.checkpoint,
        precision=args.precision,
        model=completer.model_name,
        torch_threads=args.threads,
        cpu_count=os.cpu_count(),
        load_average=os.getloadavg(),
        n_frames=len(keys),
        single=dict(
            completed=n_single,
            wall_s=w_single,
            cpu_s=c_single,
            fps_wall=len(keys) / w_single,
            fps_cpu=len(keys) / c_single,
        ),
        fused=dict(
            fuse=args.fuse,
            refine_boxes=args.refine_boxes,
            completed=n_fused,
            wall_s=w_fused,
            cpu_s=c_fused,
            fps_wall=len(keys) / w_fused,
            fps_cpu=len(keys) / c_fused,
            plan_timings=summ["timings"],
        ),
        quality_on_common_observations=dict(n_observations=len(both), classes=list(TABLE2), **quality),
        tracks=summ["n_tracks"],
        vehicle_boxes_in_tracks=len(rows),
        statuses=dict(statuses),
        moved_over_0_3_m=len(moved),
        moved_share_of_boxes=len(moved) / max(len(rows), 1),
        moved_share_of_refined=len(moved) / max(statuses.get("refined", 0), 1),
        moved_refined_m=dict(
            zip(
                ("median", "p90", "max"),
                np.percentile([r["moved_m"] for r in rows if r["status"] == "refined"] or [0.0], [50, 90, 100]),
            )
        ),
        moved_examples=[
            dict(
                track=r["box"]["track_id"][:8],
                label=r["box"]["label"],
                n_points=r["n_points"],
                moved_m=r["moved_m"],
                turned_deg=r["turned_deg"],
            )
            for r in sorted(moved, key=lambda r: -r["moved_m"])[:10]
        ],
    )
    text = json.dumps(report, indent=2, default=float)
    print(text)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(text + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
