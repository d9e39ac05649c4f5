"""Normalisation into the unit sphere: boxes, spheres, round trips, oriented boxes."""

import math

import numpy as np
import pytest
import trimesh

from spotlights.errors import ParameterError
from spotlights.geometry.boxes import Box
from spotlights.geometry.frames import (
    Normalization,
    normalization_from_box,
    normalization_from_mesh,
    normalization_from_points,
)


def test_icosphere_normalises_to_centred_sphere_of_radius_inv_sqrt3():
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    m.apply_translation([1, 2, 3])
    n = normalization_from_mesh(m)
    assert np.allclose(n.center, [1, 2, 3], atol=1e-12)
    assert n.radius == pytest.approx(math.sqrt(3) / 2)  # half the diagonal of the unit cube
    r = np.linalg.norm(n.to_unit(m.vertices), axis=1)
    assert np.allclose(r, 1 / math.sqrt(3))


def test_box_points_fill_unit_sphere_and_round_trip():
    rng = np.random.default_rng(0)
    pts = rng.uniform([-4, 1, 0], [2, 3, 1.5], size=(500, 3))
    n = normalization_from_points(pts)
    u = n.to_unit(pts)
    assert np.linalg.norm(u, axis=1).max() <= 1 + 1e-12
    corners = n.to_unit(np.array([pts.min(0), pts.max(0)]))
    assert np.allclose(np.linalg.norm(corners, axis=1), 1.0)  # box corners on the sphere
    assert np.allclose(n.from_unit(u), pts)
    hom = np.c_[pts, np.ones(len(pts))]
    assert np.allclose((hom @ n.matrix.T)[:, :3], u)
    assert np.allclose((np.c_[u, np.ones(len(u))] @ n.inverse_matrix.T)[:, :3], pts)
    assert np.allclose(Normalization.from_dict(n.to_dict()).to_unit(pts), u)


def test_oriented_box_yaw():
    # A 4 x 2 x 1.5 box at (10, 5, 0.75) heading 90 degrees: its forward axis is the source +y.
    n = normalization_from_box([10, 5, 0.75], [4, 2, 1.5], yaw=math.pi / 2)
    R = 0.5 * math.sqrt(16 + 4 + 2.25)
    assert n.radius == pytest.approx(R)
    front = n.to_unit([[10, 7, 0.75]])[0]  # 2 m ahead of the centre along the heading
    assert np.allclose(front, [2 / R, 0, 0])
    left = n.to_unit([[9, 5, 0.75]])[0]  # 1 m to the vehicle's left (source -x)
    assert np.allclose(left, [0, 1 / R, 0])
    corners = Box([10, 5, 0.75], [4, 2, 1.5], yaw=math.pi / 2).corners()
    # hand-computed: corner 7 = (-,-,-) in box axes -> centre - 2*fwd - 1*left - 0.75*up
    assert np.allclose(corners[7], [10 + 1, 5 - 2, 0])
    assert np.allclose(corners[0], [10 - 1, 5 + 2, 1.5])
    assert np.allclose(np.linalg.norm(n.to_unit(corners), axis=1), 1.0)


def test_oriented_box_full_rotation_equals_yaw():
    a = normalization_from_box([1, 2, 3], [3, 2, 1], yaw=0.3)
    c, s = math.cos(0.3), math.sin(0.3)
    b = normalization_from_box([1, 2, 3], [3, 2, 1], rotation=[[c, -s, 0], [s, c, 0], [0, 0, 1]])
    pts = np.random.default_rng(1).normal(size=(20, 3))
    assert np.allclose(a.to_unit(pts), b.to_unit(pts))


@pytest.mark.parametrize(
    "call",
    [
        lambda: normalization_from_points(np.zeros((5, 3))),
        lambda: normalization_from_points(np.zeros((0, 3))),
        lambda: normalization_from_points(np.array([[0, 0, 0], [1, np.nan, 0]])),
        lambda: normalization_from_box([0, 0, 0], [0, 0, 0]),
        lambda: normalization_from_box([0, 0, 0], [1, 1, 1], rotation=np.diag([1, 1, -1])),
    ],
)
def test_degenerate_inputs_rejected(call):
    with pytest.raises(ParameterError):
        call()


def test_clamp_to_unit_sphere_near_the_sphere():
    """Points just inside, on and just outside the unit sphere, and far inside: every point whose float64 norm
    exceeds 1 moves onto (just inside) the sphere along its ray; the others come back bit for bit."""
    from spotlights.geometry.frames import clamp_to_unit_sphere

    rng = np.random.default_rng(3)
    u = rng.normal(size=(2000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    radii = np.concatenate(
        [rng.uniform(0.0, 0.998, 500), 1.0 + rng.uniform(-1e-6, 1e-6, 1000), rng.uniform(1.001, 3, 500)]
    )
    p = (u * radii[:, None]).astype(np.float32)
    r = np.linalg.norm(p.astype(np.float64), axis=1)  # the definition: float64 norms of the float32 points
    out = clamp_to_unit_sphere(p)
    outside = r > 1.0
    assert 0 < outside[500:1500].sum() < 1000  # the band straddles the sphere
    assert np.array_equal(out[~outside], p[~outside])
    assert np.all(np.linalg.norm(out.astype(np.float64), axis=1) <= 1.0)
    moved = out[outside].astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(moved, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(moved / np.linalg.norm(moved, axis=1, keepdims=True), u[outside], atol=1e-5)


def test_box_normalization_is_made_once_and_follows_replace():
    """Box.normalization() is computed once per (immutable) box; a replaced box gets its own."""
    import pickle

    b = Box([1.0, 2.0, 0.5], [4.0, 2.0, 1.5], yaw=0.3)
    n = b.normalization()
    assert b.normalization() is n
    assert n.radius == pytest.approx(0.5 * math.sqrt(16 + 4 + 2.25))
    moved = b.replace(center=[5.0, 2.0, 0.5])
    np.testing.assert_allclose(moved.normalization().center, [5.0, 2.0, 0.5])
    np.testing.assert_allclose(n.center, [1.0, 2.0, 0.5])
    back = pickle.loads(pickle.dumps(b))
    np.testing.assert_allclose(back.normalization().to_unit(np.array([[1.0, 2.0, 0.5]])), 0.0, atol=1e-15)
