"""Point-cloud completion metrics (numpy + KD-trees; no torch).

All distances are **unsquared Euclidean distances in the unit frame** (the
object's circumscribed sphere has radius 1) unless a name says ``squared``.
For a prediction ``P`` and a ground truth ``G`` (the paper: 16,384 dense
surface samples):

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
* ``hit_ratio(depths)``   = share of rays with depth > threshold (a Spotlights
  array; the paper's Table 5 uses threshold 0, i.e. hits over cast rays).

Nearest neighbours come from a KD-tree (``pykdtree`` when installed, else
``scipy.spatial.cKDTree``) built once per ground-truth model and queried with
the concatenated predictions of all that model's samples (see
:func:`evaluate_completions`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geometry.neighbors import NearestNeighbors, _as_points, nearest_distances  # noqa: F401  (re-exported)

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


def accuracy(pred: np.ndarray, gt: np.ndarray) -> float:
    """One-sided Chamfer distance pred -> gt (the paper's accuracy, Table 1).

    Mean over the (K, 3) predicted points of the unsquared Euclidean distance to the
    nearest of the (L, 3) ground-truth points. Same units as the inputs (unit frame).
    NaN when ``pred`` is empty.
    """
    pred = _as_points(pred, "pred")
    if len(pred) == 0:
        return float("nan")
    return float(nearest_distances(pred, gt).mean())


def completeness(pred: np.ndarray, gt: np.ndarray) -> float:
    """One-sided Chamfer distance gt -> pred: mean over gt points of the unsquared NN distance to pred.

    NaN when ``pred`` is empty.
    """
    pred = _as_points(pred, "pred")
    if len(pred) == 0:
        return float("nan")
    return float(nearest_distances(gt, pred).mean())


def chamfer_l1(pred: np.ndarray, gt: np.ndarray) -> float:
    """Symmetric CD-L1 (PCN convention): (accuracy + completeness) / 2, unsquared distances."""
    return 0.5 * (accuracy(pred, gt) + completeness(pred, gt))


def chamfer_l2(pred: np.ndarray, gt: np.ndarray) -> float:
    """Symmetric CD-L2 (Completion3D convention): mean_p min_g |p-g|^2 + mean_g min_p |g-p|^2."""
    pred = _as_points(pred, "pred")
    if len(pred) == 0:
        return float("nan")
    return float(np.mean(nearest_distances(pred, gt) ** 2) + np.mean(nearest_distances(gt, pred) ** 2))


def fscore(pred: np.ndarray, gt: np.ndarray, threshold: float = 0.01) -> float:
    """F-score at ``threshold`` (unit-frame distance): 2PR/(P+R), 0 when P + R = 0.

    Precision = share of predicted points within ``threshold`` of gt; recall = share
    of gt points within ``threshold`` of pred (distances <= threshold count).
    """
    pred = _as_points(pred, "pred")
    if len(pred) == 0:
        return 0.0
    p = float(np.mean(nearest_distances(pred, gt) <= threshold))
    r = float(np.mean(nearest_distances(gt, pred) <= threshold))
    return 2.0 * p * r / (p + r) if p + r > 0 else 0.0


def hit_ratio(depths: np.ndarray, threshold: float = 0.0) -> np.ndarray | float:
    """Share of rays kept along the last axis of a depth array.

    Parameters
    ----------
    depths : (..., N*M) depths (0 = miss).
    threshold : with 0 (default) a ray counts when depth > 0 (the paper's hit ratio);
        with a clip value t > 0, when depth >= t (the rays an SA-Net prediction keeps).

    Returns
    -------
    float for a 1-D array, else (...) float64 array.
    """
    d = np.asarray(depths)
    kept = d > 0 if threshold <= 0 else d >= threshold
    out = kept.mean(axis=-1)
    return float(out) if out.ndim == 0 else out


def _fscore_from(p_within: np.ndarray, r_within: np.ndarray) -> np.ndarray:
    p, r = p_within, r_within
    s = p + r
    return np.where(s > 0, 2.0 * p * r / np.where(s > 0, s, 1.0), 0.0)


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
        q = np.concatenate([_as_points(predictions[i], "prediction") for i in sel], axis=0)
        d = trees[m].distances(q)
        starts = np.concatenate([[0], np.cumsum(sizes[sel])[:-1]])
        counts = sizes[sel]
        acc[sel] = np.add.reduceat(d, starts) / counts
        acc_sq[sel] = np.add.reduceat(d * d, starts) / counts
        prec[sel] = np.add.reduceat((d <= fscore_threshold).astype(np.float64), starts) / counts
    out["accuracy"] = acc
    if not with_completeness:
        return out
    comp = np.full(s_total, np.nan)
    comp_sq = np.full(s_total, np.nan)
    rec = np.zeros(s_total)
    for i in np.flatnonzero(sizes > 0):
        g = gt_dense[model_index[i]]
        d = NearestNeighbors(predictions[i]).distances(g)
        comp[i] = d.mean()
        comp_sq[i] = np.mean(d * d)
        rec[i] = np.mean(d <= fscore_threshold)
    out["completeness"] = comp
    out["chamfer_l1"] = 0.5 * (acc + comp)
    out["chamfer_l2"] = acc_sq + comp_sq
    out["fscore"] = _fscore_from(prec, rec)
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
    res = {"per_category": {}, "mean_over_samples": {}, "mean_over_categories": {}, "count": {}, "undefined": {}}
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
