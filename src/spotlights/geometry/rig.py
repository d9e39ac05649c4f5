"""The Spotlights ray rig (paper Sections 3.1-3.2).

A rig is N *primary* viewpoints on the unit sphere (the paper's spherical
Fibonacci lattice) each casting M rays toward the centre, the ray directions
being M *secondary* points Fibonacci-sampled with equal area on a spherical cap
of polar half-angle ``omega`` around the inward direction.

Conventions (fixed forever: the ray order *is* the representation)
------------------------------------------------------------------
* Primary point i (0 <= i < N), paper lattice::

      x_i = frac(i / Phi),  y_i = i / N,
      phi_i = 2 pi x_i,     theta_i = arccos(1 - 2 y_i),
      p_i = (sin theta_i cos phi_i, sin theta_i sin phi_i, cos theta_i)

  so p_0 is the north pole (0, 0, 1).
* Cap sample k (0 <= k < M), the same lattice on a cap of half-angle omega
  (equal area: the cap area between polar angle 0 and t is proportional to
  1 - cos t)::

      cos t_k = 1 - (1 - cos omega) k / M,   psi_k = 2 pi frac(k / Phi)

  so sample 0 is the central ray, straight toward the sphere's centre.
* Local frame of viewpoint i: ``w = -p_i`` (toward the centre);
  ``a = e_z`` unless ``|w . e_z| > 0.9``, then ``a = e_x``;
  ``u = normalize(a x w)``, ``v = w x u``. Cap sample k maps to the direction
  ``d = cos t_k w + sin t_k (cos psi_k u + sin psi_k v)``.
* Ray ``i*M + k`` starts at ``p_i`` (on the unit sphere) with direction ``d``.
  The paper's secondary point is ``P2 = p_i + r d`` on the small sphere of
  radius ``r = 2 R cos omega`` around ``p_i`` (``omega = arccos(r / 2R)``).

All arrays are float64 in the *unit frame* (the object's circumscribed sphere
scaled to radius 1).

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

import math
import re
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from ..errors import ParameterError

GOLDEN_RATIO = (1.0 + math.sqrt(5.0)) / 2.0
MAX_RAYS = 1 << 24
"""Most rays one rig may hold (N * M): 16.8 million, ~1.2 GB of float64 rays."""
RIG_KINDS = ("cap", "box")
BOX_TARGETS = ("volume", "surface", "visible", "ellipsoid")
# Parameters of a box rig left unset (the best variant of docs/box-rig.md).
BOX_DEFAULTS = {"scale": 1.0, "targets": "ellipsoid", "cap_share": 0.0}
HALTON_BASES = (2, 3, 5)


def fibonacci_lattice_2d(n: int) -> np.ndarray:
    """The paper's 2-D Fibonacci lattice on [0, 1)^2.

    Returns
    -------
    (n, 2) float64 array of ``(x_i, y_i) = (frac(i / Phi), i / n)``.
    """
    _check_count(n, "n")
    i = np.arange(n, dtype=np.float64)
    return np.stack([np.mod(i / GOLDEN_RATIO, 1.0), i / n], axis=1)


def fibonacci_sphere(n: int) -> np.ndarray:
    """N points on the unit sphere from the paper's spherical Fibonacci lattice.

    ``phi = 2 pi x_i``, ``theta = arccos(1 - 2 y_i)``; point 0 is (0, 0, 1).

    Returns
    -------
    (n, 3) float64 unit vectors.
    """
    lat = fibonacci_lattice_2d(n)
    phi = 2.0 * np.pi * lat[:, 0]
    theta = np.arccos(1.0 - 2.0 * lat[:, 1])
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=1)


def cap_directions(m: int, angle_deg: float) -> np.ndarray:
    """M equal-area Fibonacci directions on the cap of half-angle ``angle_deg`` around +z.

    Returns
    -------
    (m, 3) float64 unit vectors with polar angle <= ``angle_deg`` from +z;
    direction 0 is +z itself.
    """
    _check_count(m, "m")
    omega = math.radians(_check_angle(angle_deg))
    lat = fibonacci_lattice_2d(m)
    cos_t = 1.0 - (1.0 - math.cos(omega)) * lat[:, 1]
    sin_t = np.sqrt(np.clip(1.0 - cos_t**2, 0.0, None))
    psi = 2.0 * np.pi * lat[:, 0]
    return np.stack([sin_t * np.cos(psi), sin_t * np.sin(psi), cos_t], axis=1)


def viewpoint_frames(primary: np.ndarray) -> np.ndarray:
    """Deterministic local frames ``(u, v, w)`` of viewpoints on the unit sphere.

    Parameters
    ----------
    primary : (N, 3) float64 unit vectors (viewpoint positions).

    Returns
    -------
    (N, 3, 3) float64; ``frames[i]`` has rows ``u, v, w`` with ``w = -p_i``
    (see the module docstring for ``u`` and ``v``). Right-handed: ``u x v = w``.
    """
    w = -np.asarray(primary, dtype=np.float64)
    a = np.zeros_like(w)
    near_z = np.abs(w[:, 2]) > 0.9
    a[~near_z, 2] = 1.0
    a[near_z, 0] = 1.0
    u = np.cross(a, w)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(w, u)
    return np.stack([u, v, w], axis=1)


def cap_ray_directions(primary: np.ndarray, m: int, angle_deg: float) -> np.ndarray:
    """The paper's ray bundles: cap sample k of every viewpoint, in world coordinates.

    Parameters
    ----------
    primary : (N, 3) float64 viewpoints on the unit sphere.
    m : samples per cap; angle_deg : cap half-angle in degrees.

    Returns
    -------
    (N, m, 3) float64 unit vectors; ``[i, k]`` is direction k of viewpoint i.
    """
    local = cap_directions(m, angle_deg)  # (m, 3) in (u, v, w) coordinates
    d = np.einsum("mj,njc->nmc", local, viewpoint_frames(primary))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return d


def angle_from_radius(radius: float) -> float:
    """Cap half-angle in degrees from the small-sphere radius ``r / R`` (``omega = arccos(r / 2R)``)."""
    if not (0.0 <= radius < 2.0) or not math.isfinite(radius):
        raise ParameterError(f"small-sphere radius r/R must be in [0, 2), got {radius}")
    return math.degrees(math.acos(radius / 2.0))


def halton(n: int, bases: tuple[int, ...] = HALTON_BASES, start: int = 1) -> np.ndarray:
    """The Halton sequence: radical inverses of the indices ``start .. start + n - 1``.

    Returns
    -------
    (n, len(bases)) float64 in [0, 1); column j is the radical inverse in ``bases[j]``
    (index 1 in base 2 is 0.5, index 2 is 0.25, ...).
    """
    _check_count(n, "n")
    idx = np.arange(start, start + n, dtype=np.int64)
    out = np.zeros((n, len(bases)), dtype=np.float64)
    for j, b in enumerate(bases):
        rest, f = idx.copy(), 1.0
        while np.any(rest > 0):  # one pass per digit, vectorised over the indices
            f /= b
            out[:, j] += f * (rest % b)
            rest //= b
    return out


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


@dataclass(frozen=True)
class Rig:
    """A Spotlights rig: N viewpoints x M rays, on the paper's cap or aimed at a box.

    Attributes
    ----------
    n_primary : N, number of viewpoints (>= 1).
    n_secondary : M, rays per viewpoint (>= 1).
    angle : cap polar half-angle omega in degrees, in (0, 90] (box rigs: the
        half-angle of their cap part, used only when ``cap_share > 0``).
    kind : ``"cap"`` (the paper's rig) or ``"box"`` (box-targeted, docs/box-rig.md).
    box : box rigs only: (3,) box half-extents ``e`` in the unit frame (``size / 2R``),
        a tuple of floats.
    scale : box rigs only: target scale s in (0, 1] (default ``BOX_DEFAULTS``).
    targets : box rigs only: target set, one of ``BOX_TARGETS``.
    cap_share : box rigs only: share of each viewpoint's rays on the cap, in [0, 1).

    Cap rigs leave the four box fields ``None``. The ray arrays are computed once
    and cached; they are float64, unit frame. A box rig is usually built from its
    box-independent :class:`RigSpec`: ``spec.for_box(extents)``.
    """

    n_primary: int = 32
    n_secondary: int = 64
    angle: float = 60.0
    kind: str = "cap"
    box: tuple | None = None
    scale: float | None = None
    targets: str | None = None
    cap_share: float | None = None

    def __post_init__(self):
        spec = RigSpec(
            self.n_primary, self.n_secondary, self.angle, self.kind, self.scale, self.targets, self.cap_share
        )  # validates, fills the box defaults
        for key in ("n_primary", "n_secondary", "angle", "scale", "targets", "cap_share"):
            object.__setattr__(self, key, getattr(spec, key))
        self.__dict__["spec"] = spec  # the cached property below
        if self.kind == "box":
            if self.box is None:
                raise ParameterError(
                    "a box rig needs the box half-extents (box=...); a description without a box is a "
                    "RigSpec: RigSpec.from_dict(d).for_box(extents)"
                )
            object.__setattr__(self, "box", check_extents(self.box))
        elif self.box is not None:
            raise ParameterError("box half-extents are only for box rigs (kind='box')")

    @property
    def n_rays(self) -> int:
        """N * M."""
        return self.n_primary * self.n_secondary

    @property
    def name(self) -> str:
        """A stable identifier such as ``"cap-32x64-60"`` or ``"box-32x64-visible-s0.9"``.

        A box rig's name is its spec's (:attr:`RigSpec.name`): it names the rule, not
        the box, so rigs of one spec for different boxes share it.
        """
        return self.spec.name

    @cached_property
    def spec(self) -> RigSpec:
        """The box-independent description of this rig (set on construction)."""
        return RigSpec(
            self.n_primary, self.n_secondary, self.angle, self.kind, self.scale, self.targets, self.cap_share
        )

    @property
    def extents(self) -> np.ndarray | None:
        """(3,) float64 box half-extents (unit frame) of a box rig, else None."""
        return None if self.box is None else np.array(self.box, dtype=np.float64)

    @property
    def small_sphere_radius(self) -> float:
        """The paper's small-sphere radius r / R = 2 cos(omega)."""
        return 2.0 * math.cos(math.radians(self.angle))

    @cached_property
    def primary(self) -> np.ndarray:
        """(N, 3) float64 viewpoint positions on the unit sphere."""
        return _readonly(fibonacci_sphere(self.n_primary))

    @cached_property
    def frames(self) -> np.ndarray:
        """(N, 3, 3) float64 local frames, rows ``u, v, w`` (``w`` toward the centre)."""
        return _readonly(viewpoint_frames(self.primary))

    @cached_property
    def origins(self) -> np.ndarray:
        """(N*M, 3) float64 ray origins: row ``i*M + k`` is ``p_i``."""
        return _readonly(np.repeat(self.primary, self.n_secondary, axis=0))

    @cached_property
    def directions(self) -> np.ndarray:
        """(N*M, 3) float64 unit ray directions: row ``i*M + k`` is sample k of viewpoint i."""
        if self.kind == "box":
            d = box_directions(
                self.primary, self.n_secondary, self.extents, self.scale, self.targets, self.cap_share, self.angle
            )
            return _readonly(np.ascontiguousarray(d))
        return _readonly(cap_ray_directions(self.primary, self.n_secondary, self.angle).reshape(-1, 3))

    @property
    def secondary(self) -> np.ndarray:
        """(N*M, 3) float64 secondary points ``P2 = P1 + r d`` on the small sphere (r = 2 cos omega; cap rigs)."""
        return self.origins + self.small_sphere_radius * self.directions

    @cached_property
    def chord_lengths(self) -> np.ndarray:
        """(N*M,) float64 length of each ray's chord inside the unit sphere (``-2 o.d``)."""
        return _readonly(np.clip(-2.0 * np.einsum("ij,ij->i", self.origins, self.directions), 0.0, 2.0))

    @cached_property
    def half_chords32(self) -> np.ndarray:
        """(N*M,) float32 half chord lengths (+ 5e-7 float32 slack): the largest valid depth per ray."""
        return _readonly((self.chord_lengths / 2.0 + 5e-7).astype(np.float32))

    @cached_property
    def rays32(self) -> tuple[np.ndarray, np.ndarray]:
        """``(origins, directions)`` as C-contiguous float32 (N*M, 3) arrays, for ray engines."""
        return _readonly(self.origins.astype(np.float32)), _readonly(self.directions.astype(np.float32))

    def to_dict(self) -> dict:
        """JSON-serialisable description; ``Rig.from_dict`` rebuilds the identical rig.

        Cap rigs: ``{"kind", "n_primary", "n_secondary", "angle"}``; box rigs add
        ``"box"`` (3 floats), ``"scale"``, ``"targets"`` and ``"cap_share"``.
        """
        d = self.spec.to_dict()
        if self.box is not None:
            d["box"] = list(self.box)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Rig:
        """Rebuild a rig from :meth:`to_dict` output (either kind)."""
        spec = RigSpec.from_dict(d)
        if spec.needs_box and d.get("box") is None:
            raise ParameterError(
                f"rig description {d!r} has no box: it is a RigSpec (RigSpec.from_dict(d).for_box(extents))"
            )
        return spec.for_box(d.get("box"))


@dataclass(frozen=True)
class RigSpec:
    """A rig's box-independent description; ``for_box(extents)`` gives the concrete :class:`Rig`.

    Same fields as :class:`Rig` without ``box``. A cap spec's rig does not depend on
    the box (``for_box`` accepts ``None``); a box spec's rig does. This is what a
    dataset, a model or a command line holds; each object's encoding stores the
    concrete rig (``Rig.to_dict()`` carries the box), so it always decodes alone.

    Per-object rigs (datasets with one box per model, models predicting per-sample
    depths): ``spec.for_box(e)`` is cached by the exact extents (the last 64
    boxes); for a batch, :meth:`directions_for_boxes` gives every sample's rays in
    one vectorised call, and :attr:`origins` are shared by all boxes.
    """

    n_primary: int = 32
    n_secondary: int = 64
    angle: float = 60.0
    kind: str = "cap"
    scale: float | None = None
    targets: str | None = None
    cap_share: float | None = None

    def __post_init__(self):
        if self.kind not in RIG_KINDS:
            raise ParameterError(f"unknown rig kind {self.kind!r}; known: {', '.join(RIG_KINDS)}")
        object.__setattr__(self, "n_primary", _check_count(self.n_primary, "number of primary viewpoints N"))
        object.__setattr__(self, "n_secondary", _check_count(self.n_secondary, "number of secondary rays M"))
        if self.n_primary * self.n_secondary > MAX_RAYS:
            raise ParameterError(
                f"N * M = {self.n_primary * self.n_secondary:,} rays is more than the {MAX_RAYS:,} "
                "one rig may hold (its arrays alone would need > 1 GB)"
            )
        object.__setattr__(self, "angle", float(_check_angle(self.angle)))
        for key, value in _check_box_params(self.kind, self.scale, self.targets, self.cap_share).items():
            object.__setattr__(self, key, value)

    @property
    def needs_box(self) -> bool:
        """True when the rays depend on the object's box (box rigs)."""
        return self.kind == "box"

    @property
    def n_rays(self) -> int:
        """N * M."""
        return self.n_primary * self.n_secondary

    @property
    def name(self) -> str:
        """``"cap-32x64-60"``; box specs ``"box-32x64-visible-s0.9"`` (+ ``"-cap0.25@60"`` when mixed)."""
        if self.kind == "cap":
            return f"cap-{self.n_primary}x{self.n_secondary}-{self.angle:g}"
        name = f"box-{self.n_primary}x{self.n_secondary}-{self.targets}-s{self.scale:g}"
        return name + (f"-cap{self.cap_share:g}@{self.angle:g}" if self.cap_share else "")

    @classmethod
    def from_name(cls, name: str) -> RigSpec:
        """Parse :attr:`name` (``"cap-32x64-60"``, ``"box-32x64-ellipsoid-s1"``, ``"box-32x64-volume-s0.8-cap0.25@60"``).

        Names print numbers with 6 significant digits, so only such parameters round-trip
        exactly (``to_dict`` always does).
        """
        s = str(name).strip().lower()
        m = re.fullmatch(r"cap-(\d+)x(\d+)-([0-9.]+)", s)
        if m:
            return cls(int(m.group(1)), int(m.group(2)), float(m.group(3)))
        m = re.fullmatch(r"box-(\d+)x(\d+)-([a-z]+)-s([0-9.]+)(?:-cap([0-9.]+)@([0-9.]+))?", s)
        if m:
            return cls(
                int(m.group(1)),
                int(m.group(2)),
                float(m.group(6) or 60.0),
                "box",
                float(m.group(4)),
                m.group(3),
                float(m.group(5) or 0.0),
            )
        raise ParameterError(f"rig name {name!r} not understood; e.g. cap-32x64-60 or box-32x64-visible-s0.9")

    @property
    def origins(self) -> np.ndarray:
        """(N*M, 3) float64 ray origins, the same for every box (read-only)."""
        return _spec_rig(RigSpec(self.n_primary, self.n_secondary, self.angle), None).origins

    def for_box(self, extents=None) -> Rig:
        """The concrete rig for a box of half-extents ``extents`` (3,) in the unit frame (``size / 2R``).

        Cap specs ignore ``extents`` (may be None). Results are cached by the exact
        extents, so repeated calls for one object are free.
        """
        if not self.needs_box:
            return _spec_rig(self, None)
        if extents is None:
            raise ParameterError(f"rig {self.name} is aimed at the object's box: give its half-extents")
        return _spec_rig(self, check_extents(extents))

    def for_normalization(self, normalization) -> Rig:
        """The concrete rig for an object normalised by ``normalization`` (its box: ``size / 2R``)."""
        if not self.needs_box:
            return self.for_box(None)
        return self.for_box(extents_from_normalization(normalization))

    def directions_for_boxes(self, extents: np.ndarray) -> np.ndarray:
        """Ray directions for a batch of boxes, vectorised (no per-box rig objects).

        Parameters
        ----------
        extents : (B, 3) float box half-extents, unit frame (ignored by cap specs,
            whose directions are broadcast).

        Returns
        -------
        (B, N*M, 3) float64 unit vectors; row b equals ``for_box(extents[b]).directions``.
        """
        e = np.asarray(extents, dtype=np.float64).reshape(-1, 3)
        if not self.needs_box:
            return np.broadcast_to(self.for_box(None).directions, (len(e), self.n_rays, 3))
        check_extents(e)
        return box_directions(
            fibonacci_sphere(self.n_primary), self.n_secondary, e, self.scale, self.targets, self.cap_share, self.angle
        )

    def to_dict(self) -> dict:
        """JSON-serialisable description (cap specs: exactly a cap rig's ``to_dict()``)."""
        d = {"kind": self.kind, "n_primary": self.n_primary, "n_secondary": self.n_secondary, "angle": self.angle}
        if self.kind == "box":
            d.update(scale=self.scale, targets=self.targets, cap_share=self.cap_share)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> RigSpec:
        """Rebuild from :meth:`to_dict` output; a rig's ``to_dict()`` also works (its box is dropped)."""
        try:
            return cls(
                int(d["n_primary"]),
                int(d["n_secondary"]),
                float(d["angle"]),
                str(d.get("kind", "cap")),
                _opt(float, d.get("scale")),
                _opt(str, d.get("targets")),
                _opt(float, d.get("cap_share")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ParameterError(f"invalid rig description {d!r}: {exc}") from None


@lru_cache(maxsize=64)
def _spec_rig(spec: RigSpec, box: tuple | None) -> Rig:
    return Rig(spec.n_primary, spec.n_secondary, spec.angle, spec.kind, box, spec.scale, spec.targets, spec.cap_share)


def check_extents(extents) -> tuple:
    """Validate box half-extents (unit frame): 3 finite values >= 0, not all 0, norm <= 1 (+1e-6).

    ``extents`` is (3,) or a batch (B, 3) (every row checked). Returns the (3,) input
    as a tuple of 3 Python floats (the form :class:`Rig` stores), a batch as a
    tuple of such tuples.
    """
    try:
        e = np.asarray(extents, dtype=np.float64)
        rows = e.reshape(-1, 3) if e.ndim == 2 else e.reshape(1, 3)
    except (TypeError, ValueError):
        raise ParameterError(f"box half-extents must be 3 numbers (or rows of 3), got {extents!r}") from None
    bad = ~np.all(np.isfinite(rows), axis=1) | np.any(rows < 0, axis=1) | ~np.any(rows > 0, axis=1)
    if np.any(bad):
        raise ParameterError(
            f"box half-extents must be finite, >= 0 and not all 0, got {rows[np.argmax(bad)].tolist()}"
        )
    norm = np.linalg.norm(rows, axis=1)
    if np.any(norm > 1.0 + 1e-6):
        j = int(np.argmax(norm))
        raise ParameterError(
            f"box half-extents {rows[j].tolist()} reach outside the unit sphere (norm {norm[j]:.6g} > 1)"
        )
    out = tuple(tuple(float(x) for x in row) for row in rows)
    return out if e.ndim == 2 else out[0]


def extents_from_normalization(normalization) -> np.ndarray:
    """(3,) float64 box half-extents in the unit frame, ``size / (2 R)``, of a :class:`Normalization`."""
    size = getattr(normalization, "size", None)
    if size is None:
        raise ParameterError("this normalisation has no box size; a box rig needs the object's box")
    return np.asarray(size, dtype=np.float64) / (2.0 * float(normalization.radius))


def make_rig(
    primary: int = 32,
    secondary: int = 64,
    angle: float | None = 60.0,
    radius: float | None = None,
    *,
    kind: str = "cap",
    box=None,
    scale: float | None = None,
    targets: str | None = None,
    cap_share: float | None = None,
) -> Rig:
    """Build a rig: the paper's cap rig by default, a box-targeted rig with ``kind="box"``.

    Parameters
    ----------
    primary : N viewpoints (paper: 32).
    secondary : M rays per viewpoint (paper: 64).
    angle : cap half-angle omega in degrees, in (0, 90] (paper: 60).
    radius : alternatively the small-sphere radius r / R; ``omega = arccos(r / 2R)``
        (the paper's r = R/4 gives 82.82 degrees). Overrides ``angle`` when given.
    kind : ``"cap"`` or ``"box"``.
    box : box rigs: (3,) box half-extents in the unit frame (required).
    scale, targets, cap_share : box rigs: see :class:`Rig` (defaults ``BOX_DEFAULTS``).
    """
    return make_rig_spec(
        primary, secondary, angle, radius, kind=kind, scale=scale, targets=targets, cap_share=cap_share
    ).for_box(box)


def make_rig_spec(
    primary: int = 32,
    secondary: int = 64,
    angle: float | None = 60.0,
    radius: float | None = None,
    *,
    kind: str = "cap",
    scale: float | None = None,
    targets: str | None = None,
    cap_share: float | None = None,
) -> RigSpec:
    """Build a :class:`RigSpec` (same parameters as :func:`make_rig`, without the box)."""
    if radius is not None:
        angle = angle_from_radius(float(radius))
    if angle is None:
        raise ParameterError("give the cap angle or the small-sphere radius")
    return RigSpec(primary, secondary, angle, kind, scale, targets, cap_share)


def _check_box_params(kind: str, scale, targets, cap_share) -> dict:
    """Validated box parameters (defaults filled in) for box kinds; all None for cap kinds."""
    if kind != "box":
        if any(v is not None for v in (scale, targets, cap_share)):
            raise ParameterError("scale, targets and cap_share are only for box rigs (kind='box')")
        return {"scale": None, "targets": None, "cap_share": None}
    scale = BOX_DEFAULTS["scale"] if scale is None else scale
    targets = BOX_DEFAULTS["targets"] if targets is None else targets
    cap_share = BOX_DEFAULTS["cap_share"] if cap_share is None else cap_share
    try:
        scale, cap_share = float(scale), float(cap_share)
    except (TypeError, ValueError):
        raise ParameterError(f"box scale and cap share must be numbers, got {scale!r}, {cap_share!r}") from None
    if not (0.0 < scale <= 1.0):
        raise ParameterError(f"box target scale must be in (0, 1], got {scale!r}")
    if targets not in BOX_TARGETS:
        raise ParameterError(f"unknown box target set {targets!r}; known: {', '.join(BOX_TARGETS)}")
    if not (0.0 <= cap_share < 1.0):
        raise ParameterError(f"cap share must be in [0, 1), got {cap_share!r}")
    return {"scale": scale, "targets": str(targets), "cap_share": cap_share}


def _opt(cast, value):
    return None if value is None else cast(value)


def _check_count(n, what: str) -> int:
    try:
        ok = float(n).is_integer() and int(n) >= 1
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ParameterError(f"{what} must be an integer >= 1, got {n!r}")
    return int(n)


def _check_angle(angle) -> float:
    try:
        a = float(angle)
    except (TypeError, ValueError):
        raise ParameterError(f"cap angle must be a number of degrees in (0, 90], got {angle!r}") from None
    if not (0.0 < a <= 90.0):
        raise ParameterError(f"cap angle must be in (0, 90] degrees, got {angle!r}")
    return a


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a
