"""Generalisation to vehicles from a source the models never saw: held-out accuracy over in-distribution accuracy.

For each checkpoint, the test split of an in-distribution dataset (the ApolloScape test cars of
``cars.h5``) and of a held-out dataset (e.g. the 20 Kenney vehicles, a source no shipped model
trained on) are scored with ``spotlights evaluate``'s code (the same views per model on both:
``--max-views``); the ratio held-out / in-distribution of accuracy and completeness is the
generalisation gap (the models issue's target: accuracy within 1.5x).

Beside it, the *representation's ceiling*: each test model's ground-truth depths of the
model's rig, decoded (``geometry.encode.decode``) and scored against the same dense ground
truth. If the ceiling is about the same on both sets while a model's accuracy is much worse
on the held-out set, the representation is not the limit: the model leans on what it learned
(a template of the training cars).

Build the held-out set first (test split only, the rigs of the checkpoints)::

    spotlights dataset build --meshes ../shared/data/meshes/kenney-vehicles,manifest=src/spotlights/assets/manifests/kenney-vehicles.csv,split=test \\
        --views 100 --rig box-128x128-ellipsoid-s1 --seed 0 --out kenney-test.h5
    python benchmarks/generalisation.py --in-dist cars.h5 --held-out kenney-test.h5 \\
        --checkpoint default paper --max-views 50 --json docs/results/fair/generalisation.json

Numbers: unit frame (the box's half diagonal), means over scans; per category in the JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

from spotlights.data.store import open_dataset
from spotlights.geometry.distances import accuracy, completeness
from spotlights.geometry.encode import decode
from spotlights.learning.checkpoint import load_checkpoint, resolve_checkpoint
from spotlights.learning.evaluate import evaluate_checkpoints
from spotlights.utils import atomic_output


def decode_ceiling(path, rig: str, split: str = "test") -> dict:
    """Accuracy and completeness of the ground-truth depths of ``rig``, decoded, against the dense GT.

    Parameters
    ----------
    path : dataset file (HDF5) holding ``rig``.
    rig : rig name stored in the dataset (e.g. ``box-128x128-ellipsoid-s1``).
    split : models scored (all of that split's models).

    Returns
    -------
    dict: ``models`` (count), ``accuracy`` and ``completeness`` (means over models, unit frame:
    one-sided unsquared nearest-neighbour distances decoded points -> dense GT and back),
    ``per_category`` {category: {accuracy, completeness, models}}.
    """
    acc, comp, cats = [], [], []
    with open_dataset(path) as ds:
        rows = ds.split_models(split)
        for m in rows:
            gt = ds.ground_truth(int(m), rig)
            pts, hit = decode(gt["gt_depths"], ds.rig(rig, int(m)) if ds.rig_spec(rig).needs_box else ds.rig(rig))
            pts = pts[hit]
            acc.append(accuracy(pts, gt["gt_dense"]))
            comp.append(completeness(pts, gt["gt_dense"]))
            cats.append(str(ds.categories[m]))
    per = {}
    for c in sorted(set(cats)):
        idx = [i for i, x in enumerate(cats) if x == c]
        per[c] = {
            "accuracy": float(np.mean([acc[i] for i in idx])),
            "completeness": float(np.mean([comp[i] for i in idx])),
            "models": len(idx),
        }
    return {
        "models": len(rows),
        "accuracy": float(np.mean(acc)),
        "completeness": float(np.mean(comp)),
        "per_category": per,
    }


def _rows(report: dict) -> dict:
    """{row label: {accuracy, completeness, chamfer_l1, fscore, n_points, per_category accuracy}} of an evaluate report."""
    out = {}
    for res in report["results"]:
        for row in res["rows"]:
            label = Path(res["checkpoint"]).name + (f" ({row['variant']})" if row["variant"] else "")
            s = row["summary"]
            out[label] = {
                "model": res["model"],
                **{
                    k: s["mean_over_samples"].get(k)
                    for k in ("accuracy", "completeness", "chamfer_l1", "fscore", "n_points")
                },
                "accuracy_per_category": {c: v.get("accuracy") for c, v in s["per_category"].items()},
                "scans_per_category": {c: n for c, n in s["count"].items() if c != "all"},
            }
    return out


def subset_accuracy(row: dict, categories) -> float | None:
    """Mean accuracy over the scans of ``categories`` (scan-weighted mean of the per-category means of a
    :func:`_rows` row); None when none of them was scored."""
    cats = [c for c in categories if row["scans_per_category"].get(c)]
    n = sum(row["scans_per_category"][c] for c in cats)
    return sum(row["accuracy_per_category"][c] * row["scans_per_category"][c] for c in cats) / n if n else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--in-dist", required=True, help="in-distribution dataset (its test split), e.g. cars.h5")
    ap.add_argument("--held-out", required=True, help="held-out dataset (its test split), e.g. kenney-test.h5")
    ap.add_argument("--checkpoint", nargs="+", default=["default", "paper"], help="checkpoints or short names")
    ap.add_argument("--max-views", type=int, default=50, help="views per test model on both sets (default 50)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--subset",
        default="hatchback,sedan,suv",
        help="categories of the held-out set also scored on their own (default: the car-like Kenney vehicles)",
    )
    ap.add_argument("--json", default=None, help="write the numbers here")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    t0 = time.time()
    scores = {}
    for key, path in (("in_distribution", args.in_dist), ("held_out", args.held_out)):
        rep = evaluate_checkpoints(args.checkpoint, path, split="test", max_views=args.max_views, progress=False)
        scores[key] = {
            "data": str(path),
            "n_samples": rep["n_samples"],
            "n_models": rep["n_models"],
            "rows": _rows(rep),
        }
    rigs = sorted(
        {(load_checkpoint(resolve_checkpoint(c)).get("dataset") or {}).get("rig") or "" for c in args.checkpoint}
    )
    ceiling = {}
    for rig in [r for r in rigs if r]:
        ceiling[rig] = {
            key: decode_ceiling(path, rig)
            for key, path in (("in_distribution", args.in_dist), ("held_out", args.held_out))
        }
    subset = [c.strip() for c in args.subset.split(",") if c.strip()]
    ratios = {}
    for label, r in scores["in_distribution"]["rows"].items():
        h = scores["held_out"]["rows"].get(label)
        if h:
            ratios[label] = {k: h[k] / r[k] for k in ("accuracy", "completeness") if r.get(k) and h.get(k) is not None}
            sub = subset_accuracy(h, subset)
            h["subset_accuracy"] = sub
            ratios[label]["subset_accuracy"] = sub / r["accuracy"] if sub is not None and r.get("accuracy") else None
    print(f"held-out / in-distribution (test splits, first {args.max_views} views per model):")
    for label, r in ratios.items():
        i, h = scores["in_distribution"]["rows"][label], scores["held_out"]["rows"][label]
        print(
            f"  {label:40s} accuracy {i['accuracy']:.4f} -> {h['accuracy']:.4f} ({r['accuracy']:.2f}x), "
            f"completeness {i['completeness']:.4f} -> {h['completeness']:.4f} ({r['completeness']:.2f}x)"
            + (
                f"; {','.join(subset)} only: {h['subset_accuracy']:.4f} ({r['subset_accuracy']:.2f}x)"
                if r.get("subset_accuracy")
                else ""
            )
        )
    for rig, c in ceiling.items():
        i, h = c["in_distribution"], c["held_out"]
        print(
            f"  decoded ground truth, {rig}: accuracy {i['accuracy']:.4f} -> {h['accuracy']:.4f} "
            f"({h['accuracy'] / i['accuracy']:.2f}x), completeness {i['completeness']:.4f} -> {h['completeness']:.4f}"
        )
    out = {
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "max_views": args.max_views,
        "subset": subset,
        "checkpoints": args.checkpoint,
        "scores": scores,
        "ratio_held_out_over_in_distribution": ratios,
        "decoded_ground_truth": ceiling,
        "machine": {"cores": os.cpu_count(), "threads": args.threads, "torch": torch.__version__},
        "wall_seconds": time.time() - t0,
    }
    if args.json:
        with atomic_output(Path(args.json), suffix=".json") as tmp:
            Path(tmp).write_text(json.dumps(out, indent=1) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
