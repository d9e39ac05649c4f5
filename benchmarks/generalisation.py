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

A body type held out instead of a source (``--held-out-category``): build the set with that
category all in test, train on it, and score its test split cut in two (the held-out
category against the other test cars)::

    spotlights dataset build --meshes ../shared/data/meshes/apolloscape-cars --category-split suv=test \
        --split 0.8/0.1/0.1 --views 2000 --rig box-128x128-ellipsoid-s1 --out nosuv.h5
    spotlights train --model sanet-hit --config src/spotlights/learning/configs/variants/sanet-hit-dense.yaml \
        --data nosuv.h5 --schedule fair --compile --out runs/sanet-hit-dense-nosuv
    python benchmarks/generalisation.py --in-dist nosuv.h5 --held-out-category suv \
        --checkpoint runs/sanet-hit-dense-nosuv/best.pt --max-views 50 --json nosuv.json

Numbers: unit frame (the box's half diagonal), means over scans; per category in the JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

from spotlights.data.store import open_dataset
from spotlights.geometry.distances import accuracy, completeness
from spotlights.geometry.encode import decode
from spotlights.learning.checkpoint import load_checkpoint, resolve_checkpoint
from spotlights.learning.evaluate import evaluate_checkpoints
from spotlights.outputs import atomic_output


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
            ck = Path(res["checkpoint"])  # a run's best.pt / last.pt named with its run folder: two runs differ
            name = f"{ck.parent.name}/{ck.name}" if ck.stem in ("best", "last") else ck.name
            label = name + (f" ({row['variant']})" if row["variant"] else "")
            s = row["summary"]
            out[label] = {
                "model": res["model"],
                **{
                    k: s["mean_over_samples"].get(k)
                    for k in ("accuracy", "completeness", "chamfer_l1", "fscore", "n_points")
                },
                "accuracy_per_category": {c: v.get("accuracy") for c, v in s["per_category"].items()},
                "completeness_per_category": {c: v.get("completeness") for c, v in s["per_category"].items()},
                "scans_per_category": {c: n for c, n in s["count"].items() if c != "all"},
            }
    return out


def weighted_mean(values: dict, counts: dict, categories) -> float | None:
    """Mean of the per-category means ``values`` over ``categories``, each weighted by its count in ``counts``
    (scans or models); None when none of them has any."""
    cats = [c for c in categories if counts.get(c)]
    n = sum(counts[c] for c in cats)
    return sum(values[c] * counts[c] for c in cats) / n if n else None


def subset_accuracy(row: dict, categories, metric: str = "accuracy") -> float | None:
    """Mean ``metric`` (accuracy or completeness) over the scans of ``categories`` (scan-weighted mean of the
    per-category means of a :func:`_rows` row); None when none of them was scored."""
    return weighted_mean(row[f"{metric}_per_category"], row["scans_per_category"], categories)


def split_by_category(row: dict, held: list[str]) -> tuple[dict, dict]:
    """A :func:`_rows` row of one test split cut into (in-distribution, held-out) rows: the scans of the
    categories in ``held`` against all the others (scan-weighted means)."""
    rest = [c for c in row["scans_per_category"] if c not in held]
    out = []
    for cats in (rest, held):
        r = {m: subset_accuracy(row, cats, m) for m in ("accuracy", "completeness")}
        r["scans"] = sum(row["scans_per_category"].get(c, 0) for c in cats)
        r["categories"] = cats
        out.append(r)
    return out[0], out[1]


def held_out_category_problem(path, held: list[str]) -> str | None:
    """Why ``path`` cannot serve a hold-out of the categories ``held`` (its train split has some of them, which
    would make the hold-out a lie, or its test split lacks some), or None when it can."""
    with open_dataset(path) as ds:
        cats = {str(ds.categories[m]) for m in ds.split_models("train")}
        test = {str(ds.categories[m]) for m in ds.split_models("test")}
    seen = sorted(cats & set(held))
    if seen:
        return f"{path}: its train split has {', '.join(seen)} models; build it with --category-split CAT=test"
    if not set(held) <= test:
        return f"{path}: its test split has no {', '.join(sorted(set(held) - test))} models"
    return None


def checkpoint_rigs(checkpoints) -> list[str]:
    """The dataset rigs the checkpoints were trained on (sorted, each once; none for the point-set models)."""
    rigs = {(load_checkpoint(resolve_checkpoint(c)).get("dataset") or {}).get("rig") for c in checkpoints}
    return sorted(r for r in rigs if r)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--in-dist", required=True, help="in-distribution dataset (its test split), e.g. cars.h5")
    ap.add_argument("--held-out", default=None, help="held-out dataset (its test split), e.g. kenney-test.h5")
    ap.add_argument(
        "--held-out-category",
        default=None,
        help="hold out body types instead of a source (comma-separated): the --in-dist file's test models of "
        "these categories are the held-out set, its other test models the in-distribution set; its train split "
        "must have none of them (build it with --category-split suv=test)",
    )
    ap.add_argument("--checkpoint", nargs="+", default=["default", "paper"], help="checkpoints or short names")
    ap.add_argument("--max-views", type=int, default=50, help="views per test model on both sets (default 50)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--subset",
        default="hatchback,sedan,suv",
        help="categories of the held-out set also scored on their own (default: the car-like Kenney vehicles)",
    )
    ap.add_argument(
        "--snap",
        type=float,
        nargs="+",
        default=[],
        metavar="R",
        help="also score every SA-Net with its rays snapped to the input within R (unit frame; rows '..., snap R')",
    )
    ap.add_argument("--snap-mirror", action="store_true", help="the --snap rows snap to the mirrored input too")
    ap.add_argument("--json", default=None, help="write the numbers here")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    t0 = time.time()
    if (args.held_out is None) == (args.held_out_category is None):
        ap.error("give exactly one of --held-out (a source) and --held-out-category (body types)")
    if args.snap_mirror and not args.snap:
        ap.error("--snap-mirror goes with --snap R")
    if any(not (r > 0 and r < float("inf")) for r in args.snap):
        ap.error("--snap radii must be finite numbers > 0")
    if args.held_out_category and args.snap:
        ap.error("--snap is not scored with --held-out-category (only with --held-out)")
    if args.held_out_category:
        return by_category(args, [c.strip() for c in args.held_out_category.split(",") if c.strip()], t0)
    scores = {}
    for key, path in (("in_distribution", args.in_dist), ("held_out", args.held_out)):
        rows: dict = {}
        for snap in [None, *args.snap]:
            rep = evaluate_checkpoints(
                args.checkpoint,
                path,
                split="test",
                max_views=args.max_views,
                progress=False,
                snap=snap,
                snap_mirror=args.snap_mirror and snap is not None,
            )
            rows.update(_rows(rep))
        scores[key] = {
            "data": str(path),
            "n_samples": rep["n_samples"],
            "n_models": rep["n_models"],
            "rows": rows,
        }
    ceiling = {}
    for rig in checkpoint_rigs(args.checkpoint):
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
        "snap": args.snap,
        "snap_mirror": args.snap_mirror,
        "scores": scores,
        "ratio_held_out_over_in_distribution": ratios,
        "decoded_ground_truth": ceiling,
        "machine": {"cores": os.cpu_count(), "threads": args.threads, "torch": torch.__version__},
        "wall_seconds": time.time() - t0,
    }
    _write(args.json, out)


def _write(path, out: dict) -> None:
    if path:
        with atomic_output(Path(path), suffix=".json") as tmp:
            Path(tmp).write_text(json.dumps(out, indent=1) + "\n")
        print(f"wrote {path}")


def by_category(args, held: list[str], t0: float) -> None:
    """The body-type hold-out: one evaluation of the test split, cut into held-out and other categories."""
    problem = held_out_category_problem(args.in_dist, held)
    if problem:
        print(problem, file=sys.stderr)
        raise SystemExit(2)
    rep = evaluate_checkpoints(args.checkpoint, args.in_dist, split="test", max_views=args.max_views, progress=False)
    rows, ratios = {}, {}
    print(f"held-out body types {', '.join(held)} / the other test models (first {args.max_views} views per model):")
    for label, row in _rows(rep).items():
        i, h = split_by_category(row, held)
        rows[label] = {"in_distribution": i, "held_out": h}
        ratios[label] = {k: h[k] / i[k] for k in ("accuracy", "completeness") if i[k] and h[k] is not None}
        print(
            f"  {label:40s} accuracy {i['accuracy']:.4f} -> {h['accuracy']:.4f} ({ratios[label]['accuracy']:.2f}x), "
            f"completeness {i['completeness']:.4f} -> {h['completeness']:.4f} ({ratios[label]['completeness']:.2f}x)"
        )
    ceiling = {}
    for rig in checkpoint_rigs(args.checkpoint):
        per = decode_ceiling(args.in_dist, rig)["per_category"]
        models = {c: v["models"] for c, v in per.items()}
        cut = {}
        for key, cats in (("in_distribution", [c for c in per if c not in held]), ("held_out", held)):
            cut[key] = {
                m: weighted_mean({c: v[m] for c, v in per.items()}, models, cats) for m in ("accuracy", "completeness")
            }
            cut[key]["models"] = sum(models.get(c, 0) for c in cats)
        ceiling[rig] = cut
        i, h = cut["in_distribution"], cut["held_out"]
        print(
            f"  decoded ground truth, {rig}: accuracy {i['accuracy']:.4f} -> {h['accuracy']:.4f} "
            f"({h['accuracy'] / i['accuracy']:.2f}x)"
        )
    _write(
        args.json,
        {
            "date": time.strftime("%Y-%m-%d %H:%M"),
            "data": str(args.in_dist),
            "held_out_categories": held,
            "max_views": args.max_views,
            "checkpoints": args.checkpoint,
            "n_samples": rep["n_samples"],
            "rows": rows,
            "ratio_held_out_over_in_distribution": ratios,
            "decoded_ground_truth": ceiling,
            "machine": {"cores": os.cpu_count(), "threads": args.threads, "torch": torch.__version__},
            "wall_seconds": time.time() - t0,
        },
    )


if __name__ == "__main__":
    main()
