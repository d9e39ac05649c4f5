"""The rig against the paper's formulas (Section 3.1) and cap geometry."""

import math

import numpy as np
import pytest

from spotlights.errors import ParameterError
from spotlights.geometry.rig import Rig, angle_from_radius, cap_directions, fibonacci_sphere, make_rig

PHI = (1 + 5**0.5) / 2


def test_lattice_matches_paper_formula_pointwise():
    n = 37
    pts = fibonacci_sphere(n)
    for i in range(n):  # the paper's formula, written independently, point by point
        x, y = (i / PHI) % 1.0, i / n
        phi, theta = 2 * math.pi * x, math.acos(1 - 2 * y)
        expect = (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))
        assert np.allclose(pts[i], expect, atol=1e-12)
    assert np.allclose(pts[0], [0, 0, 1])
    assert np.allclose(np.linalg.norm(pts, axis=1), 1.0)


def test_lattice_is_nearly_uniform():
    # Equal-area: the share of points in any z-band equals its area share (1/N resolution).
    pts = fibonacci_sphere(4000)
    for z0, z1 in [(-1, -0.5), (-0.2, 0.3), (0.5, 1.0)]:
        share = np.mean((pts[:, 2] > z0) & (pts[:, 2] <= z1))
        assert abs(share - (z1 - z0) / 2) < 2e-3


@pytest.mark.parametrize("angle", [10, 30, 60, 83, 90])
def test_cap_within_angle_and_equal_area(angle):
    m = 4096
    d = cap_directions(m, angle)
    polar = np.degrees(np.arccos(np.clip(d[:, 2], -1, 1)))
    assert polar.max() <= angle + 1e-9
    assert np.allclose(d[0], [0, 0, 1])
    w = math.radians(angle)
    share = np.mean(polar <= angle / 2)
    expect = (1 - math.cos(w / 2)) / (1 - math.cos(w))  # area ratio of the half-angle cap
    assert abs(share - expect) < 2.0 / m
    # azimuthal balance: the mean direction points along the axis
    assert np.linalg.norm(d[:, :2].mean(axis=0)) < 0.01


def test_rig_rays_point_inward_within_cap_and_order():
    rig = make_rig(16, 50, angle=45)
    o, d = rig.origins, rig.directions
    assert o.shape == d.shape == (800, 3)
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    cosang = np.einsum("ij,ij->i", -o, d)  # angle to the direction toward the centre
    assert cosang.min() >= math.cos(math.radians(45)) - 1e-12
    # ray i*M + k starts at viewpoint i, and k = 0 points at the centre
    for i in (0, 7, 15):
        assert np.allclose(o[i * 50 : (i + 1) * 50], rig.primary[i])
        assert np.allclose(d[i * 50], -rig.primary[i])
    # secondary points lie on the small sphere of radius 2 cos(omega) around the viewpoint,
    # and on the unit sphere (the intersection circle) at the rim of the cap
    r = 2 * math.cos(math.radians(45))
    assert np.allclose(np.linalg.norm(rig.secondary - o, axis=1), r)
    last = make_rig(1, 1, angle=45)
    assert np.isclose(np.linalg.norm(last.secondary[0]), abs(1 - r))  # central ray: |1 - r| from the centre


def test_rim_secondary_points_lie_on_unit_sphere():
    # The paper: the cap is where the small sphere meets the unit sphere (omega = arccos(r / 2R)).
    w = math.radians(60)
    r = 2 * math.cos(w)
    p = np.array([0, 0, 1.0])
    rim_dir = np.array([math.sin(w), 0, -math.cos(w)])
    assert np.isclose(np.linalg.norm(p + r * rim_dir), 1.0)


def test_radius_parameter_gives_paper_angle():
    assert abs(angle_from_radius(0.25) - 82.82) < 0.01  # the paper's "83 degrees" is r = R/4
    assert make_rig(radius=0.25).angle == pytest.approx(math.degrees(math.acos(0.125)))


def test_rig_deterministic_and_serialisable():
    a, b = make_rig(32, 64, 60), Rig.from_dict(make_rig(32, 64, 60).to_dict())
    assert a == b and a.name == "cap-32x64-60"
    assert np.array_equal(a.directions, b.directions)
    assert not a.directions.flags.writeable


@pytest.mark.parametrize(
    "kw",
    [
        dict(primary=0),
        dict(secondary=0),
        dict(angle=0),
        dict(angle=90.5),
        dict(angle=-10),
        dict(primary=2.5),
        dict(angle=float("nan")),
    ],
)
def test_bad_parameters_rejected(kw):
    with pytest.raises(ParameterError):
        make_rig(**kw)
