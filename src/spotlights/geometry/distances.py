"""Nearest-neighbour and Chamfer distances between point sets: the one owner of every such metric.

numpy + KD-trees (:class:`~spotlights.geometry.neighbors.NearestNeighbors`); no torch. The
training losses (``spotlights.learning.losses``) have their own differentiable fast path and
are tested against this module.

For point sets ``X`` (K, 3) and ``Y`` (L, 3) in the same frame and units, with the unsquared
Euclidean nearest-neighbour distance ``d(x, Y) = min_y ||x - y||_2``:

* ``d_XY`` = (K,) ``d(x, Y)`` for every x (``squared``: ``d(x, Y)**2``), :func:`nearest_distances`;
* the point reduction of a side: ``mean`` (default) or ``sum`` over its points;
* :func:`chamfer_distance` combines the two sides by ``sum`` (default) or ``mean``, or
  returns one side (``single_directional``): the parameters of PyTorch3D's
  ``chamfer_distance`` (``norm=2`` there is ``squared=True`` here), in numpy.

The named metrics, each one setting of :func:`chamfer_distance` (prediction ``P``, ground
truth or reference ``G``; "mean" = mean over the points of the first set):

================  ===========================================  ==================================
metric            value                                        call
================  ===========================================  ==================================
accuracy          mean_p d(p, G)                               ``chamfer_distance(P, G, single_directional=True)``
completeness      mean_g d(g, P)                               ``chamfer_distance(G, P, single_directional=True)``
chamfer (Eq. 1)   mean_p d(p, G) + mean_g d(g, P)              ``chamfer_distance(P, G)``
chamfer_l1        (mean_p d(p, G) + mean_g d(g, P)) / 2        ``chamfer_distance(P, G, direction_reduction="mean")``
chamfer_l2        mean_p d(p, G)^2 + mean_g d(g, P)^2          ``chamfer_distance(P, G, squared=True)``
fscore(t)         2 prec rec / (prec + rec)                    share of P within t of G, of G within t of P
================  ===========================================  ==================================

``chamfer`` is the paper's Eq. (1) (the consistency metric ``cd`` of Table 2, PCN's
consistency); ``chamfer_l1`` is PCN's "CD-L1" (the same, halved; the L1 in the name is the
field's, the distances are Euclidean); ``chamfer_l2`` is Completion3D/TopNet's "CD-L2".

Empty sets: a mean over no points is NaN, a sum over no points is 0.

Batches: many query sets against one KD-tree are answered by one query of their concatenation
and split again with ``lengths`` (:func:`reduce_points`), as
:func:`spotlights.metrics.completion.evaluate_completions` does per ground-truth model.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .neighbors import NearestNeighbors, as_points

POINT_REDUCTIONS = ("mean", "sum", "none")
"""How :func:`chamfer_distance` reduces the distances of one side over its points."""

DIRECTION_REDUCTIONS = ("sum", "mean")
"""How :func:`chamfer_distance` combines the two sides: their sum (Eq. 1) or their mean (CD-L1)."""


def _points(x, what: str) -> np.ndarray:
    return x.points if isinstance(x, NearestNeighbors) else as_points(x, what)


def _tree(x) -> NearestNeighbors:
    return x if isinstance(x, NearestNeighbors) else NearestNeighbors(x)


def nearest_distances(source, target, squared: bool = False) -> np.ndarray:
    """Distance from every ``source`` point to its nearest ``target`` point.

    Parameters
    ----------
    source : (K, 3) float points, or a :class:`NearestNeighbors` (its points are used).
    target : (L, 3) float points (L >= 1), or a prebuilt :class:`NearestNeighbors` over them
        (reused: build one tree per target that is queried many times).
    squared : return squared distances.

    Returns
    -------
    (K,) float64, unsquared (or squared) Euclidean distances in the points' units. The query
    runs in the tree's dtype (float32 targets give float32-accurate distances).
    """
    d = _tree(target).distances(_points(source, "source"))
    return d * d if squared else d


def reduce_points(d: np.ndarray, reduction: str = "mean", lengths: Sequence[int] | np.ndarray | None = None):
    """Reduce per-point distances over the points of one set (or of each set of a batch).

    Parameters
    ----------
    d : (K,) distances (from :func:`nearest_distances`); with ``lengths``, the concatenation of
        S sets' distances, ``lengths[s]`` points each (sum(lengths) = K).
    reduction : ``"mean"`` (NaN over no points), ``"sum"`` (0 over no points) or ``"none"``
        (``d`` as it is).
    lengths : optional (S,) ints; then the result is (S,) float64, one value per set
        (segmented sums of ``np.add.reduceat``; a set of 0 points gets NaN / 0).

    Returns
    -------
    float (no ``lengths``), (S,) float64 (``lengths``), or ``d`` (``"none"``).
    """
    if reduction not in POINT_REDUCTIONS:
        raise ValueError(f"unknown point reduction {reduction!r}; use one of {', '.join(POINT_REDUCTIONS)}")
    if reduction == "none":
        return d
    d = np.asarray(d, dtype=np.float64)
    if lengths is None:
        if len(d) == 0:
            return float("nan") if reduction == "mean" else 0.0
        return float(d.mean()) if reduction == "mean" else float(d.sum())
    lengths = np.asarray(lengths, dtype=np.int64).reshape(-1)
    if int(lengths.sum()) != len(d) or (lengths < 0).any():
        raise ValueError(f"lengths sum to {int(lengths.sum())} but there are {len(d)} distances")
    out = np.full(len(lengths), np.nan if reduction == "mean" else 0.0)
    full = lengths > 0
    if full.any():
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])[full]
        sums = np.add.reduceat(d, starts)
        out[full] = sums / lengths[full] if reduction == "mean" else sums
    return out


def combine_directions(d_xy, d_yx, direction_reduction: str = "sum"):
    """The two-sided Chamfer value from its two reduced sides (floats or equal-shape arrays).

    ``"sum"``: ``d_xy + d_yx`` (the paper's Eq. (1), PyTorch3D's convention); ``"mean"``:
    ``(d_xy + d_yx) / 2`` (PCN's CD-L1).
    """
    if direction_reduction == "sum":
        return d_xy + d_yx
    if direction_reduction == "mean":
        return 0.5 * (d_xy + d_yx)
    raise ValueError(
        f"unknown direction reduction {direction_reduction!r}; use one of {', '.join(DIRECTION_REDUCTIONS)}"
    )


def chamfer_distance(
    x,
    y,
    *,
    squared: bool = False,
    single_directional: bool = False,
    point_reduction: str = "mean",
    direction_reduction: str = "sum",
):
    """Chamfer distance between two point sets, parametrised as PyTorch3D's ``chamfer_distance``.

    Parameters
    ----------
    x : (K, 3) float points, or a :class:`NearestNeighbors` over them (its tree is reused for
        the y -> x side).
    y : (L, 3) float points, or a :class:`NearestNeighbors` over them (reused for x -> y).
        Same frame and units as ``x``.
    squared : use squared Euclidean distances (PyTorch3D's ``norm=2``); default unsquared.
    single_directional : only the x -> y side: the reduction over x of d(x, y).
    point_reduction : ``"mean"`` (default), ``"sum"`` over the points of each side, or
        ``"none"``: the per-point distances, ``d_xy`` (K,) or the pair ``(d_xy, d_yx)``.
    direction_reduction : ``"sum"`` of the two sides (default, the paper's Eq. (1)) or their
        ``"mean"`` (PCN's CD-L1). Ignored with ``single_directional``.

    Returns
    -------
    float in the points' units (squared units with ``squared``); with ``point_reduction="none"``
    arrays as above. A mean over an empty set is NaN (an empty side makes the value NaN).
    """
    if point_reduction not in POINT_REDUCTIONS:
        raise ValueError(f"unknown point reduction {point_reduction!r}; use one of {', '.join(POINT_REDUCTIONS)}")
    if direction_reduction not in DIRECTION_REDUCTIONS:
        raise ValueError(
            f"unknown direction reduction {direction_reduction!r}; use one of {', '.join(DIRECTION_REDUCTIONS)}"
        )
    px, py = _points(x, "x"), _points(y, "y")
    empty = len(px) == 0 or len(py) == 0

    def side(a, b, pa):
        if empty:  # no nearest neighbour exists: NaN distances (an empty source gives no distances)
            return np.full(len(pa), np.nan)
        return nearest_distances(a, b, squared)

    d_xy = side(x, y, px)
    if single_directional:
        return d_xy if point_reduction == "none" else _reduce_side(d_xy, point_reduction, empty)
    d_yx = side(y, x, py)
    if point_reduction == "none":
        return d_xy, d_yx
    return combine_directions(
        _reduce_side(d_xy, point_reduction, empty), _reduce_side(d_yx, point_reduction, empty), direction_reduction
    )


def _reduce_side(d: np.ndarray, reduction: str, empty: bool) -> float:
    return float("nan") if empty else reduce_points(d, reduction)


# --- the named metrics ---------------------------------------------------------------------------
def accuracy(pred, gt) -> float:
    """One-sided Chamfer distance prediction -> ground truth (the paper's accuracy, Table 1).

    Mean over the (K, 3) predicted points of the unsquared Euclidean distance to the nearest of
    the (L, 3) ground-truth points (either may be a :class:`NearestNeighbors`). Same units as the
    inputs (unit frame). NaN when ``pred`` is empty.
    """
    return chamfer_distance(pred, gt, single_directional=True)


def completeness(pred, gt) -> float:
    """One-sided Chamfer distance ground truth -> prediction (the paper's completeness, Tables 3 and 4).

    Mean over the (L, 3) ground-truth points of the unsquared distance to the nearest of the
    (K, 3) predicted points. NaN when ``pred`` is empty.
    """
    return chamfer_distance(gt, pred, single_directional=True)


def chamfer_l1(pred, gt) -> float:
    """PCN's CD-L1: (accuracy + completeness) / 2, unsquared Euclidean distances (half the paper's Eq. (1))."""
    return chamfer_distance(pred, gt, direction_reduction="mean")


def chamfer_l2(pred, gt) -> float:
    """Completion3D's CD-L2: mean_p min_g |p-g|^2 + mean_g min_p |g-p|^2 (squared distances, sum of the two sides)."""
    return chamfer_distance(pred, gt, squared=True)


def fscore_from_shares(precision, recall):
    """2 P R / (P + R) from precision and recall (floats or arrays); 0 where P + R = 0."""
    p, r = np.asarray(precision, dtype=np.float64), np.asarray(recall, dtype=np.float64)
    s = p + r
    out = np.where(s > 0, 2.0 * p * r / np.where(s > 0, s, 1.0), 0.0)
    return float(out) if out.ndim == 0 else out


def fscore(pred, gt, threshold: float = 0.01) -> float:
    """F-score at ``threshold`` (same units as the points; the unit frame's 0.01 by default).

    Precision = share of the (K, 3) predicted points within ``threshold`` of the ground truth;
    recall = share of the (L, 3) ground-truth points within ``threshold`` of the prediction
    (distances <= threshold count); F = 2PR / (P + R), 0 when P + R = 0 or ``pred`` is empty
    (Tatarchenko et al.).
    """
    d_pg, d_gp = chamfer_distance(pred, gt, point_reduction="none")
    if len(d_pg) == 0:
        return 0.0
    return fscore_from_shares(float(np.mean(d_pg <= threshold)), float(np.mean(d_gp <= threshold)))
