"""The evidence the fit of :mod:`spotlights.learning.fit` reads: the rig's neighbouring rays (the residual's
smoothness and the evidence's reach) and the observed free space (each beam from the sensor to its point)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..geometry.evidence import cell_of, nearest_per_cell, sensor_extent, stereo_coords, stereo_frames
from .rays import directions_for_extents, rig_spec


@lru_cache(maxsize=8)
def _neighbour_table(spec_key: str, k: int) -> np.ndarray:
    spec = rig_spec(_spec_of_key(spec_key))
    m = spec.n_secondary
    d = directions_for_extents(spec, np.full((1, 3), 1.0 / np.sqrt(3.0)))[0].astype(np.float64)
    views = d.reshape(-1, m, 3)
    k = min(int(k), m - 1)
    cos = np.einsum("vij,vkj->vik", views, views)  # (N, M, M)
    idx = np.arange(m)
    cos[:, idx, idx] = -np.inf  # not itself
    order = np.argsort(-cos, axis=-1, kind="stable")[..., :k]  # (N, M, k) within the viewpoint
    table = order + (np.arange(len(views)) * m)[:, None, None]
    out = table.reshape(-1, k).astype(np.int64)
    out.flags.writeable = False
    return out


def _spec_of_key(key: str):
    """The rig description of a :func:`ray_neighbours` cache key (a ``RigSpec.to_dict()`` as JSON)."""
    import json

    return json.loads(key)


def ray_neighbours(rig, k: int = 6) -> np.ndarray:
    """(R, k) int64: for every ray of ``rig`` (a RigSpec, Rig or dict; R = N*M), the ``k`` rays of the same
    viewpoint whose directions are nearest to its own (largest cosine; ties: the lower index), directions of the
    rig aimed at a cube (box half-extents ``(1, 1, 1) / sqrt(3)``): the neighbour graph of the fit's smoothing,
    the same for every box. Ray ``i*M + j`` is viewpoint ``i``'s ray ``j``. Cached per rig."""
    import json

    spec = rig_spec(rig)
    return _neighbour_table(json.dumps(spec.to_dict(), sort_keys=True), int(k))


def dilate(mask: np.ndarray, neighbours: np.ndarray, rings: int) -> np.ndarray:
    """``mask`` (..., R) bool grown ``rings`` times: a ray joins when one of its ``neighbours`` (R, k) is in."""
    out = np.asarray(mask, dtype=bool)
    for _ in range(int(rings)):
        out = out | out[..., neighbours].any(-1)
    return out


@dataclass(frozen=True)
class FreeSpace:
    """The observed free space of one scan as an angular grid seen from its sensor (unit frame).

    frame : (3, 3) rows u, v, w (:func:`spotlights.geometry.evidence.stereo_frames` of the sensor); extent : the
    grid's ``a``; cells : G; limit : (G*G,) float64 the range of each cell's nearest observed point (-inf: empty
    cell); sensor : (3,) float64 (NaN: unknown, nothing carved)."""

    frame: np.ndarray
    extent: float
    cells: int
    limit: np.ndarray
    sensor: np.ndarray

    @classmethod
    def of(cls, observed: np.ndarray, sensor, cells: int = 32) -> FreeSpace:
        """The free space of ``observed`` (K, 3) points seen from ``sensor`` (3,) (None, NaN or the origin:
        unknown, an empty grid)."""
        p = np.asarray(observed, dtype=np.float64).reshape(-1, 3)
        s = np.full(3, np.nan) if sensor is None else np.asarray(sensor, dtype=np.float64).reshape(3)
        g = int(cells)
        limit = np.full(g * g, -np.inf)
        if not np.all(np.isfinite(s)) or not np.linalg.norm(s) > 0 or len(p) == 0:
            return cls(np.eye(3), 1.0, g, limit, np.full(3, np.nan))
        frame = stereo_frames(s)
        a = sensor_extent(s)
        rel = p - s
        rho = np.linalg.norm(rel, axis=-1)
        cell, inside = cell_of(stereo_coords(rel / np.where(rho > 0, rho, 1.0)[:, None], frame), a, g)
        first = nearest_per_cell(np.where(inside, cell[:, 0] * g + cell[:, 1], -1), rho, g * g)
        limit = np.where(first >= 0, rho[np.maximum(first, 0)], -np.inf)
        return cls(frame, float(a), g, limit, s)

    @property
    def known(self) -> bool:
        return bool(np.all(np.isfinite(self.sensor)))

    def depth_inside(self, points: np.ndarray, margin: float) -> np.ndarray:
        """(...) float64: how far each point (..., 3) lies inside observed free space, toward the sensor
        (``rho_cell - margin - |P - S|``, clipped at 0: 0 outside); the place is carved where it is > 0."""
        x = np.asarray(points, dtype=np.float64)
        if not self.known:
            return np.zeros(x.shape[:-1])
        rel = x - self.sensor
        dist = np.linalg.norm(rel, axis=-1)
        cell, inside = cell_of(
            stereo_coords(rel / np.where(dist > 0, dist, 1.0)[..., None], self.frame), self.extent, self.cells
        )
        g = self.cells
        key = np.clip(cell[..., 0], 0, g - 1) * g + np.clip(cell[..., 1], 0, g - 1)
        depth = self.limit[key] - margin - dist
        return np.where(inside & np.isfinite(depth), np.maximum(depth, 0.0), 0.0)

    def carved(self, points: np.ndarray, margin: float) -> np.ndarray:
        """(...) bool: the points (..., 3) that lie in observed free space (module docstring)."""
        return self.depth_inside(points, margin) > 0


def out_of_free_space(
    free: FreeSpace, origins, directions, depth, margin: float, step: float, tries: int, box_half=None
):
    """Move points out of observed free space along their rays: (depth (n,) float64, ok (n,) bool).

    origins, directions : (n, 3) rays; depth : (n,) their depths (``P = o + 2 t u``, ``t`` clamped to [0, h]).
    Each ray whose point is carved takes the nearest depth ``t + j * step`` (``j = +-1 .. +-tries``, the smaller
    ``|j|`` first, then the deeper) in [0, h] whose point is not carved (and lies in the box of half-extents
    ``box_half`` (3,), when given); ``ok`` is False where none is."""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    u = np.asarray(directions, np.float64).reshape(-1, 3)
    h = np.clip(-np.einsum("rj,rj->r", o, u), 0.0, None)
    t = np.clip(np.asarray(depth, np.float64).reshape(-1), 0.0, h)
    bad = free.carved(o + 2.0 * t[:, None] * u, margin)
    ok = ~bad
    if not bad.any():
        return t, ok
    rows = np.flatnonzero(bad)
    offs = np.array([s * j * step for j in range(1, tries + 1) for s in (1, -1)])
    cand = t[rows, None] + offs[None]  # (n_bad, 2 * tries), nearest first
    valid = (cand >= 0) & (cand <= h[rows, None])
    pts = o[rows, None] + 2.0 * np.clip(cand, 0.0, h[rows, None])[..., None] * u[rows, None]
    if box_half is not None:
        valid &= (np.abs(pts) <= np.asarray(box_half, np.float64) + 1e-6).all(-1)
    free_ok = valid & ~free.carved(pts, margin)
    first = np.argmax(free_ok, axis=1) if free_ok.shape[1] else np.zeros(len(rows), dtype=np.int64)
    if not free_ok.shape[1]:
        return t, ok
    found = free_ok[np.arange(len(rows)), first]
    t[rows[found]] = cand[found, first[found]]
    ok[rows[found]] = True
    return t, ok
