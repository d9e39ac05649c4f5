"""Mesh primitives of the procedural vehicles: lofts, boxes, wheels and the lofted body.

Every primitive is ``(vertices (V, 3) float64, faces (F, 3) int64)``, closed (every edge in two
faces), wound outward (by its signed volume), in metres; bodies are built with their front at
s = 0 and placed by ``x_of(s)`` (x = L - s, so that x points forward).
"""

from __future__ import annotations

import numpy as np

ARCH_GAP = 0.04  # wheel arch radius = wheel radius + this (m)
WHEEL_SECTIONS = 20
GLASS_RECESS = 0.015  # side glass lies this far (m) inside the pillars and the body's side
N_LOWER = 7  # section points per lower quarter (floor centre -> beltline), the centre excluded
N_UPPER = 7  # section points per upper quarter (beltline -> roof centre), the beltline excluded


def signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    """The signed volume (m^3) enclosed by triangles ``f`` (F, 3) over vertices ``v`` (V, 3)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def outward(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(v, f)`` with the winding flipped where the signed volume is negative."""
    if signed_volume(v, f) < 0:
        f = np.ascontiguousarray(f[:, ::-1])
    return v, f


def loft(xs: np.ndarray, sections: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A closed tube through cross-sections: ``xs`` (S,) stations along x, ``sections`` (S, K, 2)
    (y, z) vertices of a simple polygon each (star-shaped about its mean), the same vertex order
    at every station; each end is closed by a fan about the section's mean."""
    s, k = sections.shape[:2]
    v = np.concatenate(
        [
            np.column_stack([np.repeat(xs, k), sections.reshape(-1, 2)]),
            np.column_stack([xs[[0, -1]], sections[[0, -1]].mean(1)]),
        ]
    )
    i = np.arange(s - 1)[:, None] * k
    j = np.arange(k)[None, :]
    a, b = i + j, i + (j + 1) % k
    c, d = b + k, a + k
    quads = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    j = np.arange(k)
    front = np.column_stack([np.full(k, s * k), (j + 1) % k, j])
    back = np.column_stack([np.full(k, s * k + 1), (s - 1) * k + j, (s - 1) * k + (j + 1) % k])
    return outward(v, np.concatenate([quads, front, back]).astype(np.int64))


def box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box from corner ``lo`` to ``hi`` (3,) (8 vertices, 12 triangles)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x, y, z] for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)], dtype=np.float64)
    f = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int64,
    )  # fmt: skip
    return outward(v, f)


def rounded_box(x0: float, x1: float, hw: float, z0: float, z1: float, n: float = 10.0) -> tuple:
    """A box from x0 to x1 (x0 < x1), |y| <= hw, z0..z1 whose cross-section is a superellipse of
    exponent ``n`` (rounded long edges; the box's extremes are exactly hw, z0 and z1)."""
    sec = _superellipse(hw, z0, z1, n)
    return loft(np.array([x0, x1], dtype=np.float64), np.stack([sec, sec]))


def _superellipse(hw: float, z0: float, z1: float, n: float, k: int = 24) -> np.ndarray:
    t = 2 * np.pi * np.arange(k) / k
    c, s = np.cos(t), np.sin(t)
    y = hw * np.sign(c) * np.abs(c) ** (2 / n)
    z = (z0 + z1) / 2 + (z1 - z0) / 2 * np.sign(s) * np.abs(s) ** (2 / n)
    return np.column_stack([y, z])


def tank(x0: float, x1: float, hw: float, z0: float, z1: float, head: float, n: float = 2.6) -> tuple:
    """A tank from x0 to x1 along x: superellipse sections (|y| <= hw, z0..z1, exponent ``n``)
    with dished heads ``head`` m deep (the sections shrink to 55% at both ends)."""
    u = np.concatenate([np.linspace(0.0, 1.0, 7), [np.nan]])
    dish = 0.55 + 0.45 * np.sqrt(1.0 - (1.0 - u[:-1]) ** 2)
    xs = np.concatenate([x0 + head * u[:-1], x1 - head * u[:-1][::-1]])
    scale = np.concatenate([dish, dish[::-1]])
    zc, hz = (z0 + z1) / 2, (z1 - z0) / 2
    secs = np.stack([_superellipse(hw * a, zc - hz * a, zc + hz * a, n) for a in scale])
    return loft(xs, secs)


def wheel(x: float, y0: float, y1: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    """A wheel: a :data:`WHEEL_SECTIONS`-gon cylinder along y from ``y0`` to ``y1``, axle at
    height ``r`` and front-back position ``x``, its lowest vertex on the ground (z = 0)."""
    t = 2 * np.pi * np.arange(WHEEL_SECTIONS) / WHEEL_SECTIONS - np.pi / 2
    ring = np.column_stack([x + r * np.cos(t), r + r * np.sin(t)])  # (x, z)
    ring[0, 1] = 0.0
    # a loft along y: sections are (x, z) rings at y0 and y1; swap axes afterwards
    v, f = loft(np.array([y0, y1]), np.stack([ring, ring]))
    return outward(v[:, [1, 0, 2]], f)


def smooth(points, s: np.ndarray) -> np.ndarray:
    """The monotone cubic (PCHIP: no overshoot) through ``points`` [(s, z), ...] at ``s``."""
    from scipy.interpolate import PchipInterpolator

    ps, pz = np.array(points, dtype=np.float64).T
    return PchipInterpolator(ps, pz, extrapolate=True)(s)


def _sections(zf, zb, zt, w, wt, glass, n_low: float, n_up: float) -> np.ndarray:
    """(S, K, 2) cross-sections: a lower body from the floor ``zf`` to the beltline ``zb``
    (half-width ``w``, superellipse exponent ``n_low``) and an upper part from ``zb`` to the top
    ``zt`` leaning in to half-width ``wt`` at the top (tumblehome; rounded by ``n_up``); the upper
    points between the sill and the roof rail of a station lie ``glass`` (m, per station) further
    in (at most to 30% of their half-width)."""
    tl = np.linspace(np.pi / 2, 0.0, N_LOWER + 1)[1:]  # bottom centre excluded ... beltline
    tu = np.linspace(0.0, np.pi / 2, N_UPPER + 1)[1:]  # above the beltline ... roof centre
    cl, sl = np.cos(tl) ** (2 / n_low), np.sin(tl) ** (2 / n_low)
    cu, su = np.cos(tu) ** (2 / n_up), np.sin(tu) ** (2 / n_up)
    cu[-1] = 0.0
    yl = w[:, None] * cl
    zl = zb[:, None] - (zb - zf)[:, None] * sl
    yu = (w[:, None] - (w - wt)[:, None] * su) * cu
    zu = zb[:, None] + (zt - zb)[:, None] * su
    band = (su > 0.08) & (su < 0.8)
    yu = np.where(band[None, :], np.maximum(yu - glass[:, None], 0.3 * yu), yu)
    right_y = np.concatenate([np.zeros((len(w), 1)), yl, yu], axis=1)
    right_z = np.concatenate([zf[:, None], zl, zu], axis=1)
    y = np.concatenate([right_y, -right_y[:, -2:0:-1]], axis=1)
    z = np.concatenate([right_z, right_z[:, -2:0:-1]], axis=1)
    return np.stack([y, z], axis=-1)


def loft_body(
    s0: float,
    s1: float,
    top,
    floor,
    belt,
    half: float,
    roof_half: float,
    axles,
    arch: float,
    x_of,
    *,
    corners=(0.3, 0.3),
    n_low: float = 4.0,
    n_up: float = 3.0,
    windows=(),
    recess: float = GLASS_RECESS,
    step: float = 0.1,
) -> tuple[np.ndarray, np.ndarray]:
    """A lofted body from ``s0`` to ``s1`` (distance from the front, m).

    top, floor : control points [(s, z), ...] of the roof line and the floor (smoothed by
        :func:`smooth`); the floor rises into a circular wheel arch of radius ``arch`` over every
        s of ``axles`` (the wheel's axle at height ``arch - ARCH_GAP``).
    belt : beltline height (m), or its control points [(s, z), ...]; where the roof line is 0.3 m
        or more above it the section has a
        greenhouse of half-width ``roof_half`` at the top (tumblehome), else a crowned lid.
    half : half-width (m) of the body; the plan view is a rectangle with rounded corners of radii
        ``corners`` (front, rear) m. windows : (s_a, s_b) spans whose side glass lies ``recess``
        m inside the pillars (:data:`GLASS_RECESS`; passenger bodies: the cabin seen through an open
        window).
    """
    rf, rr = corners
    stations = [np.arange(s0, s1, step), [s1], np.array(top)[:, 0], np.array(floor)[:, 0]]
    stations += [
        s0 + rf * (1 - np.cos(np.linspace(0, np.pi / 2, 7))),
        s1 - rr * (1 - np.cos(np.linspace(0, np.pi / 2, 7))),
    ]
    for a in axles:
        stations.append(a + arch * np.cos(np.linspace(np.pi, 0, 17)))
    for a, b in windows:
        stations.append([a - 1e-3, a, b, b + 1e-3])
    s = np.unique(np.clip(np.concatenate([np.ravel(x) for x in stations]), s0, s1))
    knot = np.isin(s, np.array(top, dtype=np.float64)[:, 0])  # the roof line's maxima lie on its knots
    s = s[np.concatenate([[True], np.diff(s) > 2e-4]) | knot]
    zt = smooth(top, s)
    zf = smooth(floor, s)
    r = arch - ARCH_GAP
    for a in axles:
        inside = np.abs(s - a) < arch
        zf[inside] = np.maximum(zf[inside], r + np.sqrt(arch**2 - (s[inside] - a) ** 2))
    belt = smooth(belt, s) if np.ndim(belt) else np.full_like(s, belt)
    zb = np.minimum(belt, zt - 0.04)
    zb = np.maximum(zb, zf + 0.03)
    zt = np.maximum(zt, zb + 0.02)
    front = np.clip((s - s0) / rf, 0.0, 1.0)
    rear = np.clip((s1 - s) / rr, 0.0, 1.0)
    w = half - rf * (1 - np.sqrt(1 - (1 - front) ** 2)) - rr * (1 - np.sqrt(1 - (1 - rear) ** 2))
    green = np.clip((zt - belt - 0.05) / 0.25, 0.0, 1.0)
    crown = 0.8 * w
    wt = np.minimum(crown + (roof_half - crown) * green, w)
    glass = np.zeros_like(s)
    for a, b in windows:
        glass[(s >= a) & (s <= b)] = 1.0
    glass[[0, -1]] = 0.0
    return loft(x_of(s), _sections(zf, zb, zt, w, wt, recess * glass * green, n_low, n_up))


def wheel_house(x: float, r: float, arch: float, floor: float, half_gap: float) -> tuple[np.ndarray, np.ndarray]:
    """The inside of a wheel arch between the wheels of one axle at x: a solid from ``floor`` up to
    the arch (radius ``arch`` - 1 cm about the axle at height ``r``), for |y| <= ``half_gap``, so
    that the arch is a wheel well at each side, not a tunnel across the car (a tombstone-shaped
    section lofted along y)."""
    a = arch - 0.01
    t = np.linspace(np.pi, 0.0, 15)
    ring = np.concatenate([[[x - a, floor]], np.column_stack([x + a * np.cos(t), r + a * np.sin(t)]), [[x + a, floor]]])
    v, f = loft(np.array([-half_gap, half_gap]), np.stack([ring, ring]))
    return outward(v[:, [1, 0, 2]], f)


def wheel_pair(x: float, half: float, tyre: float, r: float) -> list:
    """Left and right wheels (radius ``r``, ``tyre`` wide) of one axle at x, their outer faces at
    |y| = ``half`` - 0.02 m."""
    y1 = half - 0.02
    return [wheel(x, y1 - tyre, y1, r), wheel(x, -y1, -y1 + tyre, r)]
