"""Per class and per source accuracy / completeness of checkpoints on one split of a dataset.

Each sample is scored as ``spotlights evaluate`` scores it (the model's output as it is, unit frame, against the
model's dense ground truth), grouped by its model's source (the name's first part: ``apolloscape-cars``,
``kenney-test``, ``procedural``) and class (``/models/class``), and the share of its points inside the box grown
by 0.15 m (the network's own, no clamp) is counted. A class-conditioned checkpoint gets each sample's class.

    python benchmarks/class_eval.py --data product.h5 --checkpoint default run/best.pt --max-views 100 \\
        --json docs/results/classes/synthetic.json
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict

import numpy as np
import torch

from spotlights.geometry.box_clamp import grown_half_extents
from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint
from spotlights.learning.data import TorchCompletionDataset
from spotlights.learning.rays import DirectionTable
from spotlights.metrics.completion import evaluate_completions


def score(checkpoint: str, ds: TorchCompletionDataset, dense: dict, batch: int = 32) -> dict:
    """{group: {"n", "accuracy", "completeness", "chamfer_l1", "inside"}} means over the samples of each group."""
    ckpt = load_checkpoint(checkpoint)
    model = model_from_checkpoint(ckpt, "cpu")
    rays = DirectionTable(model.rig, ds.extents)
    half = grown_half_extents(ds.sizes)  # (n_models, 3) grown box, unit frame
    preds, rows = [], []
    t0 = time.perf_counter()
    with torch.inference_mode():
        for s in range(0, len(ds), batch):
            items = [ds[i] for i in range(s, min(len(ds), s + batch))]
            x = torch.stack([it["partial"] for it in items])
            m = torch.stack([it["model"] for it in items])
            cls = None
            if getattr(model, "class_embedding", None) is not None:
                cls = model.class_indices(ds.classes[m.numpy()])
            dirs = rays.directions(m)
            out = model(x, cls)
            preds.extend(p.numpy() for p in model.outputs_to_points(out, directions=dirs))
            rows.extend(m.tolist())
    seconds = time.perf_counter() - t0
    rows = np.asarray(rows)
    per = evaluate_completions(preds, rows, _Dense(dense), 0.01, True, {})
    inside = np.array(
        [np.mean(np.all(np.abs(p) <= half[r], axis=1)) if len(p) else np.nan for p, r in zip(preds, rows)]
    )
    groups = defaultdict(list)
    for i, r in enumerate(rows):
        src = str(ds.info.names[r]).split("/")[0]
        cls_name = str(ds.classes[r])
        for g in (f"{src}/{cls_name}", src, f"all/{cls_name}"):
            groups[g].append(i)
    out = {"checkpoint": checkpoint, "seconds": round(seconds, 1), "groups": {}}
    for g, idx in sorted(groups.items()):
        idx = np.asarray(idx)
        out["groups"][g] = {
            "n": int(len(idx)),
            "models": int(len(set(rows[idx].tolist()))),
            "accuracy": float(np.nanmean(per["accuracy"][idx])),
            "completeness": float(np.nanmean(per["completeness"][idx])),
            "chamfer_l1": float(np.nanmean(per["chamfer_l1"][idx])),
            "inside": float(np.nanmean(inside[idx])),
        }
    return out


class _Dense:
    def __init__(self, d: dict):
        self.d = d

    def __getitem__(self, m):
        return self.d[int(m)]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--checkpoint", nargs="+", required=True)
    p.add_argument("--split", default="test")
    p.add_argument("--max-views", type=int, default=100)
    p.add_argument("--json", default=None)
    a = p.parse_args()
    torch.set_num_threads(1)
    ds = TorchCompletionDataset(a.data, a.split, rig=False, max_views=a.max_views, partials_in_memory=True)
    dense = ds.gt_dense()
    results = [score(c, ds, dense) for c in a.checkpoint]
    for r in results:
        print(r["checkpoint"], f"({r['seconds']} s)")
        for g, v in r["groups"].items():
            print(
                f"  {g:32s} n={v['n']:5d} models={v['models']:3d} acc={v['accuracy']:.5f} "
                f"comp={v['completeness']:.5f} cd={v['chamfer_l1']:.5f} inside={v['inside']:.3f}"
            )
    if a.json:
        with open(a.json, "w", encoding="utf-8") as f:
            json.dump({"data": a.data, "split": a.split, "max_views": a.max_views, "results": results}, f, indent=1)


if __name__ == "__main__":
    main()
