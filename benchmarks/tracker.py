"""The 3-D tracker on the shared nuScenes scene with simulated detections: MOTA, IDF1, identity switches, speed.

Ground truth: the scene's vehicle boxes (:data:`spotlights.data.real.CLASSES`) in each LIDAR_TOP keyframe, with the
annotation's ``num_lidar_pts``. Detections: :func:`spotlights.tracking.simulate.simulate_detections` (10% of the
detectable boxes missed, 10% false positives with low scores, 0.15 m / 3 degree / 5% size noise, seed 0; detectable:
at least one LiDAR point and within 50 m). Tracker: :func:`spotlights.tracking.track_boxes` with its default
settings, on detections with a score of at least ``--min-score``. Metrics: py-motmetrics (2 m centre distance,
same class) against the detectable boxes; seeds 1-29 as well, for the spread (and the means over the thirty seeds);
single changes of the tracker's settings on the same detections; seeds 30-59 (``--check-seeds``), with and
without the sideways gate, which was chosen on seeds 0-29; and a detector that also reports velocities
(0.3 m/s of noise), tracked with and without them. Speed: frames per CPU second of ``track_boxes`` alone (the median of
``--repeats`` runs; one thread: run with ``OMP_NUM_THREADS=1``).

    OMP_NUM_THREADS=1 python benchmarks/tracker.py --json docs/results/tracking/tracker_nuscenes.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from spotlights.data.real.nuscenes import NuScenesReader
from spotlights.tracking.detections import filter_detections
from spotlights.tracking.evaluate import clear_mot
from spotlights.tracking.simulate import DetectorModel, nuscenes_ground_truth, simulate_detections
from spotlights.tracking.tracker import TrackerConfig, track_boxes

#: The simulated detector's velocity noise, m/s, where it reports velocities (published LiDAR detectors' mean
#: velocity errors on nuScenes are of this order).
VELOCITY_SIGMA = 0.3

SHARED = Path(os.environ.get("SPOTLIGHTS_SHARED", Path(__file__).resolve().parents[2] / "shared")) / "data"
NUSCENES = SHARED / "lidar" / "nuscenes"


def cpu() -> dict:
    """The CPU's model name and whether it has AVX-512, bf16 and AMX (from /proc/cpuinfo's flags)."""
    name, flags = platform.processor(), set()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name") and name in ("", platform.processor()):
                    name = line.split(":", 1)[1].strip()
                elif line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    break
    except OSError:
        pass
    return {
        "model": name,
        "avx512": "avx512f" in flags,
        "bf16": bool({"avx512_bf16", "amx_bf16"} & flags),
        "amx": bool({"amx_tile", "amx_bf16", "amx_int8"} & flags),
        "logical_cpus": os.cpu_count(),
    }


#: The tracker without its sideways gate (the settings that turn it off).
NO_SIDEWAYS_GATE = {"lateral_speed_mps": 0.0, "lateral_floor_m": 1000.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(NUSCENES), help="the nuScenes folder (default: the shared scene)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--min-score", type=float, default=0.0)
    ap.add_argument("--repeats", type=int, default=20, help="timed runs of the tracker (the median is reported)")
    ap.add_argument("--more-seeds", type=int, default=29, help="also score seeds SEED+1 .. SEED+N (the spread)")
    ap.add_argument(
        "--check-seeds",
        type=int,
        default=30,
        help="seeds SEED+N+1 .. SEED+N+K scored too (K this; 0: none): the settings were chosen on the first ones",
    )
    ap.add_argument("--json", required=True, help="results file")
    args = ap.parse_args()

    truth_all, counts = nuscenes_ground_truth(NuScenesReader(Path(args.data)))
    model = DetectorModel()
    dets, truth = simulate_detections(truth_all, counts, model, seed=args.seed)
    dets, kept = filter_detections(dets, args.min_score)
    config = TrackerConfig()
    tracked = track_boxes(dets, config)
    scores = clear_mot(truth, tracked)
    n_det = sum(len(f.boxes) for f in dets)
    other = {}
    for seed in range(args.seed + 1, args.seed + 1 + args.more_seeds):
        d, t = simulate_detections(truth_all, counts, model, seed=seed)
        m = clear_mot(t, track_boxes(filter_detections(d, args.min_score)[0], config))
        other[str(seed)] = {k: m[k] for k in ("mota", "idf1", "id_switches", "id_switches_per_100_tracks")}
    every = [scores] + list(other.values())
    means = {
        k: float(np.mean([m[k] for m in every])) for k in ("mota", "idf1", "id_switches", "id_switches_per_100_tracks")
    }
    means["seeds"] = len(every)
    seeds = range(args.seed, args.seed + 1 + args.more_seeds)

    def over_seeds(detector: DetectorModel, tracker: TrackerConfig, which=seeds) -> dict:
        """Totals and means of ``tracker`` on ``detector``'s detections of every seed of ``which``."""
        runs = []
        for seed in which:
            d, t = simulate_detections(truth_all, counts, detector, seed=seed)
            runs.append(clear_mot(t, track_boxes(filter_detections(d, args.min_score)[0], tracker)))
        return {
            "id_switches_total": int(sum(m["id_switches"] for m in runs)),
            "id_switches_per_100_tracks_mean": float(np.mean([m["id_switches_per_100_tracks"] for m in runs])),
            "mota_mean": float(np.mean([m["mota"] for m in runs])),
        }

    alternatives = {}  # the default against single changes of one setting, on the same detections
    for name, change in (("coast_velocity_sigmas=0", {"coast_velocity_sigmas": 0.0}), ("max_misses=6", {"max_misses": 6}),
                         ("max_distance_m=3", {"max_distance_m": 3.0}), ("max_distance_m=4", {"max_distance_m": 4.0}),
                         ("no sideways gate", NO_SIDEWAYS_GATE)):  # fmt: skip
        alternatives[name] = over_seeds(model, dataclasses.replace(config, **change))
    first = args.seed + 1 + args.more_seeds
    check = range(first, first + args.check_seeds)
    held_out = {
        "seeds": [check.start, check.stop - 1] if args.check_seeds else [],
        "default": over_seeds(model, config, check) if args.check_seeds else None,
        "no sideways gate": over_seeds(model, dataclasses.replace(config, **NO_SIDEWAYS_GATE), check)
        if args.check_seeds
        else None,
    }
    # a detector that reports velocities (VELOCITY_SIGMA m/s of noise): the tracker using them, and ignoring them
    moving = dataclasses.replace(model, velocity_sigma_mps=VELOCITY_SIGMA)
    velocities = {
        "detector_velocity_sigma_mps": VELOCITY_SIGMA,
        "used (default)": over_seeds(moving, config),
        "ignored": over_seeds(moving, dataclasses.replace(config, detection_velocity_sigma=0.0)),
    }
    means["id_switches_total"] = int(sum(m["id_switches"] for m in every))
    seconds = []
    for _ in range(args.repeats):
        t0 = time.process_time()
        track_boxes(dets, config)
        seconds.append(time.process_time() - t0)
    cpu_s = float(np.median(seconds))
    result = {
        "command": "OMP_NUM_THREADS=1 python benchmarks/tracker.py --json docs/results/tracking/tracker_nuscenes.json",
        "data": "nuScenes v1.0-mini scene-0523 (shared data), LIDAR_TOP keyframes",
        "frames": len(dets),
        "detections": n_det,
        "detections_per_frame": n_det / max(len(dets), 1),
        "detector_model": dataclasses.asdict(model),
        "seed": args.seed,
        "min_score": args.min_score,
        "tracker": dataclasses.asdict(config),
        "metrics": scores,
        "other_seeds": other,
        "mean_over_seeds": means,
        "alternatives": alternatives,
        "held_out_seeds": held_out,
        "detector_velocities": velocities,
        "speed": {
            "cpu_seconds_median": cpu_s,
            "frames_per_cpu_second": len(dets) / cpu_s,
            "repeats": args.repeats,
            "threads": os.environ.get("OMP_NUM_THREADS", "unset"),
        },
        "cpu": cpu(),
        "targets": {"mota": 0.80, "id_switches_per_100_tracks": 3.0, "frames_per_second": 200.0},
    }
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    m = scores
    print(
        f"MOTA {m['mota']:.3f}  IDF1 {m['idf1']:.3f}  ID switches {m['id_switches']} "
        f"({m['id_switches_per_100_tracks']:.1f} per 100 of {m['gt_tracks']} tracks)  FP {m['false_positives']}  "
        f"FN {m['misses']} of {m['gt_boxes']}  {len(dets) / cpu_s:.0f} frames/s ({cpu()['model']}) -> {out}"
    )


if __name__ == "__main__":
    main()
