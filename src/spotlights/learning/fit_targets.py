"""The evidence of :func:`spotlights.learning.fit.fit_completions`, per scan, in each scan's unit frame: the data
rays and their target depths, the kept rays that carry free-space evidence (computed once from the unfitted
prediction), and the fitted points moved out of observed free space after the steps (see the docstring of
:mod:`spotlights.learning.fit`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..geometry.evidence import snap_to_observed
from .fit_evidence import FreeSpace, out_of_free_space

if TYPE_CHECKING:
    from .fit import FitSettings


def evidence_rays(obs, so, origins, dirs_np, dep_p, keep_p, free, m: int, cfg: FitSettings):
    """Each scan's evidence rays from its prior depths ``dep_p`` and kept rays ``keep_p`` (B, R): ``data`` (B, R)
    bool the rays :func:`~spotlights.geometry.evidence.snap_to_observed` snaps to the observed points ``obs``
    (sensors ``so`` (B, 3), NaN: unknown), ``target`` (B, R) float64 their depths (0 elsewhere), and (B, R) bool
    the kept rays that carry free-space evidence (:func:`free_evidence`)."""
    b_n, r_n = dep_p.shape
    data = np.zeros((b_n, r_n), dtype=bool)
    target = np.zeros((b_n, r_n))
    evid_free = np.zeros((b_n, r_n), dtype=bool)
    h = np.clip(-np.einsum("rj,brj->br", origins, dirs_np.astype(np.float64)), 0.0, None)  # (B, R) half chords
    for b in range(b_n):
        d_b = dirs_np[b].astype(np.float64)
        sensor = so[b] if np.all(np.isfinite(so[b])) else None
        dep, _, snapped = snap_to_observed(obs[b], origins, d_b, m, dep_p[b], keep_p[b], cfg.radius, sensor=sensor)
        data[b], target[b] = snapped, np.where(snapped, dep, 0.0)
        if free[b].known:
            evid_free[b] = free_evidence(free[b], origins, d_b, dep_p[b], keep_p[b], h[b], cfg)
    return data, target, evid_free


def free_evidence(free: FreeSpace, origins, d_b, dep_b, keep_b, h_b, cfg: FitSettings) -> np.ndarray:
    """(R,) bool: the kept rays ``keep_b`` of one scan on which a carved place of ``free`` lies in front of (or at)
    the predicted point (depths ``dep_b``, half chords ``h_b``; ``cfg.carve_samples`` samples per ray)."""
    r_n = len(keep_b)
    n_t = cfg.carve_samples
    t_pt = np.clip(dep_b, 0.0, h_b)
    samples = (np.arange(n_t) + 0.5)[None] / n_t * h_b[:, None]  # (R, T)
    ray, j = np.nonzero((samples <= t_pt[:, None]) & keep_b[:, None])  # the kept rays' samples ahead
    y = origins[ray] + 2.0 * samples[ray, j][:, None] * d_b[ray]
    crossed = np.zeros(r_n, dtype=bool)
    crossed[ray[free.carved(y, cfg.margin)]] = True
    kept = np.flatnonzero(keep_b)
    at_point = np.zeros(r_n, dtype=bool)
    at_point[kept] = free.carved(origins[kept] + 2.0 * t_pt[kept, None] * d_b[kept], cfg.margin)
    return keep_b & (crossed | at_point)


def leave_free_space(free, changed, keep_fit, dep_np, origins, dirs_np, bh_np, cfg: FitSettings) -> None:
    """No fitted point in observed free space: each changed kept ray's depth in ``dep_np`` (B, R) moved out along
    its ray (:func:`~spotlights.learning.fit_evidence.out_of_free_space`), or the ray dropped from ``keep_fit``
    (B, R); in place."""
    for b in range(len(free)):
        if free[b].known:
            rows = np.flatnonzero(changed[b] & keep_fit[b])
            t, ok = out_of_free_space(
                free[b],
                origins[rows],
                dirs_np[b, rows],
                dep_np[b, rows],
                cfg.margin,
                cfg.free_step,
                cfg.free_tries,
                None if bh_np is None else bh_np[b],
            )
            dep_np[b, rows] = t
            keep_fit[b, rows[~ok]] = False
