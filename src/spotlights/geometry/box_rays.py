"""Ray directions of box-targeted rigs (beyond the paper; docs/box-rig.md).

:class:`~spotlights.geometry.rig.Rig` (``kind="box"``) and
:meth:`~spotlights.geometry.rig.RigSpec.directions_for_boxes` call :func:`box_directions`; the
viewpoints are the paper's (:mod:`spotlights.geometry.lattice`).

Box-targeted rigs (``kind="box"``, beyond the paper; docs/box-rig.md)
---------------------------------------------------------------------
The same N viewpoints ``p_i``, but each viewpoint's M rays are aimed at the
object's box instead of spread over a cap. In the unit frame the box is
axis-aligned with half-extents ``e`` (``e = size / 2R``, so ``|e| = 1``); ``s``
in (0, 1] scales it (``se = s * e``). Ray ``i*M + k`` starts at ``p_i`` with
direction ``normalize(t_ik - p_i)`` toward a target ``t_ik = se * u_ik``, ``u_ik``
a position in the normalised box ``[-1, 1]^3``. Target sets (``targets=``):

* ``"ellipsoid"`` (the default): where the inscribed ellipsoid ``|x / se| <= 1``
  is the unit ball, the viewpoint is ``q_i = p_i / se``; the ball's tangent cone
  from ``q_i`` cuts the plane through the centre normal to ``q_i`` in a disc of
  radius ``rho = L / sqrt(L^2 - 1)``, ``L = |q_i|``. Sample k is the paper's
  lattice mapped with equal area onto that disc: ``u_ik = rho sqrt(k / M)
  (cos psi_k a_i + sin psi_k b_i)``, ``psi_k = 2 pi frac(k / Phi)``, with ``a_i``
  viewpoint i's ``u`` axis made orthogonal to ``q_i`` and ``b_i = (-q_i / L) x a_i``.
  Every ray meets the ellipsoid (so the box); sample 0 is the central ray.
* ``"volume"``: ``u_k = 2 H(k + 1) - 1``, H the Halton sequence in bases 2, 3, 5;
  the same M targets for every viewpoint.
* ``"surface"``: fixed points on the six faces of the cube, M / 6 per face.
* ``"visible"``: per viewpoint, points on the faces of the scaled box that face
  the viewpoint, face shares proportional to the solid angle each face subtends
  there. Its face shares move with the box proportions, so a ray near a face
  boundary can switch faces between two boxes: a study variant only.

The face-based sets place the 2-D lattice ``(a_k, b_k) = (frac(k / Phi),
(k + 1/2) / M)``: ``b`` is cut into consecutive intervals, one per face, of
lengths equal to the face shares; sample k goes to the face whose interval holds
``b_k``, at face coordinates ``(a_k, (b_k - start) / length)``. A mixed rig
(``cap_share = c > 0``) gives the first ``C = min(round(c M), M - 1)`` rays of
every viewpoint the paper's cap of half-angle ``angle`` (C cap samples) and aims
the others at the box. The rays depend only on (N, M, the target parameters, e),
and ray ``i*M + k`` always aims at the same normalised place of the box.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from .lattice import GOLDEN_RATIO, cap_ray_directions, fibonacci_lattice_2d, halton, viewpoint_frames

BOX_TARGETS = ("volume", "surface", "visible", "ellipsoid")


def box_face_solid_angles(points: np.ndarray, extents: np.ndarray) -> np.ndarray:
    """Solid angle each face of the box ``[-e, e]`` subtends at points outside it.

    Faces are ordered ``+x, -x, +y, -y, +z, -z``. A face seen from behind (the
    point not strictly on its outer side) counts 0. Exact closed form for a
    rectangle ``[x1, x2] x [y1, y2]`` at height ``h`` below the point:
    ``F(x2, y2) - F(x1, y2) - F(x2, y1) + F(x1, y1)``, ``F(x, y) = atan2(x y, h sqrt(x^2 + y^2 + h^2))``.

    Parameters
    ----------
    points : (..., 3) float64, unit frame.
    extents : (..., 3) float64 box half-extents (broadcast against ``points``).

    Returns
    -------
    (..., 6) float64 steradians, >= 0.
    """
    p = np.asarray(points, dtype=np.float64)
    e = np.asarray(extents, dtype=np.float64)
    p, e = np.broadcast_arrays(p, e)
    out = np.zeros(p.shape[:-1] + (6,), dtype=np.float64)
    for face in range(6):
        a, sign = face // 2, 1.0 - 2.0 * (face % 2)
        b, c = (a + 1) % 3, (a + 2) % 3
        h = sign * p[..., a] - e[..., a]
        hp = np.where(h > 0, h, 1.0)
        x1, x2 = -e[..., b] - p[..., b], e[..., b] - p[..., b]
        y1, y2 = -e[..., c] - p[..., c], e[..., c] - p[..., c]

        def f(x, y):
            return np.arctan2(x * y, hp * np.sqrt(x * x + y * y + hp * hp))

        out[..., face] = np.where(h > 0, f(x2, y2) - f(x1, y2) - f(x2, y1) + f(x1, y1), 0.0)
    return out


def _face_points(weights: np.ndarray, m: int) -> np.ndarray:
    """Normalised positions on the cube's faces for the face-based target sets.

    ``weights`` (..., 6) >= 0 (faces ``+x, -x, +y, -y, +z, -z``, not all 0) are the face
    shares; sample k of the lattice ``(a_k, b_k) = (frac(k / Phi), (k + 1/2) / m)``
    goes to the face whose interval of ``b`` holds ``b_k`` (see the module docstring).

    Returns
    -------
    (..., m, 3) float64 positions ``u`` on the surface of ``[-1, 1]^3``.
    """
    c = np.cumsum(np.asarray(weights, dtype=np.float64), axis=-1)
    upper = c / c[..., -1:]  # trailing empty faces get exactly 1.0
    lower = np.concatenate([np.zeros_like(upper[..., :1]), upper[..., :-1]], axis=-1)
    w = upper - lower
    k = np.arange(m, dtype=np.float64)
    a = np.mod(k / GOLDEN_RATIO, 1.0)
    b = (k + 0.5) / m
    face = np.count_nonzero(b[:, None] >= upper[..., None, :5], axis=-1)  # (..., m)
    lo = np.take_along_axis(lower, face, axis=-1)
    width = np.take_along_axis(w, face, axis=-1)
    local = np.clip((b - lo) / np.where(width > 0, width, 1.0), 0.0, 1.0)
    axis, sign = face // 2, 1.0 - 2.0 * (face % 2)
    u = np.empty(face.shape + (3,), dtype=np.float64)
    ax = axis[..., None] == np.arange(3)
    u_b = (axis[..., None] + 1) % 3 == np.arange(3)
    u[...] = np.where(ax, sign[..., None], 0.0)
    u += np.where(u_b, 2.0 * np.broadcast_to(a, face.shape)[..., None] - 1.0, 0.0)
    u += np.where(~ax & ~u_b, 2.0 * local[..., None] - 1.0, 0.0)
    return u


def box_targets(primary: np.ndarray, m: int, extents: np.ndarray, scale: float, targets: str) -> np.ndarray:
    """The box-targeted rig's target points (see the module docstring).

    Parameters
    ----------
    primary : (N, 3) float64 viewpoints on the unit sphere.
    m : targets per viewpoint.
    extents : (B, 3) float64 box half-extents in the unit frame.
    scale : s in (0, 1]: targets lie in (or on) the box ``[-s e, s e]``.
    targets : one of ``BOX_TARGETS`` (``"volume"``, ``"surface"``, ``"visible"``, ``"ellipsoid"``).

    Returns
    -------
    (B, N, m, 3) float64 target points, unit frame (for ``"volume"`` and ``"surface"``
    the N viewpoints share theirs: a broadcast view).
    """
    e = np.asarray(extents, dtype=np.float64).reshape(-1, 3)
    p = np.asarray(primary, dtype=np.float64)
    se = scale * e  # (B, 3)
    if targets == "volume":
        u = 2.0 * halton(m) - 1.0  # (m, 3)
        t = se[:, None, :] * u[None]  # (B, m, 3)
        return np.broadcast_to(t[:, None], (len(e), len(p), m, 3))
    if targets == "surface":
        u = _face_points(np.ones(6), m)  # (m, 3): fixed positions, M / 6 per face of the cube
        return np.broadcast_to((se[:, None, :] * u[None])[:, None], (len(e), len(p), m, 3))
    if targets == "visible":
        omega = box_face_solid_angles(p[None, :, :], se[:, None, :])  # (B, N, 6)
        empty = omega.sum(axis=-1) <= 0  # a viewpoint on the scaled box (only possible for s = 1)
        omega[empty] = 1.0
        u = _face_points(omega, m)  # (B, N, m, 3)
        return se[:, None, None, :] * u
    if targets == "ellipsoid":
        # Work where the ellipsoid [x / (s e)]^2 <= 1 is the unit ball: the viewpoint is q = p / (s e).
        se = np.maximum(se, 1e-12)  # a flat box: a flat ellipsoid
        q = p[None, :, :] / se[:, None, :]  # (B, N, 3)
        big = np.linalg.norm(q, axis=-1, keepdims=True)  # > 1: the viewpoint is outside the ellipsoid
        w = -q / big
        u = np.broadcast_to(viewpoint_frames(p)[None, :, 0, :], q.shape)  # viewpoint i's own u axis
        u = u - np.sum(u * w, axis=-1, keepdims=True) * w  # never parallel to w (see docs/box-rig.md)
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
        v = np.cross(w, u)
        rho = big / np.sqrt(np.maximum(big * big - 1.0, 1e-12))  # radius of the tangent cone at the centre
        lat = fibonacci_lattice_2d(m)  # the paper's lattice, mapped with equal area onto the unit disc
        r, psi = np.sqrt(lat[:, 1]), 2.0 * np.pi * lat[:, 0]
        c = (
            rho[..., None, :] * (r * np.cos(psi))[:, None] * u[..., None, :]
            + rho[..., None, :] * (r * np.sin(psi))[:, None] * v[..., None, :]
        )  # (B, N, m, 3)
        return se[:, None, None, :] * c
    raise ParameterError(f"unknown box target set {targets!r}; known: {', '.join(BOX_TARGETS)}")


def box_directions(
    primary: np.ndarray,
    m: int,
    extents: np.ndarray,
    scale: float,
    targets: str,
    cap_share: float = 0.0,
    angle: float = 60.0,
) -> np.ndarray:
    """Unit ray directions of box-targeted rigs, for one or many boxes at once.

    Parameters
    ----------
    primary : (N, 3) float64 viewpoints on the unit sphere.
    m : M rays per viewpoint.
    extents : (B, 3) (or (3,)) float64 box half-extents, unit frame.
    scale, targets : the target set (see :func:`box_targets`).
    cap_share : share c in [0, 1) of each viewpoint's rays on the paper's cap
        (the first ``min(round(c M), M - 1)``), the others aimed at the box.
    angle : half-angle in degrees of that cap.

    Returns
    -------
    (B, N*M, 3) float64 unit vectors (``(N*M, 3)`` when ``extents`` is (3,)), ray
    ``i*M + k`` = viewpoint i, sample k.
    """
    single = np.ndim(extents) == 1
    e = np.asarray(extents, dtype=np.float64).reshape(-1, 3)
    p = np.asarray(primary, dtype=np.float64)
    m_cap = min(int(round(cap_share * m)), m - 1)  # at least one ray aimed at the box
    t = box_targets(p, m - m_cap, e, scale, targets)  # (B, N, m - m_cap, 3)
    d = t - p[None, :, None, :]
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    d = np.where(norm > 1e-12, d / np.where(norm > 1e-12, norm, 1.0), -p[None, :, None, :])
    if m_cap:
        cap = cap_ray_directions(p, m_cap, angle)  # (N, m_cap, 3)
        d = np.concatenate([np.broadcast_to(cap[None], (len(e),) + cap.shape), d], axis=2)
    d = d.reshape(len(e), -1, 3)
    return d[0] if single else d
