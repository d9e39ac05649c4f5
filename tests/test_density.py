"""Ray-density theory (paper Section 3.3): quadrature against closed forms and the paper's own formulas.

Every reference here is independent of the 1-D quadrature in ``spotlights.analysis.density``:
closed forms derived by hand (r = 0, alpha = 0/pi, alpha = pi/2 via elliptic integrals), the
paper's double integral over the source sphere taken literally (brute-force midpoint rule),
the paper's occlusion formula integrated over the hemisphere, and explicit vector geometry.
"""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.analysis import density as dens
from spotlights.errors import ParameterError

ANGLES = (90.0, 83.0, 60.0, 30.0)


# --- closed forms -------------------------------------------------------------------------------


@pytest.mark.parametrize("angle", ANGLES)
def test_centre_value_is_one_over_8pi_for_every_alpha(angle):
    alpha = np.linspace(0.0, np.pi, 37)
    expected = 1.0 / (8.0 * np.pi * (1.0 - np.cos(np.radians(angle))))
    got = dens.rho(0.0, alpha, angle=angle)
    np.testing.assert_allclose(got, expected, rtol=1e-13)
    if angle == 90.0:
        assert abs(got[0] - 0.0397887) < 1e-7  # the paper's 1/(8 pi) per N*M


@pytest.mark.parametrize("angle", ANGLES)
def test_alpha_zero_and_pi_closed_form(angle):
    r = np.linspace(0.0, 0.98, 50)
    om = np.radians(angle)
    rr = np.maximum(r, 1e-12)
    # derived by hand: Int_{x >= x_c} 2 pi x / sqrt(1 - r^2 + r^2 x^2) dx
    inside = (1.0 - np.sqrt(1.0 - rr**2)) / (4.0 * np.pi * (1.0 - np.cos(om)) * rr**2)
    inside[0] = 1.0 / (8.0 * np.pi * (1.0 - np.cos(om)))
    expected = np.where(r <= np.sin(om), inside, 1.0 / (4.0 * np.pi * rr**2))
    np.testing.assert_allclose(dens.rho(r, 0.0, angle=angle), expected, rtol=1e-11)
    np.testing.assert_allclose(dens.rho(r, np.pi, angle=angle), expected, rtol=1e-11)


def test_alpha_half_pi_elliptic_closed_form():
    from scipy.special import ellipe, ellipk

    r = np.linspace(0.01, 0.99, 50)
    m = r * r
    expected = (ellipk(m) - ellipe(m)) / (2.0 * np.pi**2 * m)
    np.testing.assert_allclose(dens.rho(r, np.pi / 2), expected, rtol=1e-11)


# --- the paper's double integral, taken literally ------------------------------------------------


@pytest.mark.parametrize("r,alpha", [(0.3, 1.2), (0.5, 0.7), (0.8, np.pi / 2), (0.8, 0.0), (0.9, 2.5)])
def test_matches_the_papers_double_integral(r, alpha):
    brute = dens.rho_paper_integral(r, alpha, n_theta=1500, n_phi=1500)
    # the midpoint rule converges slowly across the visibility kink (cos theta = r cos alpha): ~1e-5
    assert dens.rho(r, alpha) == pytest.approx(brute, rel=2e-5)


@pytest.mark.parametrize("angle,r,alpha", [(60.0, 0.9, 2.5), (60.0, 0.5, 0.7), (30.0, 0.7, 1.0), (83.0, 0.95, 1.0)])
def test_caps_match_the_double_integral_with_a_cap_mask(angle, r, alpha):
    brute = dens.rho_paper_integral(r, alpha, angle=angle, n_theta=1500, n_phi=1500)
    assert dens.rho(r, alpha, angle=angle) == pytest.approx(brute, rel=2e-4)


# --- symmetry and the paper's range --------------------------------------------------------------


@pytest.mark.parametrize("angle", ANGLES)
def test_symmetric_under_alpha_to_pi_minus_alpha(angle):
    r = np.linspace(0.0, 0.97, 25)[:, None]
    alpha = np.linspace(0.0, np.pi / 2, 19)[None, :]
    np.testing.assert_allclose(dens.rho(r, alpha, angle=angle), dens.rho(r, np.pi - alpha, angle=angle), rtol=1e-12)


def test_hemisphere_density_grows_with_r_and_peaks_at_alpha_half_pi():
    r = np.linspace(0.0, 0.98, 50)
    alpha = np.linspace(0.0, np.pi, 61)
    g = dens.rho_grid(r, alpha)
    assert np.all(np.diff(g, axis=0) >= -1e-15)
    assert np.all(g[1:, 30] >= g[1:].max(axis=1) - 1e-15)  # alpha = pi/2 column is the maximum


def test_reproduces_the_papers_range_for_r_up_to_0_8():
    r = np.linspace(0.0, 0.8, 81)
    alpha = np.linspace(0.0, np.pi, 181)
    g = dens.rho_grid(r, alpha)
    # paper: "when 0 <= r <= 0.8, rho takes values between 0.039 and 0.057"
    assert 0.0390 <= g.min() < 0.0400
    assert 0.0565 < g.max() <= 0.0570
    assert g.min() == pytest.approx(1.0 / (8.0 * np.pi), rel=1e-12)


def test_quadrature_error_shrinks_with_resolution():
    from scipy.special import ellipe, ellipk

    r = np.linspace(0.05, 0.99, 48)
    m = r * r
    exact = (ellipk(m) - ellipe(m)) / (2.0 * np.pi**2 * m)
    exact0 = (1.0 - np.sqrt(1.0 - m)) / (4.0 * np.pi * m)
    errors = []
    ref30 = dens.rho(r, np.radians(30.0), nodes=256)
    ref89 = dens.rho(r, np.radians(89.0), nodes=256)  # hardest case: kinks at +-sin(alpha) near +-1
    for nodes in (4, 8, 16, 32, 64):
        e1 = np.max(np.abs(dens.rho(r, np.pi / 2, nodes=nodes) / exact - 1.0))
        e2 = np.max(np.abs(dens.rho(r, np.radians(30.0), nodes=nodes) / ref30 - 1.0))
        e3 = np.max(np.abs(dens.rho(r, 0.0, nodes=nodes) / exact0 - 1.0))
        e4 = np.max(np.abs(dens.rho(r, np.radians(89.0), nodes=nodes) / ref89 - 1.0))
        errors.append(max(e1, e2, e3, e4))
    # decreasing until it reaches the round-off floor
    assert all(b < a or b < 1e-12 for a, b in zip(errors, errors[1:])), errors
    assert errors[0] > 1e-4 and errors[-1] < 2e-10, errors
    assert dens.quadrature_error(r, np.linspace(0, np.pi, 19)) < 1e-11


# --- the occlusion formula ------------------------------------------------------------------------


def test_occlusion_formula_matches_explicit_geometry():
    """Build the surfel, the arrival direction and the source point as vectors; compare."""
    rng = np.random.default_rng(3)
    r, alpha = rng.uniform(0, 0.95, 200), rng.uniform(0, np.pi, 200)
    beta, gamma = rng.uniform(0, np.pi / 2, 200), rng.uniform(0, 2 * np.pi, 200)
    # frame: normal = +z; outward radial e = (-sin a, 0, cos a) (the paper's d^2 sign convention),
    # so gamma = 0 (+x) is the tangential direction towards the centre
    p = r[:, None] * np.stack([-np.sin(alpha), np.zeros(200), np.cos(alpha)], axis=1)
    u = np.stack([np.sin(beta) * np.cos(gamma), np.sin(beta) * np.sin(gamma), np.cos(beta)], axis=1)
    pu = np.einsum("ij,ij->i", p, u)
    t = -pu + np.sqrt(pu**2 + 1.0 - r**2)  # source a = p + t u on the unit sphere
    a = p + t[:, None] * u
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-12)
    cos_psi = np.einsum("ij,ij->i", a, u)  # angle between the ray and the source's inward axis
    expected = np.cos(beta) / (8 * np.pi**2 * cos_psi)
    np.testing.assert_allclose(dens.rho_direction(r, alpha, beta, gamma), expected, rtol=1e-12)
    assert np.all(dens.rho_direction(r, alpha, np.pi - beta, gamma) == 0.0)  # behind the surfel


@pytest.mark.parametrize("r,alpha", [(0.0, 0.0), (0.4, 0.5), (0.8, np.pi / 2), (0.9, 2.6)])
def test_occlusion_formula_integrates_to_the_density(r, alpha):
    mu, wmu = np.polynomial.legendre.leggauss(200)
    mu, wmu = 0.5 * (mu + 1.0), 0.5 * wmu  # cos(beta) in [0, 1]
    gamma = np.linspace(0.0, 2 * np.pi, 400, endpoint=False)
    g = dens.rho_direction_grid(r, alpha, np.arccos(mu), gamma)
    total = np.sum(g * wmu[:, None]) * (2 * np.pi / len(gamma))
    assert total == pytest.approx(float(dens.rho(r, alpha)), rel=1e-9)


def test_ring_density_central_ray_and_average():
    r, alpha = 0.5, 0.3
    assert dens.rho_ring(r, alpha, 1.0) == pytest.approx(np.cos(alpha) / (4 * np.pi * r * r), rel=1e-12)
    assert dens.rho_ring(r, alpha, 0.5) == 0.0  # a ray at 60 deg off-axis never comes within 0.866 of the centre
    m = 400_000
    c = 1.0 - (np.arange(m) + 0.5) / m  # 90-degree cap, midpoints in cos
    assert dens.rho_ring(r, alpha, c).mean() == pytest.approx(float(dens.rho(r, alpha)), rel=3e-3)


# --- API behaviour ----------------------------------------------------------------------------------


def test_vectorised_shapes_match_scalar_calls():
    r = np.array([[0.0, 0.2], [0.6, 0.95]])
    alpha = np.array([0.1, 2.0])
    got = dens.rho(r, alpha, angle=60.0)
    assert got.shape == (2, 2) and got.dtype == np.float64
    for i in range(2):
        for j in range(2):
            assert got[i, j] == float(dens.rho(r[i, j], alpha[j], angle=60.0))


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(r=1.0, alpha=0.0),
        dict(r=-0.1, alpha=0.0),
        dict(r=0.5, alpha=0.0, angle=0.0),
        dict(r=0.5, alpha=0.0, angle=95.0),
        dict(r=np.nan, alpha=0.0),
    ],
)
def test_bad_parameters_raise(kwargs):
    with pytest.raises(ParameterError):
        dens.rho(**kwargs)
