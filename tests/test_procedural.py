"""The procedural vehicle generator (spotlights.data.synthetic.procedural)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from spotlights.data.real.base import CLASSES as READER_CLASSES
from spotlights.data.synthetic.procedural import (
    BODY_TYPES,
    CLASS_BODIES,
    DIMENSIONS,
    draw_params,
    generate_vehicle,
    mesh_digest,
)
from spotlights.errors import ParameterError
from spotlights.geometry.raycast import RayCaster


@pytest.mark.parametrize("body", BODY_TYPES)
def test_same_seed_same_bytes(body):
    v1, f1, p1 = generate_vehicle(body, 7)
    v2, f2, p2 = generate_vehicle(body, np.random.SeedSequence(7))
    assert v1.tobytes() == v2.tobytes() and f1.tobytes() == f2.tobytes() and p1 == p2
    v3, f3, _ = generate_vehicle(body, 8)
    assert mesh_digest(v1, f1) != mesh_digest(v3, f3)


@pytest.mark.parametrize("body", BODY_TYPES)
def test_dimensions_inside_stated_ranges(body):
    d = DIMENSIONS[body]
    sizes = []
    for seed in range(60):
        v, _, p = generate_vehicle(body, seed)
        size = v.max(axis=0) - v.min(axis=0)
        sizes.append(size)
        for k, x in zip(("length", "width", "height"), size):
            assert d[k][0] - 1e-9 <= x <= d[k][1] + 1e-9, (body, seed, k, x)
        # the box is exactly the drawn one, centred on the origin (the object frame of the project)
        np.testing.assert_allclose(size, [p.length, p.width, p.height], atol=1e-9)
        np.testing.assert_allclose(v.max(axis=0) + v.min(axis=0), 0.0, atol=1e-9)
        if d["wheelbase"][1] > 0:
            assert d["wheelbase"][0] - 1e-9 <= p.wheelbase <= d["wheelbase"][1] + 1e-9
            assert p.front_overhang > p.wheel_radius and p.length - p.front_overhang - p.wheelbase > p.wheel_radius
        # the tyres stand on the ground: the lowest vertices are wheel vertices at z = -H / 2
        assert v[:, 2].min() == pytest.approx(-p.height / 2, abs=1e-9)
    sizes = np.array(sizes)
    # the draws spread over the ranges (not one fixed size)
    for k, name in enumerate(("length", "width", "height")):
        lo, hi = d[name]
        assert sizes[:, k].max() - sizes[:, k].min() > 0.5 * (hi - lo)
    assert max(d["width"][1] for d in DIMENSIONS.values()) <= 2.55
    assert max(d["height"][1] for d in DIMENSIONS.values()) <= 4.1


@pytest.mark.parametrize("body", BODY_TYPES)
def test_closed_outward_disjoint(body):
    for seed in range(3):
        v, f, _ = generate_vehicle(body, seed)
        mesh = trimesh.Trimesh(v, f, process=False)
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume > 0
        # outward: rays from far outside toward the centre first hit a face whose normal faces them
        rng = np.random.default_rng(seed)
        dirs = rng.normal(size=(200, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        origins = -dirs * 30.0 + rng.uniform(-0.3, 0.3, size=(200, 3))
        t, face = RayCaster(v, f).first_hit(origins, dirs)
        hit = face >= 0
        assert hit.sum() > 100  # the semi-tractor and the flatbed leave gaps open
        assert np.all(np.einsum("ij,ij->i", mesh.face_normals[face[hit]], dirs[hit]) < 0)
        # components do not overlap (no interior faces): no vertex of one lies inside another
        parts = mesh.split(only_watertight=False)
        assert len(parts) >= 5  # a body and at least four wheels
        for i, a in enumerate(parts):
            others = [b for j, b in enumerate(parts) if j != i]
            inside = np.zeros(len(a.vertices), dtype=bool)
            for b in others:
                inside |= b.contains(a.vertices)
            assert not inside.any(), (body, seed, i)


def test_box_truck_ray_hits_where_hand_computed():
    """Rays toward a generated box truck (x forward, y left, z up, box centred on the origin) hit
    its faces at the planes its drawn length, width and height put them."""
    for seed in range(4):
        v, f, p = generate_vehicle("box_truck", seed)
        L, W, H = p.length, p.width, p.height
        z_low = -H / 2 + p.clearance + 0.3  # cab front: floor at clearance + 0.1, nose well above
        z_cargo = H / 2 - 0.3  # cargo box: from above the frame up to the roof H
        x_cargo = -L / 2 + 0.5  # 0.5 m ahead of the rear
        origins = np.array(
            [
                [L, 0.0, z_low],  # along -x onto the front of the cab
                [-L, 0.3, z_cargo],  # along +x onto the rear doors of the box
                [x_cargo, 5.0, z_cargo],  # along -y onto the box's left side
                [x_cargo, 0.2, 10.0],  # along -z onto the box's roof
            ]
        )
        dirs = np.array([[-1.0, 0, 0], [1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
        t, face = RayCaster(v, f).first_hit(origins, dirs)
        assert np.all(face >= 0)
        hits = origins + t[:, None] * dirs
        # Embree intersects in float32: 1e-5 m over distances of ~10 m
        np.testing.assert_allclose(hits[:2, 0], [L / 2, -L / 2], atol=1e-5)
        assert hits[2, 1] == pytest.approx(W / 2, abs=1e-5)
        assert hits[3, 2] == pytest.approx(H / 2, abs=1e-5)


def test_classes_and_bodies():
    assert set(CLASS_BODIES) == {"car", "caravan", "truck", "bus", "trailer"}
    assert set(CLASS_BODIES) <= set(READER_CLASSES)  # the names the real readers give boxes
    assert {b for bodies in CLASS_BODIES.values() for b in bodies} == set(BODY_TYPES)
    assert "pickup" in CLASS_BODIES["car"] and "pickup" in CLASS_BODIES["truck"]
    with pytest.raises(ParameterError, match="unknown vehicle body"):
        draw_params("tank", 0)
    # a pickup's cargo bed is open: a ray straight down the bed's middle reaches the bed floor,
    # well below the cab roof and the bed walls
    v, f, p = generate_vehicle("pickup", 3)
    t, face = RayCaster(v, f).first_hit(np.array([[-p.length / 2 + 0.5, 0.0, 10.0]]), np.array([[0, 0, -1.0]]))
    z = 10.0 - t[0]
    assert face[0] >= 0 and z < p.height / 2 - 0.5


def test_long_box_trucks_are_three_axle_rigids():
    """Box trucks reach the EU rigid maximum (12.00 m); from 10 m they stand on a rear tandem: a ray
    along -y at axle height through the second rear axle (1.35 m behind the first, wheelbase behind the
    front axle) hits the outer face of its left tyre, 2 cm inside the body's side."""
    lengths = []
    for seed in range(40):
        v, f, p = generate_vehicle("box_truck", seed)
        lengths.append(p.length)
        if p.length < 10.0:
            continue
        x = p.length / 2 - (p.front_overhang + p.wheelbase + 1.35)
        t, face = RayCaster(v, f).first_hit(
            np.array([[x, 5.0, -p.height / 2 + p.wheel_radius]]), np.array([[0, -1.0, 0]])
        )
        assert face[0] >= 0 and 5.0 - t[0] == pytest.approx(p.width / 2 - 0.02, abs=1e-5), (seed, p)
    assert max(lengths) > 11.5 and sum(x >= 10.0 for x in lengths) >= 5


def test_articulated_truck_is_a_tractor_coupled_to_a_semi_trailer():
    """An articulated truck is longer than any semi-tractor; a ray from behind along +x at y = 0, 10 cm
    above the tractor's frame (whose top is 2 r + 0.28 m above the ground), passes under the whole
    semi-trailer (floor 2 r + 0.48 m) and hits the rear edge of the fifth-wheel plate: 0.45 m behind
    the kingpin, which is 0.3 m ahead of the middle of the rear axle(s) (front overhang + wheelbase,
    + 1.35 / 2 m on a 6x4 tractor). On a cab-over tractor (variant 0) a ray down over the front axle
    hits the cab roof, 3.2 m up to the trailer's height at fraction shape[8]."""
    longest_tractor = DIMENSIONS["semi_tractor"]["length"][1]
    seen = set()
    for seed in range(6):
        v, f, p = generate_vehicle("articulated_truck", seed)
        assert p.length > longest_tractor + 6.0
        L, H, r = p.length, p.height, p.wheel_radius
        kingpin = p.front_overhang + p.wheelbase + (1.35 / 2 if p.variant else 0.0) - 0.3
        origins = np.array([[-L, 0.0, -H / 2 + 2 * r + 0.38], [L / 2 - p.front_overhang, 0.0, 10.0]])
        dirs = np.array([[1.0, 0, 0], [0, 0, -1.0]])
        t, face = RayCaster(v, f).first_hit(origins, dirs)
        assert face[0] >= 0
        assert -L + t[0] == pytest.approx(L / 2 - (kingpin + 0.45), abs=1e-5), (seed, p)
        assert kingpin + 0.45 < L - 8.0  # the hit is far ahead of the trailer's rear
        if p.variant == 0:
            cab = 3.2 + (min(4.0, H) - 3.2) * p.shape[8]
            assert 10.0 - t[1] == pytest.approx(-H / 2 + cab, abs=1e-5), (seed, p)
        seen.add(p.variant)
    assert seen == {0, 1}  # both tractors (EU cab-over 4x2, US conventional 6x4) among the seeds


@pytest.mark.parametrize("body", ["trailer_box", "trailer_flatbed"])
def test_short_trailers_have_a_drawbar_and_no_landing_gear(body):
    """Trailers shorter than 9 m are drawbar trailers: a ray down 15 cm behind the front hits the drawbar's
    top, 0.85 + 0.15 shape[3] m above the ground; rays along -y 0.3 m above the ground through the front
    30% of the length hit nothing (no landing legs; the axles are behind the middle). On trailers of
    9 m and more the same rays hit the landing legs (1.6-2.4 m from the front)."""
    short = long = 0
    for seed in range(30):
        v, f, p = generate_vehicle(body, seed)
        L, H = p.length, p.height
        xs = L / 2 - np.linspace(0.05, 0.3 * L, 120)
        origins = np.column_stack([xs, np.full_like(xs, 5.0), np.full_like(xs, -H / 2 + 0.3)])
        dirs = np.tile([0, -1.0, 0], (len(xs), 1))
        caster = RayCaster(v, f)
        _, face = caster.first_hit(origins, dirs)
        if L < 9.0:
            short += 1
            assert not (face >= 0).any(), (seed, p)
            t, face = caster.first_hit(np.array([[L / 2 - 0.15, 0.0, 10.0]]), np.array([[0, 0, -1.0]]))
            assert face[0] >= 0 and 10.0 - t[0] == pytest.approx(-H / 2 + 0.85 + 0.15 * p.shape[3], abs=1e-5)
        else:
            long += 1
            assert (face >= 0).any(), (seed, p)
    assert short >= 3 and long >= 3
