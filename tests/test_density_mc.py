"""Monte-Carlo check of the ray density with real rigs and real ray casting (Embree).

The quadrature is the prediction; hit counts of real Fibonacci rigs on small discs are
the measurement. Also checks that the exact ray culling changes no count, the centre-disc
formula against an independent line simulation, and the CLI end to end.
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from spotlights.analysis import density as dens
from spotlights.analysis.montecarlo import (
    RigRays,
    centre_disc_expected_density,
    count_disc_hits,
    disc_mesh,
    mc_density,
)
from spotlights.geometry.rig import make_rig

from helpers import assert_user_error, run_cli


@pytest.mark.parametrize("angle", [90.0, 60.0, 30.0])
def test_culling_changes_no_count(angle):
    rig = make_rig(96, 128, angle=angle)
    rays = RigRays(rig)
    rng = np.random.default_rng(7)
    for _ in range(12):
        r, a = rng.uniform(0.0, 0.8), rng.uniform(0.0, np.pi)
        v, f, n = disc_mesh(r, a, 0.15)
        q = np.linalg.qr(rng.standard_normal((3, 3)))[0]
        culled = count_disc_hits(rig, v @ q.T, f, q @ n, rays=rays)
        full = count_disc_hits(rig, v @ q.T, f, q @ n, cull=False)
        assert culled == full


def test_disc_mesh_geometry():
    v, f, n = disc_mesh(0.5, 0.7, 0.1, segments=64)
    assert v.shape == (65, 3) and f.shape == (64, 3)
    np.testing.assert_allclose(v[0], [0, 0, 0.5])
    np.testing.assert_allclose(np.degrees(np.arccos(n @ v[0] / 0.5)), np.degrees(0.7))
    np.testing.assert_allclose(np.linalg.norm(v[1:] - v[0], axis=1), 0.1)
    np.testing.assert_allclose((v[1:] - v[0]) @ n, 0.0, atol=1e-15)


def test_centre_disc_crossing_probability_against_random_lines():
    """P(isotropic line at distance b crosses a centred disc of radius a) = 1 - (2/pi) asin(b/a)."""
    rng = np.random.default_rng(11)
    a, b, k = 0.1, 0.06, 400_000
    d = rng.standard_normal((k, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = np.cross(d, rng.standard_normal((k, 3)))
    t /= np.linalg.norm(t, axis=1, keepdims=True)  # uniform direction perpendicular to d
    p = b * t
    s = -p[:, 2] / d[:, 2]  # disc in the plane z = 0
    x = p + s[:, None] * d
    frac = np.mean(np.linalg.norm(x, axis=1) <= a)
    expected = 1.0 - 2.0 / np.pi * np.arcsin(b / a)
    assert abs(frac - expected) < 4 * np.sqrt(expected * (1 - expected) / k)


def test_centre_disc_formula_tends_to_the_continuum_for_large_m():
    """For M -> infinity the rig value is the continuum averaged over the disc; on a disc through the
    centre every point has alpha = pi/2, where rho has the elliptic closed form."""
    from scipy.integrate import quad
    from scipy.special import ellipe, ellipk

    a = 0.3

    def rho_half_pi(s):
        m = max(s * s, 1e-12)
        return (ellipk(m) - ellipe(m)) / (2 * np.pi**2 * m)

    cont = 2.0 / a**2 * quad(lambda s: s * rho_half_pi(s), 0.0, a, epsabs=1e-14)[0]
    assert centre_disc_expected_density(a, 400_000) == pytest.approx(cont, rel=1e-3)
    assert centre_disc_expected_density(a, 1024) > 1.01 * cont  # the finite-M spike, +2 % on this large disc
    assert centre_disc_expected_density(0.08, 1024) > 1.3 * dens.rho_closed_form_r0()  # +37 % on a small one


def test_monte_carlo_agrees_with_quadrature():
    # 64 x 1024 rays: M large enough that a disc of radius 0.09 spans >= 3 cap steps (see MCResult.shells)
    rig = make_rig(64, 1024, angle=90.0)
    placements = [(0.0, 0.0), (0.3, 0.0), (0.6, np.pi / 4), (0.85, np.pi / 2)]
    res = mc_density(rig, placements, disc_radius=0.09, n_rotations=12, seed=5)
    assert len(res) == 8
    z = np.array([x.z for x in res])
    assert np.max(np.abs(z)) < 4.0, z
    assert np.sqrt(np.mean(z**2)) < 2.0, z
    for x in res:
        assert x.hits > 500
        assert x.shells >= 3.0
        # relative 1-sigma error of this small configuration: a few percent
        assert x.se_mc / x.rho_expected < 0.06
        if x.r > 0:
            assert abs(x.rho_mc / x.rho_expected - 1.0) < 4 * x.se_mc / x.rho_expected + 1e-3
            assert x.rho_quad == pytest.approx(float(dens.rho(x.r, x.alpha)), rel=0.05)
    # at the centre the real rig is far denser than the continuum: every bundle's central ray crosses it
    centre = [x for x in res if x.r == 0.0]
    assert all(x.rho_mc > 1.2 * x.rho_quad for x in centre)


def test_monte_carlo_cap_agrees_with_quadrature():
    rig = make_rig(64, 1024, angle=60.0)
    res = mc_density(rig, [(0.4, 2.0), (0.9, 0.0)], disc_radius=0.09, n_rotations=12, seed=9)
    z = np.array([x.z for x in res])
    assert np.max(np.abs(z)) < 4.0, z


def test_mc_is_reproducible():
    rig = make_rig(64, 64, angle=90.0)
    a = mc_density(rig, [(0.5, 1.0)], disc_radius=0.09, n_rotations=3, seed=1)
    b = mc_density(rig, [(0.5, 1.0)], disc_radius=0.09, n_rotations=3, seed=1)
    assert [x.to_dict() for x in a] == [x.to_dict() for x in b]


@pytest.mark.slow
def test_cli_density_end_to_end(tmp_path):
    out = tmp_path / "density"
    proc = run_cli(
        "analyze",
        "density",
        "--out",
        out,
        "--angle",
        "90",
        "60",
        "--mc-rays",
        "128",
        "128",
        "--rotations",
        "3",
        "--r-step",
        "0.05",
        "--alpha-step",
        "5",
    )  # (no -q: it silences the summary lines too)
    assert proc.returncode == 0, proc.stderr
    assert "min 0.03979" in proc.stdout and "max 0.05691" in proc.stdout
    for name in (
        "density.csv",
        "density_heatmap.png",
        "density_directional.png",
        "density_mc.csv",
        "density_montecarlo.png",
        "density_caps.png",
        "summary.json",
    ):
        assert (out / name).stat().st_size > 0, name
    with open(out / "density.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["r", "alpha", "rho_per_nm", "angle"]
    assert {row["angle"] for row in rows} == {"90", "60"}
    r0 = [float(row["rho_per_nm"]) for row in rows if float(row["r"]) == 0.0 and row["angle"] == "90"]
    np.testing.assert_allclose(r0, 1.0 / (8.0 * np.pi), rtol=1e-12)
    summary = json.loads((out / "summary.json").read_text())
    rng = summary["angles"]["90"]["range_r_le_0.8"]
    assert rng["min"] == pytest.approx(0.0397887, abs=1e-6) and rng["max"] == pytest.approx(0.0569103, abs=1e-6)
    assert not list(out.glob(".*part*"))  # no temporary files left


def test_cli_density_bad_input(tmp_path):
    assert_user_error(run_cli("analyze", "density", "--out", tmp_path / "x", "--angle", "120", "--no-mc"), "cap angle")
    f = tmp_path / "file"
    f.write_text("x")
    assert_user_error(run_cli("analyze", "density", "--out", f, "--no-mc"), str(f))
