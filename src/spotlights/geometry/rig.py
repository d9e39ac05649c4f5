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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import ParameterError

GOLDEN_RATIO = (1.0 + math.sqrt(5.0)) / 2.0
RIG_KINDS = ("cap",)


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


def angle_from_radius(radius: float) -> float:
    """Cap half-angle in degrees from the small-sphere radius ``r / R`` (``omega = arccos(r / 2R)``)."""
    if not (0.0 <= radius < 2.0) or not math.isfinite(radius):
        raise ParameterError(f"small-sphere radius r/R must be in [0, 2), got {radius}")
    return math.degrees(math.acos(radius / 2.0))


@dataclass(frozen=True)
class Rig:
    """A Spotlights rig: N viewpoints x M rays on a cap of half-angle ``angle`` degrees.

    Attributes
    ----------
    n_primary : N, number of viewpoints (>= 1).
    n_secondary : M, rays per viewpoint (>= 1).
    angle : cap polar half-angle omega in degrees, in (0, 90].
    kind : rig kind; ``"cap"`` is the paper's rig.

    The ray arrays are computed once and cached; they are float64, unit frame.
    """

    n_primary: int = 32
    n_secondary: int = 64
    angle: float = 60.0
    kind: str = "cap"

    def __post_init__(self):
        if self.kind not in RIG_KINDS:
            raise ParameterError(f"unknown rig kind {self.kind!r}; known: {', '.join(RIG_KINDS)}")
        object.__setattr__(self, "n_primary", _check_count(self.n_primary, "number of primary viewpoints N"))
        object.__setattr__(self, "n_secondary", _check_count(self.n_secondary, "number of secondary rays M"))
        object.__setattr__(self, "angle", float(_check_angle(self.angle)))

    @property
    def n_rays(self) -> int:
        """N * M."""
        return self.n_primary * self.n_secondary

    @property
    def name(self) -> str:
        """A stable identifier such as ``"cap-32x64-60"``."""
        return f"{self.kind}-{self.n_primary}x{self.n_secondary}-{self.angle:g}"

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
        """(N*M, 3) float64 unit ray directions: row ``i*M + k`` is cap sample k of viewpoint i."""
        local = cap_directions(self.n_secondary, self.angle)  # (M, 3) in (u, v, w) coords
        d = np.einsum("mj,njc->nmc", local, self.frames).reshape(-1, 3)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return _readonly(d)

    @property
    def secondary(self) -> np.ndarray:
        """(N*M, 3) float64 secondary points ``P2 = P1 + r d`` on the small sphere (r = 2 cos omega)."""
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
        """JSON-serialisable description; ``Rig.from_dict`` rebuilds the identical rig."""
        return {"kind": self.kind, "n_primary": self.n_primary, "n_secondary": self.n_secondary, "angle": self.angle}

    @classmethod
    def from_dict(cls, d: dict) -> "Rig":
        """Rebuild a rig from :meth:`to_dict` output."""
        try:
            return cls(
                n_primary=int(d["n_primary"]),
                n_secondary=int(d["n_secondary"]),
                angle=float(d["angle"]),
                kind=str(d.get("kind", "cap")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ParameterError(f"invalid rig description {d!r}: {exc}") from None


def make_rig(primary: int = 32, secondary: int = 64, angle: float | None = 60.0, radius: float | None = None) -> Rig:
    """Build the paper's cap rig.

    Parameters
    ----------
    primary : N viewpoints (paper: 32).
    secondary : M rays per viewpoint (paper: 64).
    angle : cap half-angle omega in degrees, in (0, 90] (paper: 60).
    radius : alternatively the small-sphere radius r / R; ``omega = arccos(r / 2R)``
        (the paper's r = R/4 gives 82.82 degrees). Overrides ``angle`` when given.
    """
    if radius is not None:
        angle = angle_from_radius(float(radius))
    if angle is None:
        raise ParameterError("give the cap angle or the small-sphere radius")
    return Rig(n_primary=primary, n_secondary=secondary, angle=angle)


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
