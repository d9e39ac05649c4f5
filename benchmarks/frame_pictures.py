"""The default ``real complete`` (pictures on) side by side with another source tree: frames per second.

``real complete SOURCE --format FORMAT --frames 0:N`` as a user runs it (a PNG, a PLY and a JSON per frame, the
default model and its fallback), in a fresh process per run, alternating ``--against OTHER_SRC`` (e.g. a
checkout of the code before a change) and this checkout's ``src``, ``--rounds`` times; each run's frame loop is
timed by the command itself (``wall_seconds`` of its ``summary.json``: after the model loads). The ratio of the two
trees' medians is the number to cite (the machine is shared: a ratio measured in one run, not two absolute
numbers measured apart).

Usage::

    python benchmarks/frame_pictures.py --against before/src --frames 12 --rounds 3 \\
        --json docs/results/real/frame_pictures.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from spotlights.outputs import atomic_output

HERE = Path(__file__).resolve().parents[1]
NUSCENES = HERE.parent / "shared" / "data" / "lidar" / "nuscenes"


def one_run(src: Path, source: str, fmt: str, frames: int, extra: list[str]) -> dict:
    """One ``real complete`` of the first ``frames`` frames with ``src`` on the path: its summary's timings."""
    with tempfile.TemporaryDirectory(prefix="frame_pictures_") as tmp:
        out = Path(tmp) / "out"
        cmd = [sys.executable, "-m", "spotlights", "real", "complete", source, "--format", fmt]
        cmd += ["--frames", f"0:{frames}", "--out", str(out), "-q", *extra]
        env = dict(os.environ, PYTHONPATH=str(src))
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"{src}: real complete failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
        summary = json.loads((out / "summary.json").read_text())
        pngs = len(list(out.rglob("*.png")))
    return {
        "wall_seconds": summary["wall_seconds"],
        "frames_per_second": frames / summary["wall_seconds"],
        "process_seconds": time.perf_counter() - t0,
        "pngs": pngs,
        "load": float(Path("/proc/loadavg").read_text().split()[0]) if Path("/proc/loadavg").exists() else None,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", required=True, help="the other tree's src folder (e.g. a worktree of main)")
    ap.add_argument("--source", default=str(NUSCENES), help="dataset folder (default: the shared nuScenes scene)")
    ap.add_argument("--format", default="nuscenes")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--extra", nargs=argparse.REMAINDER, default=[], help="more real complete options (last)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    trees = {"other": Path(args.against).resolve(), "this": HERE / "src"}
    runs: dict = {k: [] for k in trees}
    for r in range(args.rounds):
        for name, src in trees.items():
            res = one_run(src, args.source, args.format, args.frames, args.extra)
            runs[name].append(res)
            print(f"round {r + 1} {name}: {res['frames_per_second']:.2f} frames/s ({res['wall_seconds']:.2f} s)")
    med = {k: statistics.median(x["wall_seconds"] for x in v) for k, v in runs.items()}
    per_round = [t["wall_seconds"] / o["wall_seconds"] for t, o in zip(runs["this"], runs["other"])]
    report = {
        "command": f"real complete {args.source} --format {args.format} --frames 0:{args.frames} -q "
        + " ".join(args.extra),
        "trees": {k: str(v) for k, v in trees.items()},
        "runs": runs,
        "median_frames_per_second": {k: args.frames / v for k, v in med.items()},
        "time_ratio_this_over_other_per_round": per_round,
        "speedup_median": med["other"] / med["this"],
        "machine": {"cores": os.cpu_count()},
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }
    print(
        f"median: this {report['median_frames_per_second']['this']:.2f} frames/s, other "
        f"{report['median_frames_per_second']['other']:.2f}: {report['speedup_median']:.2f}x"
    )
    if args.json:
        with atomic_output(Path(args.json), suffix=".json") as tmp:
            Path(tmp).write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
