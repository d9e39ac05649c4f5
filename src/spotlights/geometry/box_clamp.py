"""Keeping completions inside the object's box grown by a margin (the "inside the box" rule of completion).

Everything here works in a box's **unit frame** (its object frame divided by R = half the box
diagonal, :mod:`spotlights.geometry.frames`), where the box is axis-aligned and centred on the
origin with half-extents ``size / (2 R)``. The grown box adds ``margin`` metres on every side:
half-extents ``(size / 2 + margin) / R`` (:func:`grown_half_extents`; the default margin is the
crop margin of real scans, 0.15 m).

Two ways to clamp, both exact and pure numpy:

* **along rays** (depth models, Spotlights rigs): a point ``o + t u`` of a ray stays on its ray.
  :func:`ray_box_interval` gives the entry and exit distances of each ray through the box
  (slab method); :func:`clip_depths_to_box` clips Spotlights depths (``t = 2 d``) into
  ``[entry, exit]`` and turns a hit on a ray that never meets the box into a miss;
* **by projection** (point-set models): :func:`clamp_points_to_box` moves each outside point to
  the nearest point of the box (per-coordinate clipping is the exact Euclidean projection onto
  an axis-aligned box).

Each also reports the share of points that were inside before the clamp (what the network put
there itself). :func:`clamp_to_grown_boxes` is the step of the completion path: projection onto
each object's grown box, then the unit sphere (:func:`~spotlights.geometry.frames.clamp_to_unit_sphere`).
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from .frames import clamp_to_unit_sphere

#: metres added on every side of a box: the crop margin of real scans (data.real.extract, SceneConfig)
GROWN_BOX_MARGIN = 0.15


def grown_half_extents(sizes, margin: float = GROWN_BOX_MARGIN) -> np.ndarray:
    """Half-extents of boxes grown by ``margin``, each in its own unit frame.

    sizes : (B, 3) or (3,) box (length, width, height), metres. margin : metres per side (>= 0).
    Returns (B, 3) or (3,) float64 ``(size / 2 + margin) / R`` with ``R = |size| / 2``.
    """
    s = np.asarray(sizes, dtype=np.float64)
    if s.shape[-1:] != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ParameterError(f"box sizes must be (..., 3) positive metres, got shape {s.shape}")
    if not (np.isfinite(margin) and margin >= 0):
        raise ParameterError(f"margin must be >= 0 metres, got {margin!r}")
    r = np.linalg.norm(s, axis=-1, keepdims=True) / 2.0
    return (s / 2.0 + float(margin)) / r


def ray_box_interval(origins, directions, half) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit distances of rays ``o + t u`` through the axis-aligned box ``[-half, half]``.

    origins, directions : (..., 3) float (broadcastable; directions need not be unit: t is in
    units of ``|u|``); half : (..., 3) positive half-extents, broadcastable. Returns
    ``(t_in, t_out)`` (...,) float64 (slab method): the ray's line meets the box iff
    ``t_in <= t_out``; the ray itself iff also ``t_out >= 0``. A direction component of 0 leaves
    that slab unbounded when the origin is inside it, and empty otherwise.
    """
    o = np.asarray(origins, dtype=np.float64)
    u = np.asarray(directions, dtype=np.float64)
    h = np.asarray(half, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / u
        t1, t2 = (-h - o) * inv, (h - o) * inv
    # a zero component: inside the slab -> (-inf, inf); outside -> empty (inf, -inf)
    zero = u == 0.0
    inside = np.abs(o) <= h
    lo = np.where(zero, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    hi = np.where(zero, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    return lo.max(axis=-1), hi.min(axis=-1)


def exit_depths(origins, directions, half) -> np.ndarray:
    """(...,) float64 Spotlights depth (``t / 2``, unit directions) at which each ray leaves the
    box ``[-half, half]`` (:func:`ray_box_interval`); 0 for a ray that never meets it."""
    t_in, t_out = ray_box_interval(origins, directions, half)
    meets = (t_in <= t_out) & (t_out >= 0)
    return np.where(meets, t_out / 2.0, 0.0)


def clip_depths_to_box(depths, origins, directions, half) -> tuple[np.ndarray, float]:
    """Clip Spotlights depths so that every decoded point ``o + 2 d u`` lies in ``[-half, half]``.

    depths : (..., K) float depths (0 = miss); origins, directions : (..., K, 3) unit-frame rays
    (unit directions), broadcastable; half : (3,) or (..., 1, 3) box half-extents.

    Returns ``(clipped (..., K) float64, inside_share)``: a hit whose point is outside moves
    along its ray to the nearest of the ray's entry and exit (``t`` clipped into ``[t_in,
    t_out]``); a hit on a ray that never meets the box becomes a miss (0); misses stay misses.
    ``inside_share``: the share of hits already inside before the clip (1.0 when there are none).
    """
    d = np.asarray(depths, dtype=np.float64)
    t_in, t_out = ray_box_interval(origins, directions, half)
    t_in, t_out = np.broadcast_to(t_in, d.shape), np.broadcast_to(t_out, d.shape)
    hit = d > 0
    t = 2.0 * d
    meets = (t_in <= t_out) & (t_out > 0)
    inside = hit & meets & (t >= t_in) & (t <= t_out)
    clipped = np.where(hit & meets, np.clip(t, t_in, t_out) / 2.0, 0.0)
    n = int(hit.sum())
    return clipped, (float(inside.sum()) / n if n else 1.0)


def _float32_below(h: np.ndarray) -> np.ndarray:
    """float32 of ``h`` rounded toward zero (so that float32 points clipped to it are inside h)."""
    h32 = np.asarray(h, dtype=np.float32)
    return np.where(h32.astype(np.float64) > h, np.nextafter(h32, np.float32(0)), h32)


def clamp_points_to_box(points, half) -> tuple[np.ndarray, float]:
    """Project points onto the box ``[-half, half]`` (the nearest point of the box; inside points
    are returned unchanged, bit for bit).

    points : (K, 3) float, unit frame; half : (3,) positive half-extents.
    Returns ``(clamped (K, 3) float32, inside_share)``: ``inside_share`` is the share of points
    inside the box before the clamp (1.0 for no points).
    """
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    h32 = _float32_below(np.asarray(half, dtype=np.float64).reshape(3))
    # for a float32 coordinate, |p| <= h exactly when |p| <= h32, the largest float32 not above h: no float64 copy
    a = np.abs(p)
    within = a <= h32  # (K, 3)
    if within.all():  # every point inside (SA-Nets' rays are clipped to the box already); flat: 4x a row-wise all
        return p, 1.0
    share = float(within.all(axis=1).mean())
    return np.clip(p, -h32, h32).astype(np.float32), share


def clamp_to_grown_boxes(completions, sizes, margin: float = GROWN_BOX_MARGIN) -> tuple[list[np.ndarray], list[float]]:
    """Every completion inside its box grown by ``margin`` metres and inside the unit sphere.

    completions : B arrays (K_i, 3), each in its box's unit frame; sizes : (B, 3) box sizes, metres.
    Returns ``(clamped, inside)``: B float32 arrays (projected onto the grown box with
    :func:`clamp_points_to_box`, then moved radially into the unit sphere, which keeps them in
    the box: it is convex and holds the origin) and B floats, the share of each completion's
    points inside its grown box before any clamp.
    """
    half = grown_half_extents(np.asarray(sizes, dtype=np.float64).reshape(-1, 3), margin)
    if len(half) != len(completions):
        raise ParameterError(f"{len(completions)} completions but {len(half)} box sizes")
    out, shares = [], []
    for c, h in zip(completions, half):
        p, share = clamp_points_to_box(c, h)
        out.append(clamp_to_unit_sphere(p))
        shares.append(share)
    return out, shares
