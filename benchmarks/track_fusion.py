"""Track-level completion (``real complete --fuse ...``): speed after the model loads, and how far refinement moves boxes.

For one dataset (default: the shared nuScenes scene-0523, 40 keyframes) and one model, in one process:

1. load the model (not timed);
2. **single frames** (``--fuse none``, today's path): read every frame, crop and complete every vehicle;
3. **fused**: build the track plan (read every frame, crop each tracked vehicle), then per frame take it from
   the plan, refine its boxes (``--refine-boxes``), fuse each vehicle's window and complete it; with
   ``--track-worker`` (default) the cropping, refinement and fusion run in a second process a frame ahead
   (``TrackPlan(worker=True)``: the same outputs; its CPU seconds are reported as ``cpu_s_worker``);
4. on the observations of Table 2's classes (car, truck, trailer) completed by both: consistency between
   consecutive completions of a track at equal density (voxel 0.1, unit frame: ``real evaluate``'s headline)
   and fidelity to each frame's own points (unit frame), single vs fused.

Both loops do what ``real complete`` does minus writing files and pictures, and are timed in wall-clock
seconds and in CPU seconds of this process (``time.process_time``: on a shared machine the wall clock
measures the queue for the CPU as much as the work). Frames per second = frames / seconds. Also: the
refinement's statuses and the share of vehicle boxes whose refined box moved more than 0.3 m.

``--fallback auto`` completes the boxes the car model did not learn with the class model, as ``real complete``
does by default (the benchmark's default stays ``none``: the car model alone, as in its first results).

Usage::

    OMP_NUM_THREADS=1 python benchmarks/track_fusion.py --fuse past:5 --refine-boxes --threads 1 \\
        --json docs/results/real/track_fusion_nuscenes.json

**The track worker against one process** (``--compare-worker --repeats R``): after the runs above, ``R`` rounds of
the fused loop with its worker (started 1 s before, as ``real complete`` starts it before the model loads) and in one
process, in turn (``worker_and_one_process``: per round wall and CPU seconds, the worker's, the time waited for it,
the load average, whether the completions equal the first run's; medians)::

    OMP_NUM_THREADS=1 python benchmarks/track_fusion.py --fuse past:5 --refine-boxes --precision bf16 --threads 1 \\
        --compare-worker --repeats 3 --json docs/results/real/track_fusion_speed_worker_1thread_bf16.json

**The command side by side** (``--against OTHER_SRC``): the whole ``real complete SOURCE --fuse ... --no-pictures``
(:func:`~spotlights.completion.frames.complete_frames`, every file written), timed after the model
loads, in a fresh process per run, alternating ``OTHER_SRC`` (e.g. main's), this checkout's ``src`` in one
process (``this_serial``: ``--no-track-worker``) and with its track worker (``this``) for each torch thread count
of ``--speed-threads``, ``--repeats`` times: CPU seconds per frame of the process (and of the worker), wall
frames per second, the load average before and after each run, and the ratios of this code to the other
measured side by side (on a shared machine the honest number)::

    nice -n 10 python benchmarks/track_fusion.py --against src --refine-boxes --precision bf16 \\
        --speed-threads 1 2 --json docs/results/real/track_fusion_speed_side_by_side.json
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from spotlights.completion.frame import SceneConfig, complete_scene
from spotlights.completion.fusion import TrackPlan
from spotlights.completion.scan import resolve_fallback
from spotlights.data.real import open_reader
from spotlights.data.tracks import parse_window
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
        consistency_voxel_per_class={c: (e.get("cd"), e.get("n_objects")) for c, e in agg["classes"].items()},
        n_tracks=agg["all_objects"]["n_objects"],
        n_pairs=agg["all_objects"]["n_pairs"],
        fidelity_own_points=float(np.nanmean(fid)),
    )


def emit(report: dict, path: str | None) -> int:
    """Print ``report`` as JSON and, with ``path``, write it there too (its folder made); returns 0."""
    text = json.dumps(report, indent=2, default=float)
    print(text)
    if path:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(text + "\n", encoding="utf-8")
    return 0


def timed(fn):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", default=str(DEFAULT_SOURCE))
    ap.add_argument("--format", default="nuscenes")
    ap.add_argument("--checkpoint", default="default")
    ap.add_argument(
        "--fallback",
        default="none",
        help="the second model for the boxes the first did not learn, as real complete's --fallback (auto: the "
        "class model beside the default); default none (the car model alone, as in the first results)",
    )
    ap.add_argument("--fuse", default="past:5")
    ap.add_argument("--refine-boxes", action="store_true")
    ap.add_argument(
        "--snap", type=float, default=0.0, help="snap the rays to each input within R (unit frame), as --snap R"
    )
    ap.add_argument("--snap-mirror", action="store_true", help="with --snap: the mirrored input too")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    ap.add_argument("--precision", default="fp32", help="model forward: fp32 (default) or bf16")
    ap.add_argument(
        "--track-worker",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="refine and fuse in a second process a frame ahead (FramesSettings.track_worker; default on)",
    )
    ap.add_argument(
        "--compare-worker",
        action="store_true",
        help="then --repeats rounds of the fused loop with the track worker and in one process, in turn",
    )
    ap.add_argument("--json", default=None)
    ap.add_argument("--against", default=None, help="another checkout's src folder: time the command side by side")
    ap.add_argument("--speed-threads", type=int, nargs="+", default=[1, 2], help="torch thread counts (--against)")
    ap.add_argument("--repeats", type=int, default=1, help="side-by-side rounds (--against)")
    ap.add_argument("--command-run", action="store_true", help=argparse.SUPPRESS)  # one timed run (child)
    args = ap.parse_args(argv)
    if args.against:
        return side_by_side(args)
    if args.command_run:
        return command_run(args)
    import torch

    torch.set_num_threads(args.threads)
    reader = open_reader(args.source, args.format)
    keys = reader.frame_keys()
    config = SceneConfig(snap=args.snap, snap_mirror=args.snap_mirror)
    from spotlights.completion.fusion import TrackWorker  # this checkout's (--against runs an older one's command)

    early = TrackWorker.start() if args.track_worker else None  # as real complete: started before the model loads
    completer = load_completer(args.checkpoint, precision=args.precision)
    fallback_name = resolve_fallback(args.fallback, args.checkpoint)
    fallback = None if fallback_name is None else load_completer(fallback_name, precision=args.precision)
    with_fallback = dict(fallback=fallback, fallback_name=fallback_name)

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
            result = complete_scene(frame.points, frame.boxes, completer, config, **with_fallback)
            keep("single", key, frame, result)
            n += len(result.completed)
        return n

    def fused(worker=None):
        worker = (early if early is not None else args.track_worker) if worker is None else worker
        plan = TrackPlan(parse_window(args.fuse), config, refine=args.refine_boxes, worker=worker)
        plan.build(reader, keys)
        n = 0
        for key in keys:
            frame = plan.take(key)  # the frame the plan read (real complete reads each frame once)
            frame = reader.load(key) if frame is None else frame
            boxes, extra = plan.frame_inputs(key, frame.boxes)
            crops = plan.frame_crops(key)  # the scene's crops the worker made (None without one)
            result = complete_scene(
                frame.points, boxes, completer, config, extra_points=extra, crops=crops, **with_fallback
            )
            plan.record(key, result)
            keep("fused", key, frame, result)
            n += len(result.completed)
        plan.finish()  # the worker's final boxes and statuses (with a worker)
        return plan, n

    n_single, w_single, c_single = timed(single)
    (plan, n_fused), w_fused, c_fused = timed(fused)
    pairs = compare_worker(args, fused, kept, len(keys)) if args.compare_worker else None
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
        fallback=fallback_name,
        precision=args.precision,
        snap=args.snap,
        snap_mirror=args.snap_mirror,
        model=completer.model_name,
        torch_threads=args.threads,
        track_worker=args.track_worker,
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
            cpu_s_worker=summ["timings"]["worker_cpu_s"],
            plan_timings=summ["timings"],
        ),
        worker_and_one_process=pairs,
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
    return emit(report, args.json)


def compare_worker(args, fused, kept, n_frames: int) -> dict:
    """``--compare-worker``: ``--repeats`` rounds of the fused loop with its track worker (started 1 s before, as
    ``real complete`` starts it before the model loads) and in one process, in turn: wall and CPU seconds (this
    process; the worker's own), the load average; the outputs of every round equal the first run's."""
    from spotlights.completion.fusion import TrackWorker

    first = dict(kept["fused"])
    runs = []
    for rep in range(args.repeats):
        for name in ("worker", "one_process"):
            worker = False
            if name == "worker":
                worker = TrackWorker.start() or False
                time.sleep(1.0)  # its interpreter starts (not timed)
            load = os.getloadavg()
            kept["fused"].clear()
            (plan, _), wall, cpu = timed(lambda: fused(worker))
            same = kept["fused"].keys() == first.keys() and all(
                np.array_equal(kept["fused"][k][0], first[k][0]) for k in first
            )
            runs.append(
                dict(
                    mode=name,
                    repeat=rep,
                    wall_s=wall,
                    cpu_s=cpu,
                    cpu_s_worker=plan.timings["worker_cpu_s"],
                    wait_s=plan.timings["wait_s"],
                    load_average_before=load,
                    same_completions=bool(same),
                )
            )
            print(json.dumps(runs[-1]), file=sys.stderr, flush=True)
    med = {}
    for name in ("worker", "one_process"):
        rs = [r for r in runs if r["mode"] == name]
        med[name] = {k: float(np.median([r[k] for r in rs])) for k in ("wall_s", "cpu_s", "cpu_s_worker")}
        med[name] |= dict(
            fps_wall=n_frames / med[name]["wall_s"],
            cpu_ms_per_frame=1e3 * med[name]["cpu_s"] / n_frames,
            worker_cpu_ms_per_frame=1e3 * med[name]["cpu_s_worker"] / n_frames,
        )
    return dict(runs=runs, median=med)


def command_run(args) -> int:
    """One timed ``real complete`` (child of :func:`side_by_side`): prints a JSON line."""
    import torch

    from spotlights.completion.frame_selection import FramesSettings
    from spotlights.completion.frames import complete_frames

    torch.set_num_threads(args.threads)
    has_worker = "track_worker" in {f.name for f in dataclasses.fields(FramesSettings)}  # an older checkout: none
    with tempfile.TemporaryDirectory() as tmp:
        s = FramesSettings(
            source=[args.source],
            format=args.format,
            checkpoint=args.checkpoint,
            precision=args.precision,
            out=str(Path(tmp) / "out"),
            no_pictures=True,
            fuse=args.fuse,
            refine_boxes=args.refine_boxes,
            quiet=True,
            **({"track_worker": args.track_worker} if has_worker else {}),
        )
        completer = s.load_completer()  # not timed
        w0, c0 = time.perf_counter(), time.process_time()
        summ = complete_frames(s, completer=completer)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    n = summ["n_frames"]
    worker = summ.get("tracks", {}).get("timings", {}).get("worker_cpu_s", 0.0)
    row = dict(n_frames=n, cpu_s=cpu, wall_s=wall, cpu_ms_per_frame=1e3 * cpu / n, fps_wall=n / wall)
    # the frame loop alone (summary.json's wall_seconds: what "frames per second after the model loads" counts)
    row |= dict(loop_wall_s=summ["wall_seconds"], fps_loop=n / summ["wall_seconds"])
    row |= dict(completed=summ["totals"]["completed"], completed_by=summ["totals"].get("completed_by", {}))
    row |= dict(track_worker=has_worker and args.track_worker, worker_cpu_ms_per_frame=1e3 * worker / n)
    print(json.dumps(row | {"torch_threads": torch.get_num_threads(), "load_average": os.getloadavg()}))
    return 0


def side_by_side(args) -> int:
    """Alternate runs of ``args.against``, this checkout's src in one process (``this_serial``) and with its track
    worker (``this``) (fresh processes), per torch thread count."""
    here = str(Path(__file__).resolve().parents[1] / "src")
    codes = {"other": str(Path(args.against).resolve()), "this_serial": here, "this": here}
    runs = []
    for rep in range(args.repeats):
        for threads in args.speed_threads:
            for name, src in codes.items():
                env = dict(os.environ, PYTHONPATH=src, OMP_NUM_THREADS=str(threads))
                load = os.getloadavg()
                cmd = [sys.executable, __file__, "--command-run", "--threads", str(threads)]
                cmd += ["--no-track-worker"] if name == "this_serial" else []
                cmd += ["--source", args.source, "--format", args.format, "--checkpoint", args.checkpoint]
                cmd += ["--fuse", args.fuse, "--precision", args.precision] + (["--refine-boxes"] * args.refine_boxes)
                out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
                row = json.loads(out.strip().splitlines()[-1]) | dict(code=name, src=src, repeat=rep)
                row["load_average_before"] = load
                print(json.dumps(row), flush=True)
                runs.append(row)
    table = {}
    for threads in args.speed_threads:
        pick = {n: [r for r in runs if r["code"] == n and r["torch_threads"] == threads] for n in codes}
        keys = ("cpu_ms_per_frame", "worker_cpu_ms_per_frame", "fps_wall", "fps_loop")
        med = {n: {k: float(np.median([r.get(k, 0.0) for r in rs])) for k in keys} for n, rs in pick.items()}
        pairs = list(zip(pick["other"], pick["this_serial"], pick["this"]))  # run back to back: each triple's ratios
        table[f"threads_{threads}"] = dict(
            median=med,
            cpu_ratio_this_serial_over_other=[b["cpu_s"] / a["cpu_s"] for a, b, _ in pairs],
            wall_ratio_this_serial_over_other=[b["wall_s"] / a["wall_s"] for a, b, _ in pairs],
            wall_ratio_this_over_other=[c["wall_s"] / a["wall_s"] for a, _, c in pairs],
            loop_ratio_this_over_other=[c.get("loop_wall_s", 0) / a.get("loop_wall_s", 1) for a, _, c in pairs],
        )
    report = dict(
        command=f"real complete {args.source} --format {args.format} --fuse {args.fuse}"
        + (" --refine-boxes" if args.refine_boxes else "")
        + f" --no-pictures --precision {args.precision} (after the model loads)",
        cpu_count=os.cpu_count(),
        codes=codes,
        runs=runs,
        summary=table,
    )
    return emit(report, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
