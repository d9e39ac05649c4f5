"""Frames per second of ``real complete`` on the shared nuScenes scene with each runtime, side by side in one run.

    python benchmarks/frames_runtime.py --json docs/results/speed/frames_runtime.json

Runs ``spotlights real complete ../shared/data/lidar/nuscenes --format nuscenes --fuse past:5 --refine-boxes
--no-pictures`` as a process with ``--runtime onnx``, ``--runtime torch`` and the default (``auto``), ``--rounds``
times each (interleaved), and reports the frame loop's frames per second (the run's ``wall_seconds``, from its
summary) and the whole command's wall and CPU seconds (children's rusage), naming the CPU. Wall-clock figures:
run it on an idle machine and compare the rows with each other, not with another machine's.

One more row, ``detections --track`` (the default runtime): the same scene from a detector's boxes instead of the
labels, ``real complete ... --detections DETECTIONS.json --track --fuse past:5 --no-pictures``, with the detections
of :func:`spotlights.tracking.simulate.simulate_detections` (seed 0, the tracker benchmark's detector model) written
as a nuScenes detection result JSON: tracking, fusion and completion in one command.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
NUSCENES = Path(os.environ.get("SPOTLIGHTS_SHARED", REPO.parent / "shared")) / "data" / "lidar" / "nuscenes"
RUNTIMES = {"onnx": ["--runtime", "onnx"], "torch": ["--runtime", "torch"], "auto (default)": []}
DETECTIONS_ROW = "detections --track"


def detections_file(path: Path) -> Path:
    """Simulated detections of the shared scene (seed 0) as a nuScenes detection result JSON at ``path``."""
    from spotlights.data.real.nuscenes import NuScenesReader
    from spotlights.tracking.outputs import nuscenes_tracking_document
    from spotlights.tracking.simulate import DetectorModel, nuscenes_ground_truth, simulate_detections

    truth, counts = nuscenes_ground_truth(NuScenesReader(NUSCENES))
    detections, _ = simulate_detections(truth, counts, DetectorModel(), seed=0)
    doc = nuscenes_tracking_document(detections)
    results = {
        token: [
            {k: v for k, v in e.items() if k not in ("tracking_id", "tracking_name", "tracking_score")}
            | {"detection_name": e["tracking_name"], "detection_score": e["tracking_score"], "attribute_name": ""}
            | {"velocity": None}  # the simulated detector reports no velocity
            for e in entries
        ]
        for token, entries in doc["results"].items()
    }
    path.write_text(json.dumps({"meta": doc["meta"], "results": results}))
    return path


def run_once(extra: list[str], out: Path, base: list[str] | None = None) -> dict:
    """One ``real complete`` process: its frames, loop seconds, runtime, precision, wall and CPU seconds."""
    args = ["real", "complete", str(NUSCENES), "--format", "nuscenes"]
    args += ["--fuse", "past:5", "--refine-boxes"] if base is None else base
    args += ["--no-pictures", "--out", str(out), "-q", *extra]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    proc = subprocess.run([sys.executable, "-m", "spotlights", *args], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(proc.stderr[-2000:])
    s = json.loads((out / "summary.json").read_text())
    return {
        "frames": s["n_frames"],
        "loop_s": s["wall_seconds"],
        "runtime": s["runtime"],
        "precision": s["precision"],
        "command_wall_s": wall,
        "command_cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json", required=True)
    a = ap.parse_args()
    sys.path.insert(0, str(REPO / "src"))
    from spotlights.learning.cpu import cpu_description

    runs: dict[str, list[dict]] = {k: [] for k in [*RUNTIMES, DETECTIONS_ROW]}
    with tempfile.TemporaryDirectory() as tmp:
        detections = detections_file(Path(tmp) / "detections.json")
        tracked = ["--detections", str(detections), "--track", "--fuse", "past:5"]
        for r in range(a.rounds):
            for name, extra in RUNTIMES.items():
                runs[name].append(run_once(extra, Path(tmp) / f"{r}-{name.split()[0]}"))
            runs[DETECTIONS_ROW].append(run_once([], Path(tmp) / f"{r}-detections", base=tracked))
    rows = {}
    for name, rs in runs.items():
        loop = statistics.median(x["loop_s"] for x in rs)
        rows[name] = {
            "runtime": rs[0]["runtime"],
            "precision": rs[0]["precision"],
            "frames": rs[0]["frames"],
            "frames_per_s": rs[0]["frames"] / loop,
            "loop_s": loop,
            "command_wall_s": statistics.median(x["command_wall_s"] for x in rs),
            "command_cpu_s": statistics.median(x["command_cpu_s"] for x in rs),
        }
        print(
            f"{name:15s} {rows[name]['runtime']:6s} {rows[name]['precision']:5s} {rows[name]['frames_per_s']:6.2f} frames/s"
        )
    result = {
        "command": "python benchmarks/frames_runtime.py --json docs/results/speed/frames_runtime.json",
        "cpu": cpu_description(),
        "load_average": list(os.getloadavg()),
        "rounds": a.rounds,
        "rows": rows,
    }
    Path(a.json).parent.mkdir(parents=True, exist_ok=True)
    Path(a.json).write_text(json.dumps(result, indent=2) + "\n")
    print("->", a.json)


if __name__ == "__main__":
    main()
