"""Per-ray evidence of a partial scan: the observed points near each ray, and the free space it crosses.

No learning (numpy only). The ray-local SA-Net (``sanet-local``, :mod:`spotlights.learning.evidence`
batches the same definitions in torch) gives every ray of a rig what the scan says along its line.
Everything is in the unit frame of the object's box; a ray is ``P = o + 2 t d`` (``o`` on the unit
sphere, ``d`` a unit direction, ``t`` the rig's normalised depth, ``0 <= t <= h = -o . d``, half
the ray's chord through the unit sphere).

Angular grids
-------------
Both kinds of evidence look the scan up in an *angular grid* around a centre of projection ``c``
(a rig viewpoint, or the LiDAR): with the frame ``(u, v, w)`` of :func:`spotlights.geometry.lattice.viewpoint_frames`
for ``c / |c|`` (``w`` points from ``c`` toward the box centre), a direction ``x`` maps to its
stereographic coordinates ``s = (x.u, x.v) / (1 + x.w)`` (conformal, finite for every direction
but ``-w``), and ``s`` to the cell ``floor((s + a) / (2a) * G)`` of a ``G x G`` grid over
``[-a, a]^2`` (directions outside it fall in no cell). A cell keeps, of the scan points whose
direction from ``c`` falls in it, the one nearest to ``c`` (the first surface seen in that
direction; ties: the lower point index).

Near-ray evidence (:func:`near_ray_evidence`)
---------------------------------------------
Viewpoint ``i``'s grid has ``a`` = the largest stereographic coordinate (in absolute value, at least 1e-6) of
the rig's rays, each in its own viewpoint's frame, over every viewpoint; ``G = near_cells``. A ray of viewpoint ``i`` with direction ``d``
looks at the 2 x 2 cells nearest to ``s(d)`` (the cells ``floor(q - 1/2) + {0, 1}`` per axis,
``q`` its grid coordinate): up to 4 *candidates*, each the point of its cell nearest to ``o_i``.
A candidate ``x`` has depth ``t = (x - o).d / 2`` and distance to the line ``delta = |x - o - 2 t d|``;
it counts when ``t > 0`` and ``delta <= radius``. Returned per ray: the candidates sorted by
``delta`` (counted ones first; ``depth``, ``distance``, ``valid`` (R, 4)) and ``count`` (R,) in 0..4.
This is an angular-grid stand-in for "the k points nearest to the line": exact for the points it
returns, but a point hidden behind a nearer one of the same cell (seen from ``o_i``) is not
returned (it is occluded from there anyway).

Free space (:func:`carved_depths`)
----------------------------------
The segment from the LiDAR at ``S`` to each observed point is empty. The LiDAR's grid has
``G = carve_cells`` over the stereographic disc of the unit sphere seen from ``S``
(``a = tan(alpha / 2)``, ``sin alpha = 1 / |S|``; ``a = 1`` when ``|S| <= 1``). A place ``y`` is
*carved* (observed empty) when its direction from ``S`` falls in a cell that holds a point and
``|y - S| < rho_cell - margin``, ``rho_cell`` the distance from ``S`` to that cell's nearest
point. Each ray is sampled at ``T = carve_samples`` depths, the centres of ``T`` equal bins of
``[0, h]``: ``t_j = (j + 1/2) h / T``; bin ``j`` is carved when its centre is. A NaN ``S``
(unknown sensor) carves nothing. :func:`free_space_decode` uses the bins at decoding: a predicted
surface inside a carved bin moves to the start of the next bin that is not carved, or is
dropped when every bin after it is carved.

Snapping to the observed points (:func:`snap_to_observed`)
----------------------------------------------------------
At decoding (no learning, off unless asked: ``--snap R``), a ray that passes within ``R`` of an observed
point takes its depth from the scan instead of the network: of the ray's counted near-ray candidates
(above, radius ``R``) the one nearest to its line, ``x`` with normal ``n`` (:func:`point_normals`: the
least-variance axis of its 8 nearest observed points), gives the depth where the ray meets the plane
through ``x`` normal to ``n`` when that meeting point is within ``R`` of ``x``, ahead of the origin, and
the ray is not grazing (``|d . n| >= 0.3``); else the depth of ``x``'s foot on the line (``t`` above). The
ray is kept (a hit) whatever the network said. Rays without a candidate keep the network's depth and hit.

*Occlusion* (when the LiDAR's origin ``S`` is known): a ray's candidate is the first observed point seen from
the ray's *viewpoint*, which may lie on the far side of the object, behind a near surface the network drew
rightly. So a ray the network kept is not snapped onto a candidate more than ``R`` beyond its predicted
surface (``2 (t_snap - t_pred) > R``) unless that surface lies in observed free space (its bin is carved,
above, from the points actually observed: not their mirror image): a surface the LiDAR saw through is wrong,
one it did not is kept. Without a sensor origin (NaN, or at the box's centre: a scan given in its object's own
frame) the rule cannot be applied and every candidate snaps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError, parameter_names, shown
from .lattice import viewpoint_frames

NEAR_CANDIDATES = 4
"""Candidates per ray: the 2 x 2 cells around the ray's direction in its viewpoint's grid."""


@dataclass(frozen=True)
class EvidenceParams:
    """Parameters of the per-ray evidence (see the module docstring).

    near_cells : G of each viewpoint's angular grid (default 32). radius : largest distance of a
    counted point to the ray's line, unit frame (0.05, about 13 cm on a car). carve_cells : G of the
    LiDAR's grid (32). carve_samples : T depth bins per ray (8). margin : unit-frame distance in front
    of an observed point that is not carved (0.02: LiDAR noise).
    """

    near_cells: int = 32
    radius: float = 0.05
    carve_cells: int = 32
    carve_samples: int = 8
    margin: float = 0.02

    def __post_init__(self):
        for name in ("near_cells", "carve_cells", "carve_samples"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not self.radius > 0 or not self.margin >= 0:
            raise ValueError(f"radius must be > 0 and margin >= 0, got {self.radius}, {self.margin}")


def stereo_frames(centres: np.ndarray) -> np.ndarray:
    """(..., 3, 3) float64 frames (rows u, v, w; ``w = -c / |c|``) of centres of projection ``c`` (..., 3).

    The rig's own viewpoint frames (:func:`~spotlights.geometry.lattice.viewpoint_frames` of ``c / |c|``)."""
    c = np.asarray(centres, dtype=np.float64)
    flat = c.reshape(-1, 3)
    n = np.linalg.norm(flat, axis=1, keepdims=True)
    return viewpoint_frames(flat / np.where(n > 0, n, 1.0)).reshape(c.shape[:-1] + (3, 3))


def stereo_coords(directions: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """(..., 2) float64 stereographic coordinates ``(x.u, x.v) / (1 + x.w)`` of unit directions (..., 3)
    in ``frames`` (..., 3, 3) (broadcast); ``inf`` for the direction ``-w``."""
    x = np.asarray(directions, dtype=np.float64)
    f = np.asarray(frames, dtype=np.float64)
    comp = np.einsum("...j,...ij->...i", x, f)
    den = 1.0 + comp[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((den > 1e-12)[..., None], comp[..., :2] / den[..., None], np.inf)


def sensor_extent(sensor: np.ndarray) -> float:
    """``a`` of the LiDAR's grid: the stereographic radius ``tan(alpha / 2)`` of the unit sphere seen
    from ``sensor`` (3,) (``sin alpha = 1 / |S|``), 1 when the sensor is inside the sphere."""
    r = float(np.linalg.norm(sensor))
    if not r > 1.0:
        return 1.0
    return float(np.tan(0.5 * np.arcsin(1.0 / r)))


def cell_of(s: np.ndarray, extent: float, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Cells of stereographic coordinates ``s`` (..., 2) in a ``cells x cells`` grid over ``[-extent, extent]^2``:
    (..., 2) int64 indices and an (...) bool mask of the coordinates inside the grid."""
    q = (np.asarray(s, dtype=np.float64) + extent) / (2.0 * extent) * cells
    with np.errstate(invalid="ignore"):
        inside = np.all((q >= 0) & (q < cells), axis=-1)
    idx = np.floor(np.where(np.isfinite(q), q, -1.0)).astype(np.int64)
    return idx, inside


def nearest_per_cell(keys: np.ndarray, ranges: np.ndarray, n_keys: int) -> np.ndarray:
    """(n_keys,) int64 index of the entry nearest (smallest ``ranges``, ties: lowest index) among the
    entries of each key; -1 for keys without entries. ``keys`` (E,) int64 in [0, n_keys) or -1 (no cell);
    ``ranges`` (E,) finite (a NaN range would leave its key without an entry)."""
    out = np.full(n_keys, -1, dtype=np.int64)
    ok = np.flatnonzero(keys >= 0)
    if len(ok) == 0:
        return out
    k, r = keys[ok], ranges[ok]
    # two unbuffered minima instead of a sort (3.6x faster on 32,768 entries): each key's smallest range, then
    # the lowest index among its entries at that range
    best = np.full(n_keys, np.inf)
    np.minimum.at(best, k, r)
    hit = r == best[k]
    none = np.iinfo(np.int64).max
    idx = np.full(n_keys, none, dtype=np.int64)
    np.minimum.at(idx, k[hit], ok[hit])
    has = idx != none
    out[has] = idx[has]
    return out


def _near_candidates(p: np.ndarray, o: np.ndarray, d: np.ndarray, n_secondary: int, params: EvidenceParams):
    """The 4 candidates of every ray (:func:`near_ray_evidence`, unsorted): ``index`` (R, 4) int64 point row or -1,
    ``t`` (R, 4) float64 depth, ``dist`` (R, 4) float64 distance to the line (0 without a candidate), ``valid``
    (R, 4) bool. ``p`` (K, 3), ``o`` and ``d`` (R, 3) float64, unit frame."""
    r, m, g = len(o), int(n_secondary), int(params.near_cells)
    if m < 1 or r % m:
        raise ValueError(f"{r} rays are not whole viewpoints of {m} rays each (the rig's n_secondary)")
    views = o[::m]
    frames = stereo_frames(views)  # (N, 3, 3)
    # the rays' coordinates in their viewpoint's frame, view by view: the grid's extent and the rays' cells
    s_rays = stereo_coords(d.reshape(len(views), m, 3), frames[:, None]).reshape(r, 2)
    a = float(max(np.max(np.abs(s_rays)), 1e-6))
    rel = p[None] - views[:, None]  # (N, K, 3)
    rho = np.linalg.norm(rel, axis=-1)
    u = rel / np.where(rho > 0, rho, 1.0)[..., None]
    cell, inside = cell_of(stereo_coords(u, frames[:, None]), a, g)
    n = len(views)
    keys = np.where(inside, (np.arange(n)[:, None] * g + cell[..., 0]) * g + cell[..., 1], -1).reshape(-1)
    flat = nearest_per_cell(keys, rho.reshape(-1), n * g * g)  # index into the (N, K) pairs
    first = np.where(flat >= 0, flat % max(len(p), 1), -1)  # (N * g * g,) point index or -1
    view = np.arange(r) // m
    q = (s_rays + a) / (2.0 * a) * g
    base = np.floor(q - 0.5).astype(np.int64)
    cand = np.full((r, NEAR_CANDIDATES), -1, dtype=np.int64)
    for j, (dx, dy) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):  # the 4 cells, not the rays
        cx, cy = base[:, 0] + dx, base[:, 1] + dy
        ok = (cx >= 0) & (cx < g) & (cy >= 0) & (cy < g)
        key = (view * g + np.clip(cx, 0, g - 1)) * g + np.clip(cy, 0, g - 1)
        cand[:, j] = np.where(ok, first[key], -1)
    x = p[np.maximum(cand, 0)] if len(p) else np.zeros((r, NEAR_CANDIDATES, 3))
    rel = x - o[:, None]
    t = 0.5 * np.einsum("rkj,rj->rk", rel, d)
    dist = np.linalg.norm(rel - (2.0 * t)[..., None] * d[:, None], axis=-1)
    has = cand >= 0
    valid = has & (t > 0) & (dist <= params.radius)
    return cand, np.where(has, t, 0.0), np.where(has, dist, 0.0), valid


def near_ray_evidence(
    points: np.ndarray, origins: np.ndarray, directions: np.ndarray, n_secondary: int, params: EvidenceParams
) -> dict:
    """Near-ray evidence of one scan (module docstring), vectorised over rays.

    Parameters
    ----------
    points : (K, 3) observed points, unit frame. origins : (R, 3) ray origins (viewpoint ``r // n_secondary``),
    directions : (R, 3) unit directions, unit frame. n_secondary : M, rays per viewpoint.

    Returns ``depth`` (R, 4) float64 normalised depths, ``distance`` (R, 4) float64 unit-frame distances to
    the line, ``valid`` (R, 4) bool (counted candidates first, each group by increasing distance; not counted
    entries hold their values or 0 without a candidate), ``count`` (R,) int64.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    _, t, dist, valid = _near_candidates(p, o, d, n_secondary, params)
    r = len(o)
    order = np.lexsort((np.arange(NEAR_CANDIDATES)[None].repeat(r, 0), dist, ~valid), axis=-1)
    take = lambda a_: np.take_along_axis(a_, order, axis=-1)  # noqa: E731
    return {"depth": take(t), "distance": take(dist), "valid": take(valid), "count": valid.sum(-1).astype(np.int64)}


def carved_depths(
    points: np.ndarray, origins: np.ndarray, directions: np.ndarray, sensor: np.ndarray, params: EvidenceParams
) -> dict:
    """Free-space evidence of one scan (module docstring), vectorised over rays.

    Parameters
    ----------
    points : (K, 3) observed points, unit frame. origins, directions : (R, 3) rays, unit frame.
    sensor : (3,) the LiDAR's optical centre, unit frame (NaN: unknown, or the origin: nothing is carved).

    Returns ``carved`` (R, T) bool (bin j of ray r observed empty), ``sample_depth`` (R, T) float64 the
    bins' centre depths ``(j + 1/2) h / T`` and ``half_chord`` (R,) float64 ``h``.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    s = np.asarray(sensor, dtype=np.float64).reshape(3)
    n_t, g = int(params.carve_samples), int(params.carve_cells)
    h = np.clip(-np.einsum("rj,rj->r", o, d), 0.0, None)
    depth = (np.arange(n_t) + 0.5)[None] / n_t * h[:, None]
    carved = np.zeros(depth.shape, dtype=bool)
    if not np.all(np.isfinite(s)) or not np.linalg.norm(s) > 0 or len(p) == 0:
        # unknown, or at the box's centre (a scan given in its object's frame: no direction to look from)
        return {"carved": carved, "sample_depth": depth, "half_chord": h}
    frame = stereo_frames(s)
    a = sensor_extent(s)
    rel = p - s
    rho = np.linalg.norm(rel, axis=-1)
    cell, inside = cell_of(stereo_coords(rel / np.where(rho > 0, rho, 1.0)[:, None], frame), a, g)
    keys = np.where(inside, cell[:, 0] * g + cell[:, 1], -1)
    first = nearest_per_cell(keys, rho, g * g)
    limit = np.where(first >= 0, rho[np.maximum(first, 0)], -np.inf)  # (g*g,) nearest range per cell
    y = o[:, None] + 2.0 * depth[..., None] * d[:, None]  # (R, T, 3)
    rel = y - s
    dist = np.linalg.norm(rel, axis=-1)
    cy, iny = cell_of(stereo_coords(rel / np.where(dist > 0, dist, 1.0)[..., None], frame), a, g)
    key = np.clip(cy[..., 0], 0, g - 1) * g + np.clip(cy[..., 1], 0, g - 1)
    carved = iny & (dist < limit[key] - params.margin)
    return {"carved": carved, "sample_depth": depth, "half_chord": h}


def free_space_decode(depth: np.ndarray, keep: np.ndarray, carved: np.ndarray, half_chord: np.ndarray):
    """Move predicted surfaces out of observed free space (module docstring), vectorised.

    depth : (..., R) predicted normalised depths; keep : (..., R) bool kept rays; carved : (..., R, T) bool;
    half_chord : (..., R) ``h``. A kept ray whose depth (clamped to [0, h]) lies in a carved bin
    ``j = min(floor(depth / h * T), T - 1)`` moves to ``i h / T``, ``i`` the first bin >= j not carved, or
    is dropped when there is none. Returns (depth, keep) with the same shapes.
    """
    c = np.asarray(carved, dtype=bool)
    n_t = c.shape[-1]
    h = np.asarray(half_chord, dtype=np.float64)
    dd = np.clip(np.asarray(depth, dtype=np.float64), 0.0, h)
    j = np.minimum(np.floor(np.where(h > 0, dd / np.where(h > 0, h, 1.0), 0.0) * n_t), n_t - 1).astype(np.int64)
    # next free bin at or after each bin: n_t when none
    idx = np.where(~c, np.arange(n_t), n_t)
    nxt = np.minimum.accumulate(idx[..., ::-1], axis=-1)[..., ::-1]
    i = np.take_along_axis(nxt, j[..., None], axis=-1)[..., 0]
    inside = np.take_along_axis(c, j[..., None], axis=-1)[..., 0]
    new_depth = np.where(inside, i * h / n_t, dd)
    new_keep = np.asarray(keep, dtype=bool) & ~(inside & (i >= n_t))
    return new_depth, new_keep


SNAP_MIN_COSINE = 0.3
"""A ray meets an observed point's tangent plane only when ``|d . n|`` is at least this (not grazing)."""

NORMAL_NEIGHBOURS = 8
"""Observed points (the point included) whose least-variance axis is a point's normal."""


def point_normals(points: np.ndarray, k: int = NORMAL_NEIGHBOURS) -> np.ndarray:
    """(K, 3) float64 unit normals (sign arbitrary) of (K, 3) points: the eigenvector of the smallest
    eigenvalue of the covariance of each point's ``min(k, K)`` nearest points (itself included). Fewer
    than 3 points: zeros (no plane)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) < 3:
        return np.zeros_like(p)
    from scipy.spatial import cKDTree

    _, idx = cKDTree(p).query(p, k=min(int(k), len(p)))
    nb = p[idx] - p[idx].mean(axis=1, keepdims=True)
    _, vec = np.linalg.eigh(np.einsum("kni,knj->kij", nb, nb))
    return vec[:, :, 0]


def snap_radius(snap, snap_mirror: bool = False, option: str = "snap", mirror_option: str = "snap_mirror"):
    """The radius that a ``--snap`` value asks for, checked once for every surface that snaps (``complete``,
    ``real complete``, ``evaluate``, ``real evaluate``, the API): ``None`` (snapping off) for ``None`` or 0, else
    a float > 0 (unit frame of a box: its half-diagonal is 1).

    Raises :class:`~spotlights.errors.ParameterError` naming ``option`` for any other value (negative, NaN,
    infinite, not a real number: text and booleans too), and naming ``mirror_option`` when ``snap_mirror`` is asked
    without a radius.
    """
    import numbers

    real = isinstance(snap, numbers.Real) and not isinstance(snap, (bool, np.bool_))
    r = 0.0 if snap is None else float(snap) if real else float("nan")
    if not (np.isfinite(r) and r >= 0):
        raise ParameterError(
            f"{shown(option)}: the snap radius must be a finite number > 0 (unit frame; 0: off), got {snap!r}",
            *parameter_names(option),
        )
    if snap_mirror and r == 0:
        raise ParameterError(
            f"{shown(mirror_option)} goes with {shown(option)} R", *parameter_names(option, mirror_option)
        )
    return r if r > 0 else None


def snap_to_observed(
    points: np.ndarray,
    origins: np.ndarray,
    directions: np.ndarray,
    n_secondary: int,
    depth: np.ndarray,
    keep: np.ndarray,
    radius: float,
    near_cells: int = 32,
    sensor: np.ndarray | None = None,
    seen: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Snap the rays that pass near observed points onto them (module docstring), one scan, vectorised.

    Parameters
    ----------
    points : (K, 3) points to snap to, unit frame (repeats removed here): the observed points, with their mirror
        image when asked. origins, directions : (R, 3) the rays (viewpoint ``r // n_secondary``), unit frame.
        depth : (R,) predicted normalised depths (a point is ``o + 2 t d``). keep : (R,) bool predicted hits.
        radius : R > 0, unit frame. near_cells : the viewpoint grids' G (:class:`EvidenceParams`).
    sensor : (3,) the LiDAR's optical centre, unit frame: applies the occlusion rule (module docstring); None,
        NaN or the origin (the box's centre): not applied. seen : (K', 3) the points actually observed, whose free space is carved (default
        ``points``).

    Returns ``(depth (R,) float64, keep (R,) bool, snapped (R,) bool)``: the snapped rays' depths from the
    scan and kept; the others as given.
    """
    if not radius > 0:
        raise ValueError(f"the snap radius must be > 0, got {radius}")
    dep = np.array(depth, dtype=np.float64).reshape(-1)
    kp = np.array(keep, dtype=bool).reshape(-1)
    p = np.unique(np.asarray(points, dtype=np.float64).reshape(-1, 3), axis=0)
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if not (len(dep) == len(kp) == len(o) == len(d)):
        raise ValueError(f"depth {dep.shape}, keep {kp.shape}, origins {o.shape}, directions {d.shape} differ in rays")
    if len(p) == 0:
        return dep, kp, np.zeros(len(dep), dtype=bool)
    cand, t, dist, valid = _near_candidates(p, o, d, n_secondary, EvidenceParams(near_cells=near_cells, radius=radius))
    snapped = valid.any(axis=1)
    rows = np.flatnonzero(snapped)
    best = np.argmin(np.where(valid[rows], dist[rows], np.inf), axis=1)
    j = cand[rows, best]
    t_foot = t[rows, best]
    x, n = p[j], point_normals(p)[j]
    o_r, d_r = o[rows], d[rows]
    dn = np.einsum("ij,ij->i", d_r, n)
    facing = np.abs(dn) >= SNAP_MIN_COSINE
    t_plane = np.einsum("ij,ij->i", x - o_r, n) / (2.0 * np.where(facing, dn, 1.0))
    meet = o_r + (2.0 * t_plane)[:, None] * d_r
    on_plane = facing & (t_plane > 0) & (np.linalg.norm(meet - x, axis=1) <= radius)
    t_snap = np.where(on_plane, t_plane, t_foot)
    if sensor is not None and np.all(np.isfinite(sensor)) and np.linalg.norm(sensor) > 0:
        # occlusion: a kept prediction stays unless the LiDAR saw through it (module docstring)
        behind = kp[rows] & (2.0 * (t_snap - dep[rows]) > radius)
        if behind.any():
            b = rows[behind]
            obs = p if seen is None else np.asarray(seen, dtype=np.float64).reshape(-1, 3)
            carve = carved_depths(obs, o[b], d[b], np.asarray(sensor, dtype=np.float64), EvidenceParams())
            h, n_t = carve["half_chord"], carve["carved"].shape[1]
            bin_ = np.minimum(np.floor(np.clip(dep[b], 0.0, h) / np.where(h > 0, h, 1.0) * n_t), n_t - 1).astype(int)
            hidden = ~carve["carved"][np.arange(len(b)), bin_]  # the predicted surface's bin was not seen empty
            t_snap[np.flatnonzero(behind)[hidden]] = dep[b[hidden]]
            snapped[b[hidden]] = False
    dep[rows] = t_snap
    kp[rows] = True
    return dep, kp, snapped


@dataclass(frozen=True)
class SnapTargets:
    """What a batch of B scans snaps to (:func:`snap_batch_to_observed`), unit frames.

    observed : B arrays (K_b, 3), the points each scan's rays snap to (with their mirror image when asked).
    radius : R > 0. sensors : (B, 3) the LiDAR in each unit frame (the occlusion rule; None, a NaN row or the
    origin: not applied). seen : B arrays (K'_b, 3), the points actually observed, carved for the rule (None: ``observed``).
    """

    observed: list
    radius: float
    sensors: np.ndarray | None = None
    seen: list | None = None


def snap_batch_to_observed(
    targets: SnapTargets,
    origins: np.ndarray,
    directions: np.ndarray,
    n_secondary: int,
    depth: np.ndarray,
    keep: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`snap_to_observed` of B scans: ``targets`` (:class:`SnapTargets`), origins (R, 3), directions (R, 3)
    (shared) or (B, R, 3), depth (B, R), keep (B, R) bool; unit frame. Returns ``(depth (B, R) float64, keep
    (B, R) bool)``."""
    dirs = np.asarray(directions, dtype=np.float64)
    n = len(depth)
    for name, value in (("observed point sets", targets.observed), ("seen point sets", targets.seen)):
        if value is not None and len(value) != n:
            raise ValueError(f"{len(value)} {name} for {n} scans")
    sensors = None if targets.sensors is None else np.asarray(targets.sensors, dtype=np.float64).reshape(-1, 3)
    if sensors is not None and len(sensors) != n:
        raise ValueError(f"{len(sensors)} sensor origins for {n} scans")
    rows = [
        snap_to_observed(
            targets.observed[b],
            origins,
            dirs[b] if dirs.ndim == 3 else dirs,
            n_secondary,
            depth[b],
            keep[b],
            targets.radius,
            sensor=None if sensors is None else sensors[b],
            seen=None if targets.seen is None else targets.seen[b],
        )
        for b in range(n)
    ]
    return np.stack([r[0] for r in rows]), np.stack([r[1] for r in rows])
