"""The heading check (``complete --heading-check``): how often it is right, on synthetic test cars and real boxes.

A detector box that points backwards is the same box turned by 180 degrees about its up axis; in the
box's unit frame the partial input is then rotated (x, y negated). The check completes both and keeps
the heading whose completion lies closer to the observed points (fidelity: mean distance from the
partial input to the completion). This script measures, for one model:

* **synthetic test cars** (``--data``, the test split of a completion dataset: the right heading is
  known): for every scan, fidelity with the right heading (``f_right``) and with the turned one
  (``f_turned``); the accuracy (prediction -> ground-truth surface, one-sided mean, unit frame) of the
  completion with each heading (what a backward box costs); and, for a decision rule "turn when the
  other heading's fidelity is lower by more than ``margin`` (relative)", the false-alarm rate (right
  boxes turned) and the recovery rate (backward boxes turned back);
* **real annotated boxes** (``--real`` observation files from ``real extract``; annotations are taken as
  right): the false-alarm rate per class, at each margin.

Writes ``--json`` (default ``docs/results/heading_check.json``). Usage::

    python benchmarks/heading.py --data data/cars.h5 --real av2.h5 nuscenes.h5 kitti.h5 --views 40
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from spotlights.data.real.extract import read_observations
from spotlights.data.store import open_dataset
from spotlights.experiments.real_evaluation import complete_all, flip_heading
from spotlights.geometry.neighbors import serial_queries
from spotlights.learning.inference import load_completer
from spotlights.metrics.consistency import fidelity, nn_distances

MARGINS = (0.0, 0.05, 0.10, 0.20, 0.30, 0.40, 0.50, 0.60)


def rates(f_right: np.ndarray, f_turned: np.ndarray, margin: float) -> dict:
    """False alarms (right heading turned) and recoveries (turned heading turned back) of the rule
    'turn when the other fidelity < (1 - margin) x this one'."""
    ok = np.isfinite(f_right) & np.isfinite(f_turned)
    fr, ft = f_right[ok], f_turned[ok]
    return {
        "margin": margin,
        "n": int(ok.sum()),
        "false_alarm_rate": float(np.mean(ft < (1 - margin) * fr)) if ok.any() else None,
        "recovery_rate": float(np.mean(fr < (1 - margin) * ft)) if ok.any() else None,
    }


def synthetic(completer, data: str, views: int, batch: int) -> dict:
    with open_dataset(data) as ds:
        models = ds.split_models("test")
        idx = np.concatenate(
            [ds.split_indices("test")[ds.sample_model[ds.split_indices("test")] == m][:views] for m in models]
        )
        h5 = ds._h5()
        partial = np.asarray(h5["samples/partial"][np.sort(idx)], dtype=np.float32)
        model_of = np.asarray(h5["samples/model"][np.sort(idx)])
        gt = {int(m): np.asarray(h5["models/gt_dense"][int(m)], dtype=np.float64) for m in np.unique(model_of)}
        sizes = np.asarray(ds.size)[model_of] if ds.size is not None else None
    right = complete_all(completer, partial, batch_size=batch, progress=False, box_sizes=sizes)
    turned_in = flip_heading(partial)
    turned = complete_all(completer, turned_in, batch_size=batch, progress=False, box_sizes=sizes)
    with serial_queries():
        f_r = np.array([fidelity(p, c) for p, c in zip(partial, right)])
        f_t = np.array([fidelity(p, c) for p, c in zip(turned_in, turned)])
        # accuracy in the object's own (right) frame: a backward box's completion is turned back first
        acc_r = np.array([nn_distances(c, gt[int(m)]).mean() if len(c) else np.nan for c, m in zip(right, model_of)])
        acc_t = np.array(
            [nn_distances(flip_heading(c), gt[int(m)]).mean() if len(c) else np.nan for c, m in zip(turned, model_of)]
        )
    return {
        "n_scans": int(len(partial)),
        "n_models": int(len(gt)),
        "accuracy_right_heading": float(np.nanmean(acc_r)),
        "accuracy_backward_box": float(np.nanmean(acc_t)),
        "accuracy_ratio": float(np.nanmean(acc_t) / np.nanmean(acc_r)),
        "fidelity_right": float(np.nanmean(f_r)),
        "fidelity_turned": float(np.nanmean(f_t)),
        "rules": [rates(f_r, f_t, m) for m in MARGINS],
    }


def real(completer, path: str, batch: int) -> dict:
    obs = read_observations(path)
    right = complete_all(completer, obs.partial, batch_size=batch, progress=False, box_sizes=obs.box_size)
    turned_in = flip_heading(obs.partial)
    turned = complete_all(completer, turned_in, batch_size=batch, progress=False, box_sizes=obs.box_size)
    with serial_queries():
        f_r = np.array([fidelity(p, c) for p, c in zip(obs.partial, right)])
        f_t = np.array([fidelity(p, c) for p, c in zip(turned_in, turned)])
    cls = np.array(obs.cls)
    out = {
        "file": str(path),
        "source_format": obs.meta.get("source_format"),
        "n_observations": len(obs),
        "rules": [rates(f_r, f_t, m) for m in MARGINS],
        "per_class": {},
    }
    for c in sorted(set(cls)):
        k = cls == c
        out["per_class"][c] = {"n": int(k.sum()), "rules": [rates(f_r[k], f_t[k], m) for m in MARGINS]}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", default="default")
    ap.add_argument("--data", default=None, help="completion dataset (its test split): synthetic cars")
    ap.add_argument("--views", type=int, default=40, help="test scans per test model")
    ap.add_argument("--real", nargs="*", default=[], help="observation files of real scans (annotated boxes)")
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json", default="docs/results/heading_check.json")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    comp = load_completer(args.checkpoint, device="cpu")
    t0 = time.perf_counter()
    res = {"checkpoint": args.checkpoint, "model": comp.model_name, "margins": list(MARGINS), "real": []}
    if args.data:
        res["synthetic"] = synthetic(comp, args.data, args.views, args.batch)
    for p in args.real:
        res["real"].append(real(comp, p, args.batch))
    res["seconds"] = time.perf_counter() - t0
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    if "synthetic" in res:
        s = res["synthetic"]
        print(
            f"synthetic: {s['n_scans']} test scans of {s['n_models']} cars; accuracy right {s['accuracy_right_heading']:.4f}, "
            f"backward box {s['accuracy_backward_box']:.4f} ({s['accuracy_ratio']:.2f}x)"
        )
        for r in s["rules"]:
            print(
                f"  margin {r['margin']:.2f}: false alarms {r['false_alarm_rate']:.3f}, recoveries {r['recovery_rate']:.3f}"
            )
    for r in res["real"]:
        print(
            f"{r['source_format']} ({r['n_observations']} observations): false alarms "
            + ", ".join(f"m={x['margin']:.2f} {x['false_alarm_rate']:.3f}" for x in r["rules"])
        )
        for c, v in r["per_class"].items():
            print(f"    {c} ({v['n']}): " + ", ".join(f"{x['false_alarm_rate']:.3f}" for x in v["rules"]))
    print(f"-> {args.json}")


if __name__ == "__main__":
    main()
