"""Point-cloud completion metrics: batched evaluation and aggregation (numpy; no torch).

Every distance metric is defined once, in :mod:`spotlights.geometry.distances` (re-exported
here): all distances are **unsquared Euclidean distances in the unit frame** (the object's
circumscribed sphere has radius 1) unless a name says ``l2``. For a prediction ``P`` and a
ground truth ``G`` (the paper: 16,384 dense surface samples):

* ``accuracy(P, G)``      = mean over p in P of min_g ||p - g||       (one-sided
  Chamfer distance prediction -> ground truth; the paper's Table 1 metric)
* ``completeness(P, G)``  = mean over g in G of min_p ||g - p||       (one-sided,
  ground truth -> prediction; the paper's ablation metric, after [acccomp])
* ``chamfer_l1(P, G)``    = (accuracy + completeness) / 2             (PCN's CD:
  mean of the two one-sided means of unsquared distances)
* ``chamfer_l2(P, G)``    = mean_p min_g ||p-g||^2 + mean_g min_p ||g-p||^2
  (Completion3D/TopNet's CD: sum of the two one-sided means of squared distances)
* ``fscore(P, G, t)``     = 2 prec rec / (prec + rec), prec = share of P within
  ``t`` of G, rec = share of G within ``t`` of P (Tatarchenko et al.; t = 0.01)
* ``kept_ratio(depths, clip)`` = share of rays a prediction keeps (depth > 0, or
  >= the clip); with clip 0 the paper's hit ratio (Table 5 reports it after the clip).

Nearest neighbours come from a KD-tree (``pykdtree`` when installed, else
``scipy.spatial.cKDTree``) built once per ground-truth model and queried with
the concatenated predictions of all that model's samples (see
:func:`evaluate_completions`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geometry.distances import (  # noqa: F401  (re-exported: the distance kernels' owner is geometry.distances)
    accuracy,
    chamfer_l1,
    chamfer_l2,
    combine_directions,
    completeness,
    fscore,
    fscore_from_shares,
    nearest_distances,
    reduce_points,
)
from ..geometry.neighbors import NearestNeighbors, as_points

METRIC_NAMES = ("accuracy", "completeness", "chamfer_l1", "chamfer_l2", "fscore")
"""Per-sample metrics computed by :func:`evaluate_completions`, in report order."""

METRIC_DESCRIPTIONS = {
    "accuracy": "one-sided CD prediction -> dense GT: mean over predicted points of the unsquared NN distance (unit frame)",
    "completeness": "one-sided CD dense GT -> prediction: mean over GT points of the unsquared NN distance (unit frame)",
    "chamfer_l1": "symmetric CD-L1 (PCN): (accuracy + completeness) / 2",
    "chamfer_l2": "symmetric CD-L2 (Completion3D): mean squared NN distance pred->GT + mean squared NN distance GT->pred",
    "fscore": "F-score at threshold t (default 0.01): harmonic mean of precision (pred within t of GT) and recall (GT within t of pred)",
    "hit_ratio": "share of rays kept (depth > 0, or >= clip when clipped) over all rays of the rig",
    "n_points": "number of predicted points",
}


def kept_ratio(depths: np.ndarray, clip: float = 0.0) -> np.ndarray | float:
    """Share of rays a (predicted) depth array keeps, along its last axis.

    Not :func:`spotlights.geometry.encode.hit_ratio` (the share of hits of an encoding, over
    every entry): this one counts per array and knows SA-Net's clip.

    Parameters
    ----------
    depths : (..., N*M) depths (0 = miss).
    clip : with 0 (default) a ray counts when depth > 0 (the paper's hit ratio);
        with a clip value t > 0, when depth >= t (the rays an SA-Net prediction keeps).

    Returns
    -------
    float for a 1-D array, else (...) float64 array.
    """
    d = np.asarray(depths)
    kept = d > 0 if clip <= 0 else d >= clip
    out = kept.mean(axis=-1)
    return float(out) if out.ndim == 0 else out


def evaluate_completions(
    predictions: Sequence[np.ndarray],
    model_index: np.ndarray,
    gt_dense: np.ndarray | Sequence[np.ndarray],
    fscore_threshold: float = 0.01,
    with_completeness: bool = True,
    trees: dict | None = None,
) -> dict[str, np.ndarray]:
    """All per-sample metrics for many predictions, one KD-tree per ground-truth model.

    Parameters
    ----------
    predictions : S arrays (K_s, 3) float32/float64, unit frame (K_s may vary, may be 0).
    model_index : (S,) int, row of each sample's ground truth in ``gt_dense``.
    gt_dense : (n_models, L, 3) array or sequence of (L_m, 3) arrays, unit frame.
    fscore_threshold : F-score distance threshold (unit frame).
    with_completeness : also compute the gt -> pred direction (completeness, CD-L1,
        CD-L2, F-score); it builds one small tree per prediction.
    trees : optional cache ``model row -> NearestNeighbors`` reused across calls.

    Returns
    -------
    dict of (S,) float64 arrays: ``accuracy`` and ``n_points`` always; with
    completeness also ``completeness``, ``chamfer_l1``, ``chamfer_l2``, ``fscore``.
    Samples with an empty prediction get NaN distances and F-score 0.
    """
    model_index = np.asarray(model_index, dtype=np.int64).reshape(-1)
    s_total = len(predictions)
    if len(model_index) != s_total:
        raise ValueError(f"{s_total} predictions but {len(model_index)} model indices")
    trees = {} if trees is None else trees
    sizes = np.array([len(p) for p in predictions], dtype=np.int64)
    acc = np.full(s_total, np.nan)
    acc_sq = np.full(s_total, np.nan)
    prec = np.zeros(s_total)
    out: dict[str, np.ndarray] = {"n_points": sizes.astype(np.float64)}
    for m in np.unique(model_index):
        sel = np.flatnonzero((model_index == m) & (sizes > 0))
        if len(sel) == 0:
            continue
        if m not in trees:
            trees[m] = NearestNeighbors(gt_dense[m])
        # one query of every prediction of this model, split again per sample
        q = np.concatenate([as_points(predictions[int(i)], "prediction") for i in sel], axis=0)
        d = nearest_distances(q, trees[m])
        acc[sel] = reduce_points(d, "mean", lengths=sizes[sel])
        acc_sq[sel] = reduce_points(d * d, "mean", lengths=sizes[sel])
        prec[sel] = reduce_points((d <= fscore_threshold).astype(np.float64), "mean", lengths=sizes[sel])
    out["accuracy"] = acc
    if not with_completeness:
        return out
    comp = np.full(s_total, np.nan)
    comp_sq = np.full(s_total, np.nan)
    rec = np.zeros(s_total)
    for i in np.flatnonzero(sizes > 0):
        g = gt_dense[model_index[i]]
        d = nearest_distances(g, predictions[int(i)])
        comp[i] = reduce_points(d, "mean")
        comp_sq[i] = reduce_points(d * d, "mean")
        rec[i] = reduce_points((d <= fscore_threshold).astype(np.float64), "mean")
    out["completeness"] = comp
    out["chamfer_l1"] = combine_directions(acc, comp, "mean")
    out["chamfer_l2"] = combine_directions(acc_sq, comp_sq, "sum")
    out["fscore"] = fscore_from_shares(prec, rec)
    return out


def summarize(per_sample: dict[str, np.ndarray], categories: Sequence[str], order: Sequence[str] | None = None) -> dict:
    """Aggregate per-sample metrics per category and overall.

    Parameters
    ----------
    per_sample : metric name -> (S,) values (NaN = undefined, e.g. an empty prediction).
    categories : (S,) category of each sample.
    order : category order for the report (default: sorted).

    Returns
    -------
    dict with
      ``per_category``: {category: {metric: mean over that category's samples}},
      ``mean_over_samples``: {metric: mean over all samples (each sample weighs 1)},
      ``mean_over_categories``: {metric: unweighted mean of the per-category means},
      ``count``: {category: number of samples, "all": S},
      ``undefined``: {metric: number of NaN samples excluded from the means}.
    Means ignore NaN samples (they are counted in ``undefined``).
    """
    cats = np.asarray([str(c) for c in categories])
    names = sorted(set(cats.tolist())) if order is None else [c for c in order if c in set(cats.tolist())]
    res: dict[str, dict] = {
        "per_category": {},
        "mean_over_samples": {},
        "mean_over_categories": {},
        "count": {},
        "undefined": {},
    }
    for c in names:
        res["count"][c] = int(np.sum(cats == c))
    res["count"]["all"] = int(len(cats))
    for metric, values in per_sample.items():
        v = np.asarray(values, dtype=np.float64)
        res["undefined"][metric] = int(np.sum(np.isnan(v)))
        per_cat = {}
        for c in names:
            vc = v[cats == c]
            per_cat[c] = float(np.nanmean(vc)) if np.any(~np.isnan(vc)) else float("nan")
            res["per_category"].setdefault(c, {})[metric] = per_cat[c]
        res["mean_over_samples"][metric] = float(np.nanmean(v)) if np.any(~np.isnan(v)) else float("nan")
        vals = [x for x in per_cat.values() if not np.isnan(x)]
        res["mean_over_categories"][metric] = float(np.mean(vals)) if vals else float("nan")
    return res
