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
    box_range,
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
            lo, hi = box_range(body, k)  # the width of a passenger body with door mirrors: + 0.2 m
            assert lo - 1e-9 <= x <= hi + 1e-9, (body, seed, k, x)
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
        lo, hi = box_range(body, name)
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


def _crossings(v: np.ndarray, f: np.ndarray, origins: np.ndarray, dirs: np.ndarray) -> list[np.ndarray]:
    """Brute-force Moller-Trumbore: for every ray, the signs of dot(face normal, direction) of all
    the faces it crosses (t > 0), in order along the ray (-1: entering, +1: leaving)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    e1, e2 = b - a, c - a
    normal = np.cross(e1, e2)
    out = []
    for o, d in zip(origins, dirs):
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o - a
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        w = (q @ d) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0)
        order = np.argsort(t[hit])
        out.append(np.sign(normal[hit] @ d)[order])
    return out


@pytest.mark.parametrize("body", BODY_TYPES)
def test_every_ray_that_enters_leaves(body):
    """Lines in random directions through random points of the box (brute force, every face):
    the crossings alternate enter, leave, enter, leave ... and end leaving (closed, outward, no
    overlapping components)."""
    rng = np.random.default_rng(11)
    for seed in (0, 1):
        v, f, p = generate_vehicle(body, seed)
        half = np.array([p.length, p.width, p.height]) / 2
        targets = rng.uniform(-half, half, size=(40, 3))
        dirs = rng.normal(size=(40, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        origins = targets - 40.0 * dirs
        n_hit = 0
        for signs in _crossings(v, f, origins, dirs):
            assert len(signs) % 2 == 0, (body, seed, signs)
            assert np.all(signs[0::2] < 0) and np.all(signs[1::2] > 0), (body, seed, signs)
            n_hit += len(signs) > 0
        assert n_hit >= 10


def _slab_hits(caster: RayCaster, axis: int, level: float, half: np.ndarray, n: int = 60) -> int:
    """How many of n x 3 lines inside the plane {x[axis] = level} hit the mesh: lines along the
    next axis at a grid of positions along the other, spanning the box (+ 1 m)."""
    a1, a2 = (axis + 1) % 3, (axis + 2) % 3
    hits = 0
    for sweep, across in ((a1, a2), (a2, a1)):
        grid = np.linspace(-half[across], half[across], n)
        o = np.zeros((n, 3))
        o[:, axis] = level
        o[:, across] = grid
        o[:, sweep] = -half[sweep] - 1.0
        d = np.zeros((n, 3))
        d[:, sweep] = 1.0
        _, face = caster.first_hit(o, d)
        hits += int((face >= 0).sum())
    return hits


@pytest.mark.parametrize("body", BODY_TYPES)
def test_the_box_faces_touch_the_mesh_and_nothing_lies_beyond(body):
    """The stated box (the drawn length, width, height, centred): lines in the planes 1 mm outside
    each of its six faces hit nothing; lines in the planes 2.5 cm inside hit the mesh."""
    for seed in (0, 1, 2):
        v, f, p = generate_vehicle(body, seed)
        half = np.array([p.length, p.width, p.height]) / 2
        caster = RayCaster(v, f)
        for axis in range(3):
            for sign in (1.0, -1.0):
                assert _slab_hits(caster, axis, sign * (half[axis] + 1e-3), half) == 0, (body, seed, axis, sign)
                assert _slab_hits(caster, axis, sign * (half[axis] - 0.025), half) > 0, (body, seed, axis, sign)


def test_long_vehicles_reach_twenty_metres():
    """Articulated trucks span 13.5-20.0 m (a US conventional tractor with a 53 ft semi-trailer at the
    top), their semi-trailer the rest; articulated buses 17.5-18.75 m (EU 96/53/EC). A ray along -x at
    cab height from ahead of a 16-20 m truck first meets its cab's front at x = +L/2, one from behind
    at the trailer's mid height its rear at -L/2."""
    lengths = []
    for seed in range(40):
        v, f, p = generate_vehicle("articulated_truck", seed)
        lengths.append(p.length)
        assert 13.5 <= p.length <= 20.0
        if p.length < 16.0:
            continue
        size = v.max(0) - v.min(0)
        assert size[0] == pytest.approx(p.length, abs=1e-9)
        z = -p.height / 2 + p.clearance + 0.4
        # the semi-trailer's floor (a tank's bottom) rests at 2 r + 0.48 m; its top (a tank's) is at
        # most 0.1 m below the height: the middle between them is the rear's most rearward point
        z_rear = -p.height / 2 + (2 * p.wheel_radius + 0.48 + p.height - 0.1) / 2
        t, face = RayCaster(v, f).first_hit(
            np.array([[p.length, 0.0, z], [-p.length, 0.0, z_rear]]), np.array([[-1.0, 0, 0], [1.0, 0, 0]])
        )
        assert np.all(face >= 0)
        np.testing.assert_allclose([p.length - t[0], -p.length + t[1]], [p.length / 2, -p.length / 2], atol=1e-5)
    assert max(lengths) > 19.5 and sum(x >= 16.0 for x in lengths) >= 10
    buses = [generate_vehicle("articulated_bus", s)[2].length for s in range(10)]
    assert min(buses) >= 17.5 and max(buses) <= 18.75


def test_new_bodies_have_their_features():
    """A pickup stays open; a coupe is lower than a sedan of the same seed's range; a tanker's top
    at mid length is its catwalk at the stated height; door mirrors (variant 1) widen a passenger
    body's box by 0.2 m beyond the body drawn from the published range."""
    v, f, p = generate_vehicle("trailer_tanker", 0)
    t, face = RayCaster(v, f).first_hit(np.array([[0.0, 0.0, 10.0]]), np.array([[0, 0, -1.0]]))
    assert face[0] >= 0 and 10.0 - t[0] == pytest.approx(p.height / 2, abs=1e-5)
    assert max(DIMENSIONS["coupe"]["height"]) < max(DIMENSIONS["sedan"]["height"])
    mirrors = 0
    for seed in range(20):
        p = draw_params("sedan", seed)
        lo, hi = DIMENSIONS["sedan"]["width"]
        body = p.width - 0.2 * p.variant
        assert lo - 1e-9 <= body <= hi + 1e-9
        mirrors += p.variant
    assert 10 <= mirrors <= 20  # 80% of passenger bodies have mirrors


@pytest.mark.timeout(300)
def test_dataset_build_same_bytes_with_one_or_two_workers(tmp_path):
    """A tiny dataset build of every car body and every trailer body (6 + 3 procedural vehicles, one
    view each): the same file's bytes with 1 and 2 workers."""
    import hashlib

    from spotlights.data.synthetic import BuildConfig, build_dataset

    cfg = BuildConfig(
        procedural={"count": 6, "classes": ["car"]}, views=1, split="4/1/1", seed=3, gt_points=32, gt_dense=64
    )
    digests = []
    for workers in (1, 2):
        out = tmp_path / f"w{workers}.h5"
        build_dataset(cfg, out, workers=workers, block=1, progress=False, log=lambda m: None)
        digests.append(hashlib.sha256(out.read_bytes()).hexdigest())
    assert digests[0] == digests[1]
