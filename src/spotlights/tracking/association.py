"""Matching boxes to tracks: 3-D GIoU of oriented boxes, centre distances, and the optimal assignment.

Boxes here are rows of a (N, 7) float64 array ``(x, y, z, yaw, l, w, h)``: centre (metres), heading about +z
(radians), length, width, height (metres), all in one frame whose z axis is up. Boxes turn about z only: the
bird's-eye footprint is a rectangle, the vertical extent an interval.

3-D GIoU (Rezatofighi et al., 2019, in its 3-D form as AB3DMOT and SimpleTrack use it)::

    I = area(footprint_a ∩ footprint_b) * overlap of the z intervals
    U = vol_a + vol_b - I
    C = area(convex hull of both footprints) * (max top - min bottom)
    GIoU = I / U - (C - U) / C                      in (-1, 1]; 1 for identical boxes

Footprint intersections and hulls are computed by shapely (vectorised over the pairs), only for pairs whose centres
are within a gate; other pairs get ``-inf`` (never matched). The assignment is
:func:`scipy.optimize.linear_sum_assignment` on the negated similarity, keeping only pairs past the threshold.
"""

from __future__ import annotations

import numpy as np

#: (4, 2) signs of a footprint's corners along the box's length and width, counter-clockwise.
_FOOT = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])


def footprints(boxes: np.ndarray) -> np.ndarray:
    """(N, 4, 2) float64 bird's-eye corners (x, y), counter-clockwise, of boxes (N, 7) ``(x, y, z, yaw, l, w, h)``."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
    c, s = np.cos(b[:, 3]), np.sin(b[:, 3])
    local = _FOOT[None] * (0.5 * b[:, None, 4:6])  # (N, 4, 2) along length, width
    x = b[:, None, 0] + c[:, None] * local[..., 0] - s[:, None] * local[..., 1]
    y = b[:, None, 1] + s[:, None] * local[..., 0] + c[:, None] * local[..., 1]
    return np.stack([x, y], axis=-1)


def centre_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) float64 Euclidean distances, metres, between the centres of boxes a (N, 7) and b (M, 7)."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 7)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 7)
    return np.linalg.norm(a[:, None, :3] - b[None, :, :3], axis=-1)


def lateral_offsets(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) float64 bird's-eye distances, metres, of the centres of boxes b (M, 7) from the line through each box
    of a (N, 7) along its heading: ``|(c_b - c_a) . (-sin yaw_a, cos yaw_a)|``, how far b lies to a's side."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 7)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 7)
    d = b[None, :, :2] - a[:, None, :2]
    return np.abs(-np.sin(a[:, 3])[:, None] * d[..., 0] + np.cos(a[:, 3])[:, None] * d[..., 1])


def giou_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K,) float64 3-D GIoU of the box pairs a[k], b[k] (both (K, 7)); see the module docstring."""
    import shapely

    a = np.asarray(a, dtype=np.float64).reshape(-1, 7)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 7)
    if len(a) == 0:
        return np.zeros(0)
    fa, fb = footprints(a), footprints(b)
    pa, pb = shapely.polygons(fa), shapely.polygons(fb)
    area_i = shapely.area(shapely.intersection(pa, pb))
    hull = shapely.area(shapely.convex_hull(shapely.multipoints(np.concatenate([fa, fb], axis=1))))
    lo_a, hi_a = a[:, 2] - 0.5 * a[:, 6], a[:, 2] + 0.5 * a[:, 6]
    lo_b, hi_b = b[:, 2] - 0.5 * b[:, 6], b[:, 2] + 0.5 * b[:, 6]
    dz = np.clip(np.minimum(hi_a, hi_b) - np.maximum(lo_a, lo_b), 0.0, None)
    inter = area_i * dz
    vol_a = a[:, 4] * a[:, 5] * a[:, 6]
    vol_b = b[:, 4] * b[:, 5] * b[:, 6]
    union = vol_a + vol_b - inter
    enclosing = hull * (np.maximum(hi_a, hi_b) - np.minimum(lo_a, lo_b))
    with np.errstate(invalid="ignore", divide="ignore"):
        g = inter / union - (enclosing - union) / enclosing
    return np.where(np.isfinite(g), g, -1.0)


def giou_matrix(a: np.ndarray, b: np.ndarray, gate_m: float | np.ndarray = np.inf) -> np.ndarray:
    """(N, M) float64 3-D GIoU of every pair of boxes a (N, 7) and b (M, 7); pairs whose centres are farther apart
    than ``gate_m`` metres (a number, or (N,) one per box of ``a``) are not computed and get ``-inf``."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 7)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 7)
    out = np.full((len(a), len(b)), -np.inf)
    if out.size == 0:
        return out
    ii, jj = np.nonzero(centre_distances(a, b) <= np.reshape(np.asarray(gate_m, dtype=np.float64), (-1, 1)))
    out[ii, jj] = giou_pairs(a[ii], b[jj])
    return out


def assign(similarity: np.ndarray, threshold: float) -> list[tuple[int, int]]:
    """The one-to-one matching of rows to columns that maximises the summed margin ``similarity - threshold`` over
    the matched pairs, among pairs whose similarity exceeds ``threshold`` (others, ``-inf`` among them, are never
    matched): (row, column) pairs, by row.

    :func:`scipy.optimize.linear_sum_assignment` on the cost ``-(similarity - threshold)`` for the pairs past the
    threshold and 0 for the others (an unmatched row or column gains nothing), then the zero-cost pairs dropped.
    """
    from scipy.optimize import linear_sum_assignment

    s = np.asarray(similarity, dtype=np.float64)
    if s.size == 0:
        return []
    ok = s > threshold
    if not ok.any():
        return []
    cost = np.where(ok, threshold - np.where(ok, s, 0.0), 0.0)
    rows, cols = linear_sum_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols) if ok[r, c]]
