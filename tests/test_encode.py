"""Encoding and decoding against closed forms (sphere, box) and brute force."""

import math

import numpy as np
import pytest
import trimesh

from spotlights.geometry import (
    MeshProbe,
    RayCaster,
    decode,
    encode_mesh,
    encode_mesh_files,
    encode_meshes,
    hit_ratio,
    load_encoding,
    load_mesh,
    make_rig,
    save_encoding,
)

from helpers import CARS, brute_force_first_hit, need, sphere_ray_depths

# The icosphere is a polyhedron inscribed in the sphere: its faces lie up to
# delta = rho - min(face-plane distance) inside it (computed from the mesh itself), so a
# mesh hit is never earlier than the sphere hit and at most delta / cos(incidence) later
# along the ray, cos(incidence) = sqrt(discriminant) / rho. Near-tangent rays can miss the
# polyhedron while grazing the sphere: rays whose discriminant is within 1e-3 of tangency
# are excluded from the hit/miss comparison. Embree works in float32 (~1e-7 relative).
RHO = 1 / math.sqrt(3)


def inscribed_gap(mesh_unit_vertices, faces):
    tri = mesh_unit_vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return RHO - np.abs(np.einsum("fc,fc->f", n, tri[:, 0])).min()


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
    m.apply_translation([1, 2, 3])
    return m


@pytest.mark.parametrize("angle", [30, 60, 90])
def test_sphere_depths_match_closed_form(sphere, angle):
    rig = make_rig(24, 256, angle=angle)
    depths = encode_mesh(sphere, rig)
    t, disc = sphere_ray_depths(rig.origins, rig.directions, [0, 0, 0], 1 / math.sqrt(3))
    clear = np.abs(disc) > 1e-3
    expect_hit = np.isfinite(t)
    assert np.array_equal((depths > 0)[clear], expect_hit[clear])
    both = (depths > 0) & expect_hit
    probe = MeshProbe(sphere)
    delta = inscribed_gap(probe.normalization.to_unit(sphere.vertices), sphere.faces)
    assert 0 < delta < 2e-4
    err = depths[both] - t[both] / 2  # depth = distance / 2
    bound = delta / (np.sqrt(disc[both]) / RHO) / 2
    assert err.min() > -1e-6
    assert (err <= bound + 1e-6).all()
    assert depths.dtype == np.float32 and depths.min() >= 0 and depths.max() <= 1


def test_sphere_hit_ratio_is_solid_angle_ratio(sphere):
    # The sphere of radius 1/sqrt(3) subtends a half-angle asin(1/sqrt(3)) = 35.26 deg from
    # every viewpoint; with equal-area cap sampling the hit share is the area ratio of caps.
    m = 2048
    depths = encode_mesh(sphere, make_rig(6, m, angle=60))
    expect = (1 - math.cos(math.asin(1 / math.sqrt(3)))) / (1 - math.cos(math.radians(60)))
    assert expect == pytest.approx(0.367, abs=1e-3)
    assert hit_ratio(depths) == pytest.approx(expect, abs=2.0 / m)


def test_decoded_points_lie_on_sphere_and_in_original_frame(sphere, tmp_path):
    rig = make_rig(32, 64, angle=60)
    probe = MeshProbe(sphere)
    depths = probe.encode(rig)
    pts, mask = decode(depths, rig)
    assert pts.shape == (2048, 3) and mask.shape == (2048,)
    r = np.linalg.norm(pts[mask], axis=1)
    delta = inscribed_gap(probe.normalization.to_unit(sphere.vertices), sphere.faces)
    assert (r <= RHO + 1e-6).all() and (r >= RHO - delta - 1e-6).all()
    save_encoding(tmp_path / "s.npz", depths, rig, probe.normalization)
    enc = load_encoding(tmp_path / "s.npz")
    orig = enc.points(frame="original")
    assert np.allclose(np.linalg.norm(orig - [1, 2, 3], axis=1), 0.5, atol=2e-4)
    with np.load(tmp_path / "s.npz") as z:  # the file contract of `spotlights encode`
        assert z["depths"].dtype == np.float32 and z["depths"].shape == (2048,)
        assert z["origins"].dtype == np.float32 and z["origins"].shape == (2048, 3)
        assert z["directions"].dtype == np.float32 and z["directions"].shape == (2048, 3)
        assert z["center"].dtype == np.float64 and z["center"].shape == (3,)
        assert z["radius"].dtype == np.float64 and z["radius"].shape == ()
        assert int(z["primary"]) == 32 and int(z["secondary"]) == 64 and float(z["angle"]) == 60


def test_box_mesh_points_on_faces():
    box = trimesh.creation.box(extents=[4, 2, 1])  # not normalised: rays see a 4x2x1 box
    rig = make_rig(64, 128, angle=60)
    depths = encode_mesh(box, rig)
    pts, mask = decode(depths, rig)
    R = 0.5 * math.sqrt(16 + 4 + 1)
    half = np.array([2, 1, 0.5]) / R
    on_face = np.isclose(np.abs(pts[mask]), half, atol=1e-5).any(axis=1)
    inside = (np.abs(pts[mask]) <= half + 1e-5).all(axis=1)
    assert on_face.all() and inside.all()
    assert mask.mean() > 0.2


def test_decode_clip_and_batch():
    rig = make_rig(2, 4, angle=30)
    depths = np.array([[0, 0.1, 0.3, 0.5, 0.0, 0.25, 0.19, 1.0]] * 3, dtype=np.float32)
    pts, mask = decode(depths, rig, clip=0.2)
    assert pts.shape == (3, 8, 3)
    assert mask[0].tolist() == [False, False, True, True, False, True, False, True]
    assert np.allclose(pts[0, 3], rig.origins[3] + 2 * 0.5 * rig.directions[3], atol=1e-6)


def test_engine_matches_brute_force_moller_trumbore():
    rng = np.random.default_rng(3)
    mesh = trimesh.creation.annulus(r_min=0.2, r_max=0.6, height=0.5, sections=24)
    o = rng.normal(size=(400, 3))
    o /= np.linalg.norm(o, axis=1, keepdims=True)
    d = -o + 0.3 * rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, face = RayCaster(mesh.vertices, mesh.faces).first_hit(o, d)
    bf, _ = brute_force_first_hit(mesh, o, d)  # every ray against every triangle, both windings
    assert np.array_equal(np.isfinite(t), np.isfinite(bf))
    assert np.allclose(t[np.isfinite(t)], bf[np.isfinite(bf)], atol=1e-5)
    assert (face[np.isfinite(t)] >= 0).all()


def test_trimesh_engine_agrees_with_embree():
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.4)
    rig = make_rig(8, 64, angle=60)
    a = MeshProbe(m, engine="embree").encode(rig)
    b = MeshProbe(m, engine="trimesh").encode(rig)
    assert np.allclose(a, b, atol=1e-5)


def test_encode_many_meshes_and_rigs():
    meshes = [trimesh.creation.box(extents=[1, 1, 1]), trimesh.creation.icosphere(radius=2)]
    rigs = [make_rig(8, 16, 60), make_rig(16, 8, 30)]
    out = encode_meshes(meshes, rigs)
    assert set(out) == {"cap-8x16-60", "cap-16x8-30"}
    assert out["cap-8x16-60"].shape == (2, 128)
    assert np.array_equal(out["cap-16x8-30"][1], encode_mesh(meshes[1], rigs[1]))


def test_real_car_hit_ratio_plausible():
    car = load_mesh(need(CARS) / "sedan" / "037-CAR02.ply")
    d = encode_mesh(car, make_rig())
    assert 0.2 < hit_ratio(d) < 0.5  # cars fill little of their sphere (paper: ~34-50% at 60 deg)


def test_encode_mesh_files_same_bytes_whatever_workers(tmp_path):
    paths = []
    for j, ext in enumerate([[1, 2, 3], [2, 1, 1], [1, 1, 4]]):
        p = tmp_path / f"box{j}.ply"
        trimesh.creation.box(extents=ext).export(p)
        paths.append(p)
    rig = make_rig(8, 32, 60)
    a = encode_mesh_files(paths, rig, workers=1)[rig.name]
    b = encode_mesh_files(paths, [rig], workers=2)[rig.name]
    assert a.shape == (3, 256) and a.tobytes() == b.tobytes()
    assert np.array_equal(a[1], encode_mesh(load_mesh(paths[1]), rig))


def test_one_query_split_over_threads_gives_identical_depths():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.7)
    rig = make_rig(64, 512, angle=60)  # 32,768 rays: above the split threshold
    one = MeshProbe(mesh).encode(rig)
    two = MeshProbe(mesh, workers=2).encode(rig)
    assert one.tobytes() == two.tobytes()
