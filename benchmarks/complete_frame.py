"""Time to complete a whole LiDAR frame once the model is loaded (``spotlights complete SCAN --boxes ...``).

The frame: KITTI object 002155 (velodyne_reduced, 13 vehicles in its label_2 file, 8 with at least
10 points) from ``../shared/data/lidar/kitti-object/training-fov-cropped``. Measured in one run,
median of ``--repeats`` runs after a warm-up, for each torch thread count of ``--threads``
(default 1 and 2, the runs of the two interleaved so that both see the same load; the target:
< 0.5 s on 2 cores):

* ``read``: the scan (.bin) and the label file with its calibration -> boxes in the Velodyne frame;
* ``complete``: crop every box, one batched forward pass per model (the main one, and ``--fallback``'s for the
  boxes only it learned: by default the class model beside the default, as ``complete``), map back
  (:func:`complete_scene`);
* ``complete + heading check``: the same with both headings of every box (twice the batch);
* ``write``: the scene PLY (x y z, source, object);
* ``end to end``: read + complete + write (no picture);

each as wall-clock seconds and as this process's CPU seconds (the machine is shared: CPU time
shows what the work costs, wall time what a user waits). Also checks that every completion point
lies inside its box's sphere. Writes ``--json`` (default ``docs/results/complete_frame.json``).

Usage: ``python benchmarks/complete_frame.py [--threads 1 2] [--repeats 20] [--checkpoint default]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = Path(os.environ.get("SPOTLIGHTS_SHARED", HERE.parent.parent / "shared")) / "data"


def timed(fn, repeats: int, threads=(None,)) -> tuple[dict, object]:
    """Median wall and CPU seconds of ``fn()`` per torch thread count, the counts interleaved run by run."""
    import torch

    wall = {t: [] for t in threads}
    cpu = {t: [] for t in threads}
    out = None
    for t in threads:  # warm-up
        if t:
            torch.set_num_threads(t)
        fn()
    for _ in range(repeats):
        for t in threads:
            if t:
                torch.set_num_threads(t)
            t0, c0 = time.perf_counter(), time.process_time()
            out = fn()
            wall[t].append(time.perf_counter() - t0)
            cpu[t].append(time.process_time() - c0)
    res = {
        str(t): {"wall_s": statistics.median(wall[t]), "cpu_s": statistics.median(cpu[t]), "wall_min_s": min(wall[t])}
        for t in threads
    }
    return (res[str(threads[0])] if threads == (None,) else res), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", default=str(SHARED / "lidar" / "kitti-object" / "training-fov-cropped"))
    ap.add_argument("--frame", default="002155")
    ap.add_argument("--checkpoint", default="default")
    ap.add_argument(
        "--fallback", default="auto", help="as `complete --fallback` (auto: the class model beside the default)"
    )
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--json", default=str(HERE.parent / "docs" / "results" / "complete_frame.json"))
    args = ap.parse_args()

    import torch

    from spotlights.completion.frame import SceneConfig, complete_scene, write_scene
    from spotlights.completion.scan import resolve_fallback
    from spotlights.data.real.boxfiles import read_box_file
    from spotlights.data.real.scans import read_scan
    from spotlights.learning.inference import load_completer

    threads = tuple(args.threads)
    torch.set_num_threads(max(threads))
    root = Path(args.root)
    scan_p, label_p, calib_p = (
        root / "velodyne_reduced" / f"{args.frame}.bin",
        root / "label_2" / f"{args.frame}.txt",
        root / "calib" / f"{args.frame}.txt",
    )
    t0 = time.perf_counter()
    completer = load_completer(args.checkpoint, device="cpu")
    fallback_name = resolve_fallback(args.fallback, args.checkpoint)
    fallback = None if fallback_name is None else load_completer(fallback_name, device="cpu")
    load_s = time.perf_counter() - t0
    fb = {"fallback": fallback, "fallback_name": fallback_name}

    def read():
        return read_scan(scan_p), read_box_file(label_p, calib=calib_p).boxes

    r_read, (points, boxes) = timed(read, args.repeats)
    plain, heading = SceneConfig(), SceneConfig(heading_check=True)
    r_complete, result = timed(lambda: complete_scene(points, boxes, completer, plain, **fb), args.repeats, threads)
    r_heading, _ = timed(lambda: complete_scene(points, boxes, completer, heading, **fb), args.repeats, threads)
    with tempfile.TemporaryDirectory() as scratch:  # the timed PLY writes, removed afterwards
        tmp = Path(scratch) / "scene.ply"
        r_write, _ = timed(lambda: write_scene(result, tmp), args.repeats)

        def end_to_end():
            pts, bx = read()
            return write_scene(complete_scene(pts, bx, completer, plain, **fb), tmp)

        r_all, _ = timed(end_to_end, args.repeats, threads)
    inside = all(
        np.linalg.norm(o.completion - o.used_box.center, axis=1).max() <= o.used_box.radius * (1 + 1e-6)
        for o in result.completed
    )
    vehicles = sum(b.cls is not None for b in boxes)
    res = {
        "frame": f"kitti-object/training-fov-cropped {args.frame}",
        "scan_points": int(len(points)),
        "boxes": len(boxes),
        "vehicle_boxes": vehicles,
        "completed": len(result.completed),
        "skipped": result.skipped(),
        "completion_points": int(sum(len(o.completion) for o in result.completed)),
        "every_completion_point_inside_its_sphere": bool(inside),
        "model": completer.model_name,
        "checkpoint": args.checkpoint,
        "fallback": fallback_name,
        "completed_by_fallback": sum(o.completed_by is not None for o in result.completed),
        "threads": args.threads,
        "repeats": args.repeats,
        "model_load_s": load_s,  # the main model and the fallback, if any
        "read": r_read,
        "complete": r_complete,
        "complete_heading_check": r_heading,
        "write_ply": r_write,
        "end_to_end_no_picture": r_all,
        "cpu": _cpu_name(),
        "load_average": os.getloadavg(),
    }
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    print(
        f"{res['frame']}: {len(points)} points, {vehicles} vehicle boxes, {len(result.completed)} completed "
        f"({res['completion_points']} points, all inside their spheres: {inside}); model load {load_s:.2f} s"
    )

    def line(name, r):
        print(
            f"  {name:34s} wall {1000 * r['wall_s']:7.1f} ms (min {1000 * r['wall_min_s']:.1f})   cpu {1000 * r['cpu_s']:7.1f} ms"
        )

    for k in ("read", "write_ply"):
        line(k, res[k])
    for k in ("complete", "complete_heading_check", "end_to_end_no_picture"):
        for t, r in res[k].items():
            line(f"{k} ({t} thread{'s' if t != '1' else ''})", r)
    print(f"load average {res['load_average'][0]:.1f} on this machine -> {args.json}")


def _cpu_name() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return ""


if __name__ == "__main__":
    main()
