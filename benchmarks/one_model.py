"""One model for every class: per source/class test accuracy, a long-truck check and the learning curve, in one run.

Three parts, every checkpoint side by side:

* **test split** of a union dataset (ApolloScape test cars, held-out Kenney vehicles, held-out procedural
  bodies per class): ``benchmarks/class_eval.py``'s scoring (unit frame, outputs as they are, the share of
  points inside the box grown by 0.15 m before any clamp), the first ``--max-views`` views of each model;
* **long trucks**: procedural articulated trucks of ``--truck-length`` (+- 0.5 m, the first ``--trucks``
  seeds that draw one), each scanned once by the simulated HDL-64E (``LidarSimulator``, seeded pose 12-18 m
  away), completed by :func:`spotlights.api.complete_frame` with no fallback (the checkpoint alone): its
  status (``completed``, or ``not_learned``: left as observed points by the learned-domain gate; then also
  ``forced``: the same with ``complete_unknown``), the share
  of the network's points inside the grown box before the clamp, and the completion's accuracy /
  completeness in metres against 20,000 points sampled on the truck's surface;
* **learning curve** of a run (``--train-log``: its ``log.csv``): step, wall seconds, validation CD-L1,
  accuracy, completeness, threshold per interval.

    python benchmarks/one_model.py --data union.h5 --checkpoint default classes runs/wide/best.pt \\
        --labels default classes wide-classes --train-log runs/wide/log.csv --json one_model.json
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from class_eval import score  # noqa: E402
from spotlights.api import complete_frame  # noqa: E402
from spotlights.data.lidar import LidarSimulator, VehiclePose  # noqa: E402
from spotlights.data.synthetic.procedural import draw_params, vehicle_arrays  # noqa: E402
from spotlights.geometry.boxes import Box  # noqa: E402
from spotlights.learning.data import TorchCompletionDataset  # noqa: E402

CURVE = ("epoch", "global_step", "wall_seconds", "val_chamfer_l1", "val_accuracy", "val_completeness", "val_threshold")


def long_vehicles(
    length: float, n: int, max_seeds: int = 4000, body: str = "articulated_truck", first_seed: int = 0
) -> list:
    """The first ``n`` seeds from ``first_seed`` on whose vehicle of ``body`` is within 0.5 m of ``length``:
    [(seed, v, f)]."""
    out = []
    for seed in range(first_seed, first_seed + max_seeds):
        p = draw_params(body, seed)
        if abs(p.length - length) <= 0.5:
            v, f = vehicle_arrays(p)
            out.append((seed, v, f))
            if len(out) == n:
                break
    return out


def vehicle_check(checkpoints: dict, vehicles: list, cls: str = "truck") -> dict:
    """{label: [per vehicle: seed, size, status, inside_box, points, accuracy_m, completeness_m]}; boxes of class
    ``cls``."""
    scans = []
    for seed, v, f in vehicles:
        sim = LidarSimulator(v, f)
        rng = np.random.default_rng(seed)
        pose = VehiclePose(
            float(rng.uniform(12, 18)), float(rng.uniform(-math.pi, math.pi)), float(rng.uniform(-math.pi, math.pi))
        )
        scan = sim.scan(pose, rng)
        m = sim.object_to_sensor(pose)
        pts = scan.points @ m[:3, :3].T + m[:3, 3]
        box = Box(sim.box_center_in_sensor(pose), sim.size, yaw=pose.heading, cls=cls, label=cls)
        surface = trimesh.Trimesh(v, f, process=False).sample(20000, seed=seed) @ m[:3, :3].T + m[:3, 3]
        scans.append((seed, pts, box, cKDTree(surface), surface))
    out = {}
    for label, ckpt in checkpoints.items():
        rows = []
        for seed, pts, box, tree, surface in scans:
            res = complete_frame(pts, [box], ckpt, fallback="none")
            o = res.objects[0]
            row = {"seed": seed, "size_m": [round(float(s), 2) for s in box.size], "scan_points": len(pts)}
            row["status"] = o.status
            if o.status == "completed" and len(o.completion):
                row["inside_box"] = round(float(o.inside_box), 4)
                row["points"] = len(o.completion)
                row["accuracy_m"] = round(float(tree.query(o.completion)[0].mean()), 4)
                row["completeness_m"] = round(float(cKDTree(o.completion).query(surface)[0].mean()), 4)
            if o.status == "not_learned":  # what the network would draw if the gate let it (complete_unknown)
                forced = complete_frame(pts, [box], ckpt, fallback="none", complete_unknown=True).objects[0]
                if forced.status == "completed" and len(forced.completion):
                    row["forced"] = {
                        "inside_box": round(float(forced.inside_box), 4),
                        "accuracy_m": round(float(tree.query(forced.completion)[0].mean()), 4),
                        "completeness_m": round(float(cKDTree(forced.completion).query(surface)[0].mean()), 4),
                    }
            rows.append(row)
        out[label] = rows
    return out


def learned_lengths(checkpoint) -> dict:
    """{class: [shortest, longest] training box length, m} of a checkpoint's learned domain."""
    from spotlights.learning.checkpoint import load_checkpoint
    from spotlights.learning.domain import LearnedDomain

    dom = LearnedDomain.from_checkpoint(load_checkpoint(checkpoint))
    sizes = dom.class_sizes or {c: (dom.size_min, dom.size_max) for c in dom.classes}
    return {c: [round(float(lo[0]), 2), round(float(hi[0]), 2)] for c, (lo, hi) in sizes.items()}


def learning_curve(path: Path) -> list:
    """The intervals of a run's ``log.csv``: the columns of :data:`CURVE` (numbers rounded)."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return [{k: (round(float(r[k]), 5) if r.get(k) not in (None, "") else None) for k in CURVE if k in r} for r in rows]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--checkpoint", nargs="+", required=True)
    p.add_argument("--labels", nargs="+", default=None, help="a name per checkpoint in the JSON (default: as given)")
    p.add_argument("--max-views", type=int, default=100, help="test views per model (1..150)")
    p.add_argument("--trucks", type=int, default=3, help="long trucks scanned (1..20)")
    p.add_argument("--truck-length", type=float, default=16.0, help="metres, 12..20")
    p.add_argument("--trailer-length", type=float, default=None, help="also --trucks flatbed trailers of this length")
    p.add_argument(
        "--first-seed", type=int, default=0, help="long vehicles: the generator seeds searched start here (default 0)"
    )
    p.add_argument("--train-log", type=Path, default=None)
    p.add_argument("--json", type=Path, default=None)
    a = p.parse_args()
    labels = a.labels or a.checkpoint
    if len(labels) != len(a.checkpoint):
        p.error("--labels needs one name per --checkpoint")
    if not (1 <= a.max_views <= 150 and 1 <= a.trucks <= 20 and 12 <= a.truck_length <= 20):
        p.error("--max-views 1..150, --trucks 1..20, --truck-length 12..20")
    torch.set_num_threads(1)
    ckpts = dict(zip(labels, a.checkpoint))
    ds = TorchCompletionDataset(a.data, "test", rig=False, max_views=a.max_views, partials_in_memory=True)
    dense = ds.gt_dense()
    result = {"max_views": a.max_views, "first_seed": a.first_seed, "checkpoints": list(labels), "test": {}}
    for label, c in ckpts.items():
        r = score(c, ds, dense)
        result["test"][label] = {
            g: {k: (round(v, 5) if isinstance(v, float) else v) for k, v in s.items()} for g, s in r["groups"].items()
        }
        for g, v in r["groups"].items():
            print(
                f"{label:14s} {g:32s} n={v['n']:5d} acc={v['accuracy']:.5f} comp={v['completeness']:.5f} in={v['inside']:.3f}"
            )
    trucks = long_vehicles(a.truck_length, a.trucks, first_seed=a.first_seed)
    result["trucks"] = {"length_m": a.truck_length, "results": vehicle_check(ckpts, trucks)}
    for label, rows in result["trucks"]["results"].items():
        for r in rows:
            print(label, r)
    if a.trailer_length:
        trailers = long_vehicles(a.trailer_length, a.trucks, body="trailer_flatbed", first_seed=a.first_seed)
        result["trailers"] = {"length_m": a.trailer_length, "results": vehicle_check(ckpts, trailers, "trailer")}
        for label, rows in result["trailers"]["results"].items():
            for r in rows:
                print(label, "trailer", r)
    result["domains"] = {label: learned_lengths(c) for label, c in ckpts.items()}
    print("learned lengths (m):", result["domains"])
    if a.train_log:
        result["learning_curve"] = learning_curve(a.train_log)
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
