"""Ray density of a surfel inside the Spotlights sphere (paper Section 3.3).

Model (the paper's assumptions 1-3): the bounding sphere has radius ``R = 1``;
``N`` ray sources are spread uniformly over it (source density ``N / 4pi`` per unit
area); each source emits ``M`` rays spread uniformly over a cap of half-angle
``omega`` around the direction to the centre (ray density ``M / (2pi (1 - cos omega))``
per steradian; the paper takes ``omega = 90`` degrees, i.e. a solid angle of ``2pi``).
A surfel ``dS`` sits at distance ``r`` from the centre; ``alpha`` is the angle between
its normal ``n`` and the *outward* radial direction ``e`` (``alpha = 0``: the surfel
faces away from the centre, ``alpha = pi``: it faces the centre). The ray density
``rho`` is the expected number of rays hitting the *front* of the surfel per unit
area; every function here returns it **per unit N*M** (multiply by ``N*M`` to get
rays per unit area of the unit frame).

Derivation (see ``docs/analysis.md`` for the long form). A source at ``a`` (unit
vector) sends ``rho_r * dS cos(beta) / d^2`` rays onto ``dS``, where ``d = |a - P|``,
``P = r e`` and ``cos(beta) = n . (a - P) / d`` is the incidence cosine at the
surfel; only ``cos(beta) > 0`` counts. Integrating over the sources,

    rho = rho_s rho_r / (N M) * Int_{S^2} max(0, n.(a - P)) / |a - P|^3 dA(a).       (1)

With the polar axis along ``n`` this is exactly the paper's double integral
(``theta`` is measured from the surfel normal, not from the radial direction).
Changing variables from the source point ``a`` to the arrival direction ``u`` seen
from the surfel (``dA = d^2 dOmega / cos(psi)``, ``cos(psi) = a.u =
sqrt(1 - r^2 + (P.u)^2)`` is the angle between the ray and the source's axis)
turns (1) into an integral over the surfel's front hemisphere,

    rho = 1 / (8 pi^2 (1 - cos omega)) * Int_{n.u > 0, cos psi >= cos omega} (n.u) / cos(psi) dOmega(u),   (2)

whose integrand is the paper's occlusion formula ``rho(r, alpha, beta, gamma)``
(:func:`rho_direction`). Taking the polar axis along ``e`` instead, the azimuthal
integral of ``max(0, n.u)`` has a closed form ``G(x)`` (``x = e.u``) and the cap
condition becomes ``|x| >= x_c = sqrt(max(0, 1 - sin^2(omega) / r^2))``, leaving a
one-dimensional integral

    rho = 1 / (8 pi^2 (1 - cos omega)) * Int_{|x| >= x_c} G(x) / sqrt(1 - r^2 + r^2 x^2) dx,              (3)

which :func:`rho` evaluates with the substitution ``x = (eps / r) sinh(s)``
(``eps = sqrt(1 - r^2)``; it removes the near-singular peak at ``x = 0`` that turns into
a logarithmic divergence as ``r -> 1``), split at the kinks of ``G`` (``x = +-sin(alpha)``)
and at ``+-x_c``, each piece mapped by ``s = a + (b - a)(1 - cos t) / 2`` (which makes the
``(x - x_k)^{3/2}`` kinks analytic) and integrated by Gauss-Legendre in ``t``. With the
default 64 nodes per piece the relative error is below 2e-10 on ``r <= 0.99`` (worst case:
``alpha`` within a degree of ``pi/2`` at ``r = 0.99``, where the kinks at ``+-sin(alpha)`` come
close to the branch points at ``+-1``) and below 1e-13 for ``r <= 0.9`` (measured against
256 nodes; :func:`quadrature_error` estimates it for any grid).

Closed forms used as independent checks:

* ``r = 0``: ``rho = 1 / (8 pi (1 - cos omega))`` (``1 / (8 pi)`` for the paper's hemisphere);
* ``alpha = 0`` or ``pi``: ``rho = (1 - sqrt(1 - r^2)) / (4 pi (1 - cos omega) r^2)`` for
  ``r <= sin omega`` and ``1 / (4 pi r^2)`` beyond;
* ``alpha = pi/2``, ``omega = 90``: ``rho = (K(r^2) - E(r^2)) / (2 pi^2 r^2)`` (complete
  elliptic integrals, parameter ``m = r^2``).

Symmetry: ``rho(r, alpha) = rho(r, pi - alpha)`` exactly (the integrand of (2) depends on
``(P.u)^2`` only), so a thin two-sided wall receives the same density on both faces.
"""

from __future__ import annotations

import functools

import numpy as np

from ..errors import ParameterError

__all__ = [
    "rho",
    "rho_grid",
    "rho_closed_form_r0",
    "rho_closed_form_alpha0",
    "rho_closed_form_alpha_half_pi",
    "rho_paper_integral",
    "rho_direction",
    "rho_direction_grid",
    "rho_at_points",
    "rho_ring",
    "quadrature_error",
    "cap_solid_angle",
]

#: default Gauss-Legendre nodes per smooth piece of the 1-D integral (3)
DEFAULT_NODES = 64


def cap_solid_angle(angle_deg: float) -> float:
    """Solid angle (steradian) of a cap of half-angle ``angle_deg`` degrees: ``2pi (1 - cos omega)``."""
    return 2.0 * np.pi * (1.0 - np.cos(np.radians(angle_deg)))


def _check_angle(angle_deg: float) -> float:
    angle_deg = float(angle_deg)
    if not (0.0 < angle_deg <= 90.0):
        raise ParameterError(f"cap angle must be in (0, 90] degrees (the sources face the centre), got {angle_deg:g}")
    return angle_deg


def _check_r(r: np.ndarray) -> None:
    if np.any(~np.isfinite(r)) or np.any(r < 0.0) or np.any(r >= 1.0):
        raise ParameterError("r must lie in [0, 1): the surfel must be strictly inside the unit sphere")


def _g_azimuthal(x: np.ndarray, sa, ca) -> np.ndarray:
    """Azimuthal integral ``G(x) = Int_0^{2pi} max(0, n.u) dphi`` with the polar axis on ``e``.

    ``u = (sqrt(1-x^2) cos phi, sqrt(1-x^2) sin phi, x)`` in a frame whose z axis is the
    outward radial direction ``e`` and where ``n = (sin alpha, 0, cos alpha)``; then
    ``n.u = A cos(phi) + B`` with ``A = sin(alpha) sqrt(1-x^2) >= 0``, ``B = cos(alpha) x``, and
    ``G = 2pi max(0, B)`` if ``|B| >= A`` else ``2 (sqrt(A^2 - B^2) + B arccos(-B / A))``
    (``A^2 - B^2 = sin^2(alpha) - x^2`` exactly). ``x`` in [-1, 1]; ``sa = sin(alpha) >= 0``,
    ``ca = cos(alpha)`` broadcast against it. float64, dimensionless.
    """
    x2 = x * x
    a_ = sa * np.sqrt(np.maximum(1.0 - x2, 0.0))
    b_ = ca * x
    mid = np.abs(b_) < a_
    ratio = np.divide(-b_, a_, out=np.zeros(np.broadcast(x, sa, ca).shape), where=mid)
    inner = 2.0 * (np.sqrt(np.maximum(sa * sa - x2, 0.0)) + b_ * np.arccos(np.minimum(np.maximum(ratio, -1.0), 1.0)))
    return np.where(mid, inner, 2.0 * np.pi * np.maximum(b_, 0.0))


@functools.lru_cache(maxsize=32)
def gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Cached Gauss-Legendre nodes and weights on [-1, 1]: two (n,) float64 read-only arrays (numpy's ``leggauss``)."""
    z, w = np.polynomial.legendre.leggauss(int(n))
    z.setflags(write=False)
    w.setflags(write=False)
    return z, w


@functools.lru_cache(maxsize=32)
def _gauss_cos_nodes(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes ``u`` in [0, 1] and weights for ``Int_0^1 f(u) du`` after ``u = (1 - cos t) / 2``.

    Gauss-Legendre in ``t`` on [0, pi]; the weights include ``du/dt = sin(t) / 2``.
    """
    z, w = gauss_legendre(n)
    t = 0.5 * np.pi * (z + 1.0)
    u = 0.5 * (1.0 - np.cos(t))
    wu = w * 0.5 * np.pi * 0.5 * np.sin(t)
    u.setflags(write=False)
    wu.setflags(write=False)
    return u, wu


def rho(r, alpha, angle: float = 90.0, nodes: int = DEFAULT_NODES) -> np.ndarray:
    """Ray density of a front-facing surfel, per unit ``N*M``, by 1-D quadrature of eq. (3).

    Args:
        r: distance of the surfel from the sphere centre, array-like in [0, 1)
            (unit frame, R = 1). Broadcasts against ``alpha``.
        alpha: angle in radians between the surfel normal and the outward radial
            direction, in [0, pi].
        angle: cap half-angle ``omega`` of every ray bundle in degrees, (0, 90]; 90 is the
            paper's hemisphere (solid angle 2pi).
        nodes: Gauss-Legendre nodes per smooth piece (5 pieces).

    Returns:
        float64 array of the broadcast shape: expected rays per unit surfel area divided by
        ``N*M`` (``1/(8 pi) = 0.0398`` at ``r = 0`` for the hemisphere). Relative error
        below 2e-10 for ``r <= 0.99`` (1e-13 for ``r <= 0.9``) at the default ``nodes``.
    """
    omega = np.radians(_check_angle(angle))
    r, alpha = np.broadcast_arrays(np.asarray(r, dtype=np.float64), np.asarray(alpha, dtype=np.float64))
    _check_r(r)
    shape = r.shape
    r = r.reshape(-1)
    alpha = alpha.reshape(-1)
    out = np.empty(r.shape, dtype=np.float64)
    u, wu = _gauss_cos_nodes(nodes)
    norm = 1.0 / (8.0 * np.pi**2 * (1.0 - np.cos(omega)))
    sin_om = np.sin(omega)
    chunk = max(1, 250_000 // (5 * len(u)))
    for lo in range(0, r.size, chunk):
        rr = np.maximum(r[lo : lo + chunk], 1e-150)[:, None]
        al = alpha[lo : lo + chunk][:, None]
        eps = np.sqrt(1.0 - rr * rr)
        big_s = np.arcsinh(rr / eps)
        xc = np.sqrt(np.clip(1.0 - (sin_om / rr) ** 2, 0.0, None))
        s_c = np.arcsinh(rr * xc / eps)
        s_a = np.arcsinh(rr * np.sin(al) / eps)
        brk = np.sort(np.concatenate([-big_s, -s_a, -s_c, s_c, s_a, big_s], axis=1), axis=1)  # (B, 6)
        a_ = brk[:, :-1, None]  # (B, 5, 1)
        b_ = brk[:, 1:, None]
        s = a_ + (b_ - a_) * u  # (B, 5, n)
        x = (eps / rr)[:, :, None] * np.sinh(s)
        np.minimum(np.maximum(x, -1.0, out=x), 1.0, out=x)
        f = _g_azimuthal(x, np.sin(al)[:, :, None], np.cos(al)[:, :, None])
        f = np.where(np.abs(x) >= xc[:, :, None], f, 0.0)
        integral = np.sum(f * wu * (b_ - a_), axis=(1, 2))
        out[lo : lo + chunk] = norm * integral / rr[:, 0]
    return out.reshape(shape)


def rho_grid(r_values, alpha_values, angle: float = 90.0, nodes: int = DEFAULT_NODES) -> np.ndarray:
    """:func:`rho` on the tensor grid ``r_values x alpha_values``.

    Args:
        r_values: (R,) radii in [0, 1). alpha_values: (A,) orientations in radians.
    Returns:
        (R, A) float64, per unit ``N*M``.
    """
    r_values = np.asarray(r_values, dtype=np.float64)
    alpha_values = np.asarray(alpha_values, dtype=np.float64)
    return rho(r_values[:, None], alpha_values[None, :], angle=angle, nodes=nodes)


def quadrature_error(r_values, alpha_values, angle: float = 90.0, nodes: int = DEFAULT_NODES) -> float:
    """Estimated max absolute quadrature error of :func:`rho` on a grid, per unit ``N*M``.

    Compares ``nodes`` with ``2*nodes`` Gauss points per piece (the latter is taken as
    the truth; the estimate is conservative because convergence is exponential).
    """
    a = rho_grid(r_values, alpha_values, angle=angle, nodes=nodes)
    b = rho_grid(r_values, alpha_values, angle=angle, nodes=2 * nodes)
    return float(np.max(np.abs(a - b)))


def rho_closed_form_r0(angle: float = 90.0) -> float:
    """Closed form at the centre, per unit ``N*M``: ``1 / (8 pi (1 - cos omega))``; 1/(8pi) at 90 deg."""
    omega = np.radians(_check_angle(angle))
    return float(1.0 / (8.0 * np.pi * (1.0 - np.cos(omega))))


def rho_closed_form_alpha0(r, angle: float = 90.0) -> np.ndarray:
    """Closed form for ``alpha = 0`` (and, by symmetry, ``alpha = pi``), per unit ``N*M``.

    ``(1 - sqrt(1 - r^2)) / (4 pi (1 - cos omega) r^2)`` for ``r <= sin omega``, ``1 / (4 pi r^2)``
    beyond. ``r``: array-like in [0, 1); returns float64 of its shape.
    """
    omega = np.radians(_check_angle(angle))
    r = np.asarray(r, dtype=np.float64)
    _check_r(r)
    rr = np.maximum(r, 1e-8)
    inside = (1.0 - np.sqrt(1.0 - rr * rr)) / (4.0 * np.pi * (1.0 - np.cos(omega)) * rr * rr)
    small = 1.0 / (8.0 * np.pi * (1.0 - np.cos(omega)))  # limit r -> 0
    inside = np.where(r < 1e-8, small, inside)
    return np.where(r <= np.sin(omega), inside, 1.0 / (4.0 * np.pi * rr * rr))


def rho_closed_form_alpha_half_pi(r) -> np.ndarray:
    """Closed form for ``alpha = pi/2`` with the paper's hemisphere (omega = 90 deg), per unit ``N*M``.

    ``(K(m) - E(m)) / (2 pi^2 m)``, ``m = r^2``, complete elliptic integrals of the first and
    second kind (``scipy.special.ellipk/ellipe``, parameter convention). ``r`` in [0, 1).
    """
    from scipy.special import ellipe, ellipk

    r = np.asarray(r, dtype=np.float64)
    _check_r(r)
    m = np.maximum(r * r, 1e-12)
    val = (ellipk(m) - ellipe(m)) / (2.0 * np.pi**2 * m)
    return np.where(r * r < 1e-12, 1.0 / (8.0 * np.pi), val)


def rho_paper_integral(r: float, alpha: float, angle: float = 90.0, n_theta: int = 1200, n_phi: int = 1200) -> float:
    """The paper's double integral taken literally: a brute-force reference for tests.

    ``NM/(8pi^2) Int dtheta Int dphi sin(theta) (cos theta - r cos alpha) / d^3`` with
    ``d^2 = r^2 - 2r(cos alpha cos theta - sin alpha sin theta cos phi) + 1``, over the source
    sphere (polar axis = surfel normal), keeping only sources that see the front of the surfel
    (``cos theta > r cos alpha``) and, for ``angle < 90``, whose cap contains the surfel.
    Tensor midpoint rule, ``n_theta x n_phi`` points: error ~1e-6 relative (the integrand has a
    kink on the visibility boundary). Scalars in, float out, per unit ``N*M``.
    """
    omega = np.radians(_check_angle(angle))
    _check_r(np.asarray(r, dtype=np.float64))
    th = (np.arange(n_theta) + 0.5) * (np.pi / n_theta)
    ph = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    ct, st = np.cos(th)[:, None], np.sin(th)[:, None]
    ca, sa = np.cos(alpha), np.sin(alpha)
    a_dot_e = ca * ct - sa * st * np.cos(ph)[None, :]  # a . e with e = (-sin a, 0, cos a)
    d2 = r * r - 2.0 * r * a_dot_e + 1.0
    num = ct - r * ca  # n . (a - P)
    # source at a emits towards -a; it reaches P iff the angle between (P - a) and -a <= omega
    cos_psi = (1.0 - r * a_dot_e) / np.sqrt(d2)
    keep = (num > 0.0) & (cos_psi >= np.cos(omega) - 1e-15)
    f = np.where(keep, st * num / d2**1.5, 0.0)
    ray_density = 1.0 / (2.0 * np.pi * (1.0 - np.cos(omega)))  # per steradian, per unit M
    return float(f.sum() * (np.pi / n_theta) * (2.0 * np.pi / n_phi) * ray_density / (4.0 * np.pi))


def rho_direction(r, alpha, beta, gamma, angle: float = 90.0) -> np.ndarray:
    """The paper's occlusion formula: density received per steradian of arrival direction.

    ``rho(r, alpha, beta, gamma) = cos(beta) / (8 pi^2 (1 - cos omega) sqrt(xi r^2 + 1))``,
    ``xi = (sin alpha sin beta cos gamma - cos alpha cos beta)^2 - 1`` (the paper's formula with
    ``omega = 90``). ``(beta, gamma)`` (radians) is the arrival direction seen from the surfel:
    ``beta`` = polar angle from the surfel normal (= incidence angle of those rays),
    ``gamma`` = azimuth measured from the tangential direction pointing *towards* the sphere
    centre. ``sqrt(xi r^2 + 1)`` is the cosine between the ray and its source's axis; the value
    is the number of rays per unit ``N*M``, per unit surfel area and per steradian that are lost
    if that direction is blocked. Returns 0 behind the surfel (``cos beta <= 0``) and, for
    ``angle < 90``, for directions whose source's cap does not contain the surfel.
    Integrating it over the hemisphere gives :func:`rho`. All arguments broadcast; float64.
    """
    omega = np.radians(_check_angle(angle))
    r = np.asarray(r, dtype=np.float64)
    _check_r(r)
    alpha, beta, gamma = (np.asarray(v, dtype=np.float64) for v in (alpha, beta, gamma))
    xi = (np.sin(alpha) * np.sin(beta) * np.cos(gamma) - np.cos(alpha) * np.cos(beta)) ** 2 - 1.0
    cos_psi = np.sqrt(np.clip(xi * r * r + 1.0, 0.0, None))
    val = np.cos(beta) / (8.0 * np.pi**2 * (1.0 - np.cos(omega)) * cos_psi)
    ok = (np.cos(beta) > 0.0) & (cos_psi >= np.cos(omega) - 1e-15)
    return np.where(ok, val, 0.0)


def rho_direction_grid(r: float, alpha: float, beta_values, gamma_values, angle: float = 90.0) -> np.ndarray:
    """:func:`rho_direction` for one surfel on the grid ``beta_values x gamma_values``.

    Returns (B, G) float64, per unit ``N*M`` per steradian.
    """
    beta_values = np.asarray(beta_values, dtype=np.float64)
    gamma_values = np.asarray(gamma_values, dtype=np.float64)
    return rho_direction(r, alpha, beta_values[:, None], gamma_values[None, :], angle=angle)


def rho_at_points(points, normals, angle: float = 90.0, nodes: int = DEFAULT_NODES) -> np.ndarray:
    """:func:`rho` for surfels given by position and unit normal in the unit frame.

    Args:
        points: (..., 3) float64 positions, ``|p| < 1``. normals: (..., 3) unit normals (the
            front side is the side the normal points to).
    Returns:
        (...,) float64 per unit ``N*M``. At ``p = 0`` alpha is irrelevant (set to 0).
    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    r = np.linalg.norm(points, axis=-1)
    cos_a = np.einsum("...k,...k->...", points, normals) / np.maximum(r, 1e-300)
    alpha = np.arccos(np.clip(cos_a, -1.0, 1.0))
    return rho(r, alpha, angle=angle, nodes=nodes)


def rho_ring(r, alpha, c) -> np.ndarray:
    """Density from one ray per source at a fixed polar angle ``arccos(c)`` off the source axis.

    The building block of a discrete rig: if every source emits one ray at angle
    ``psi = arccos(c)`` from its axis (towards the centre) with a uniformly random azimuth,
    the front of a surfel at ``(r, alpha)`` receives ``N * rho_ring`` rays per unit area, with

        rho_ring = (G(x) + G(-x)) / (8 pi^2 r^2 x),   x = sqrt(c^2 - 1 + r^2) / r,

    (``G`` as in eq. (3); zero where the ring cannot reach radius ``r``, i.e. ``r < sin psi``; it
    diverges like ``1 / sqrt(r - sin psi)`` on the caustic sphere ``r = sin psi``). Averaging over
    ``c`` uniform in ``[cos omega, 1]`` gives :func:`rho`; a rig whose cap samples sit at
    ``c_k`` has the rotation-averaged density ``(1/M) sum_k rho_ring(r, alpha, c_k)``. At ``c = 1``
    (the central ray of every bundle, which passes through the centre) it is
    ``|cos alpha| / (4 pi r^2)``.

    Args: r in (0, 1), alpha radians, c in [0, 1]; broadcast; returns float64, per unit ``N``.
    """
    r, alpha, c = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (r, alpha, c)))
    _check_r(r)
    rr = np.maximum(r, 1e-300)
    q = c * c - 1.0 + r * r
    ok = (q > 0.0) & (r > 0.0)
    x = np.where(ok, np.sqrt(np.clip(q, 0.0, None)) / rr, 1.0)
    x = np.clip(x, 1e-300, 1.0)
    sa, ca = np.sin(alpha), np.cos(alpha)
    val = (_g_azimuthal(x, sa, ca) + _g_azimuthal(-x, sa, ca)) / (8.0 * np.pi**2 * rr * rr * x)
    return np.where(ok, val, 0.0)
