"""The point sets of a Spotlights rig: the paper's Fibonacci lattices (viewpoints, cap rays) and Halton.

The cap rig's rays (paper Sections 3.1-3.2) are built here; :mod:`spotlights.geometry.rig` holds
the :class:`~spotlights.geometry.rig.Rig` that caches them, :mod:`spotlights.geometry.box_rays`
the box-targeted rays.

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

import numpy as np

from ..errors import ParameterError

GOLDEN_RATIO = (1.0 + math.sqrt(5.0)) / 2.0
HALTON_BASES = (2, 3, 5)


def fibonacci_lattice_2d(n: int) -> np.ndarray:
    """The paper's 2-D Fibonacci lattice on [0, 1)^2.

    Returns
    -------
    (n, 2) float64 array of ``(x_i, y_i) = (frac(i / Phi), i / n)``.
    """
    check_count(n, "n")
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
    check_count(m, "m")
    omega = math.radians(check_angle(angle_deg))
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
    check_count(n, "n")
    idx = np.arange(start, start + n, dtype=np.int64)
    out = np.zeros((n, len(bases)), dtype=np.float64)
    for j, b in enumerate(bases):
        rest, f = idx.copy(), 1.0
        while np.any(rest > 0):  # one pass per digit, vectorised over the indices
            f /= b
            out[:, j] += f * (rest % b)
            rest //= b
    return out


def check_count(n, what: str) -> int:
    """``n`` as an int if it is an integer >= 1, else :class:`ParameterError` naming ``what``."""
    try:
        ok = float(n).is_integer() and int(n) >= 1
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ParameterError(f"{what} must be an integer >= 1, got {n!r}")
    return int(n)


def check_angle(angle) -> float:
    """A cap half-angle in degrees as a float in (0, 90], else :class:`ParameterError`."""
    try:
        a = float(angle)
    except (TypeError, ValueError):
        raise ParameterError(f"cap angle must be a number of degrees in (0, 90], got {angle!r}") from None
    if not (0.0 < a <= 90.0):
        raise ParameterError(f"cap angle must be in (0, 90] degrees, got {angle!r}")
    return a
