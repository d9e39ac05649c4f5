"""Box-targeted rigs: geometry against closed forms, determinism, files, CLI, study."""

import hashlib
import json
import math
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from spotlights.errors import ParameterError
from spotlights.geometry.encode import MeshProbe, decode, load_encoding, save_encoding
from spotlights.geometry.frames import Normalization, normalization_from_mesh
from spotlights.geometry.rig import (
    BOX_TARGETS,
    Rig,
    RigSpec,
    box_face_solid_angles,
    fibonacci_sphere,
    halton,
    make_rig,
    make_rig_spec,
)

from helpers import assert_user_error, run_cli, slab_interval, src_pythonpath

PHI = (1 + 5**0.5) / 2
CAR = np.array([4.6, 1.9, 1.5]) / np.linalg.norm([4.6, 1.9, 1.5])  # a car's box half-extents, |e| = 1
BOXES = [
    CAR,
    np.ones(3) / math.sqrt(3),
    np.array([0.2, 0.3, 0.93]) / np.linalg.norm([0.2, 0.3, 0.93]),
    np.array([0.9, 0.05, 0.1]),
    np.array([0.6, 0.8, 0.0]),
]  # last: a flat box


def radical_inverse(i: int, base: int) -> float:
    """Digits of i in ``base``, mirrored about the point (written independently of the library)."""
    digits, out = [], 0.0
    while i:
        digits.append(i % base)
        i //= base
    for j, d in enumerate(digits):
        out += d / base ** (j + 1)
    return out


# ---------------------------------------------------------------------------------------------
# geometry
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("targets", BOX_TARGETS)
@pytest.mark.parametrize("scale", [0.5, 0.9, 1.0])
def test_every_ray_passes_through_the_box(targets, scale):
    for e in BOXES:
        rig = make_rig(16, 40, kind="box", box=e, targets=targets, scale=scale)
        o, d = rig.origins, rig.directions
        assert np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
        assert np.allclose(o, np.repeat(fibonacci_sphere(16), 40, axis=0))  # the paper's viewpoints
        t0, t1 = slab_interval(o, d, -e - 1e-9, e + 1e-9)
        assert np.all(t0 <= t1) and np.all(t1 > 0), (targets, scale, e)
        # and through the scaled box [-s e, s e] too (the targets' box)
        if targets != "ellipsoid":
            t0, t1 = slab_interval(o, d, -scale * e - 1e-9, scale * e + 1e-9)
            assert np.all(t0 <= t1)


def test_volume_targets_are_halton_points_in_the_box():
    m, s = 20, 0.8
    assert np.allclose(halton(3)[:, 0], [0.5, 0.25, 0.75]) and np.allclose(halton(3)[:, 1], [1 / 3, 2 / 3, 1 / 9])
    for e in BOXES[:3]:
        rig = make_rig(5, m, kind="box", box=e, targets="volume", scale=s)
        for i, p in enumerate(rig.primary):
            for k in range(m):
                u = np.array([2 * radical_inverse(k + 1, b) - 1 for b in (2, 3, 5)])
                t = s * e * u
                want = (t - p) / np.linalg.norm(t - p)
                assert np.allclose(rig.directions[i * m + k], want, atol=1e-12)


def test_solid_angles_against_closed_forms_and_monte_carlo():
    # a square of half-side a seen from height h on its axis: 4 arcsin(a^2 / (a^2 + h^2))
    a, h = 0.3, 0.5
    om = box_face_solid_angles(np.array([0.0, 0.0, 0.2 + h]), np.array([a, a, 0.2]))
    assert om[4] == pytest.approx(4 * math.asin(a * a / (a * a + h * h)), rel=1e-12)
    assert np.allclose(om[[0, 1, 2, 3, 5]], 0.0)
    # a cube seen from far away along a diagonal: three faces, equal shares
    om = box_face_solid_angles(np.array([50.0, 50.0, 50.0]), np.ones(3))
    assert np.allclose(om[[0, 2, 4]], om[0]) and np.allclose(om[[1, 3, 5]], 0.0)
    # an off-axis point: Monte-Carlo over uniform directions
    rng = np.random.default_rng(1)
    p, e = np.array([0.7, -0.4, 0.55]), np.array([0.5, 0.3, 0.2])
    d = rng.normal(size=(400_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t0, t1 = slab_interval(np.broadcast_to(p, d.shape), d, -e, e)
    hit = (t0 <= t1) & (t1 > 0)
    entry = p + t0[:, None] * d
    om = box_face_solid_angles(p, e)
    for face in range(6):
        ax, sign = face // 2, 1 - 2 * (face % 2)
        on_face = hit & np.isclose(entry[:, ax], sign * e[ax], atol=1e-9)
        assert om[face] == pytest.approx(4 * math.pi * on_face.mean(), abs=4e-3)


def test_visible_targets_are_on_faces_facing_the_viewpoint_shared_by_solid_angle():
    m, s = 400, 0.9
    for e in BOXES[:4]:
        rig = make_rig(12, m, kind="box", box=e, targets="visible", scale=s)
        o, d = rig.origins, rig.directions
        se = s * e
        t0, _ = slab_interval(o, d, -se, se)
        entry = o + t0[:, None] * d
        cheb = np.max(np.abs(entry) / se, axis=1)
        assert np.allclose(cheb, 1.0, atol=1e-9)  # the ray enters the scaled box
        # the target is that entry point: it sits on a face facing the viewpoint (on an edge: one of two)
        sign = np.sign(entry)
        facing = np.isclose(np.abs(entry) / se, 1.0, atol=1e-9) & (sign * o - se > 0)
        assert np.all(facing.any(axis=1))
        face_axis = np.argmax(facing, axis=1)
        sign = sign[np.arange(len(sign)), face_axis]
        # face shares follow the faces' solid angles (1/M resolution of the lattice, edge ties)
        for i in range(12):
            om = box_face_solid_angles(rig.primary[i], se)
            sl = slice(i * m, (i + 1) * m)
            for face in range(6):
                ax, sg = face // 2, 1 - 2 * (face % 2)
                count = np.sum((face_axis[sl] == ax) & (sign[sl] == sg))
                assert abs(count / m - om[face] / om.sum()) <= 2.5 / m


def test_surface_targets_are_fixed_positions_on_the_faces():
    m, s = 600, 0.8
    for e in BOXES[:3]:
        rig = make_rig(3, m, kind="box", box=e, targets="surface", scale=s)
        d = rig.directions
        # the target of ray k: on the far or near side of the scaled box, at the position set by the lattice
        k = np.arange(m)
        a, b = np.mod(k / PHI, 1.0), (k + 0.5) / m
        face = np.floor(6 * b).astype(int)
        local = 6 * b - face
        u = np.zeros((m, 3))
        for j in range(m):
            ax, sg = face[j] // 2, 1 - 2 * (face[j] % 2)
            u[j, ax], u[j, (ax + 1) % 3], u[j, (ax + 2) % 3] = sg, 2 * a[j] - 1, 2 * local[j] - 1
        for i in range(3):
            t = s * e * u
            want = (t - rig.primary[i]) / np.linalg.norm(t - rig.primary[i], axis=1, keepdims=True)
            assert np.allclose(d[i * m : (i + 1) * m], want, atol=1e-9)
        assert np.bincount(face, minlength=6).tolist() == [100] * 6


def test_ellipsoid_rays_meet_the_inscribed_ellipsoid_and_sample_zero_is_central():
    m = 64
    for e in BOXES:
        s = 1.0
        rig = make_rig(20, m, kind="box", box=e, targets="ellipsoid", scale=s)
        o, d = rig.origins, rig.directions
        if np.all(e > 0):  # ray/ellipsoid in closed form: |(o + t d) / (s e)|^2 = 1
            oo, dd = o / (s * e), d / (s * e)
            qa, qb, qc = np.sum(dd * dd, 1), 2 * np.sum(oo * dd, 1), np.sum(oo * oo, 1) - 1
            disc = qb * qb - 4 * qa * qc
            assert np.all(disc >= -1e-9)
            # the outermost lattice ring grazes it: sqrt((M-1)/M) of the tangent cone
            assert np.min(disc / (qb * qb)) < 0.2
        # sample 0 of each viewpoint is the central ray, as in the paper's cap
        assert np.allclose(d[::m], -rig.primary, atol=1e-12)


@pytest.mark.parametrize("targets", ["volume", "surface", "ellipsoid"])  # not "visible" (docs/box-rig.md)
def test_rays_move_continuously_with_the_box_proportions(targets):
    # ordered correspondences: along a path of boxes (a car -> a cube -> a tall box), no ray jumps
    path = [CAR, BOXES[1], BOXES[2]]
    prev = None
    worst = 0.0
    for a, b in zip(path[:-1], path[1:]):
        for w in np.linspace(0, 1, 150):
            e = (1 - w) * a + w * b
            e /= np.linalg.norm(e)
            d = make_rig(32, 64, kind="box", box=e, targets=targets, scale=0.9).directions
            if prev is not None:
                worst = max(worst, float(np.max(np.arccos(np.clip(np.sum(d * prev, 1), -1, 1)))))
            prev = d
    assert worst < math.radians(2.0), math.degrees(worst)


def test_mixed_rig_keeps_the_paper_cap_first():
    rig = make_rig(8, 64, 45.0, kind="box", box=CAR, targets="ellipsoid", cap_share=0.25)
    cap = make_rig(8, 16, 45.0).directions.reshape(8, 16, 3)
    d = rig.directions.reshape(8, 64, 3)
    assert np.array_equal(d[:, :16], cap)
    t0, t1 = slab_interval(rig.origins.reshape(8, 64, 3)[:, 16:].reshape(-1, 3), d[:, 16:].reshape(-1, 3), -CAR, CAR)
    assert np.all(t0 <= t1)
    assert rig.name == "box-8x64-ellipsoid-s1-cap0.25@45"


# ---------------------------------------------------------------------------------------------
# determinism, specs, serialisation
# ---------------------------------------------------------------------------------------------
def _digest(rig):
    return hashlib.sha256(np.ascontiguousarray(rig.directions).tobytes()).hexdigest()


def test_rig_is_deterministic_for_a_given_box_even_across_processes():
    spec = make_rig_spec(32, 64, kind="box")
    a = spec.for_box(CAR)
    b = Rig.from_dict(json.loads(json.dumps(a.to_dict())))
    assert a == b and np.array_equal(a.directions, b.directions) and a is spec.for_box(CAR.copy())
    code = (
        "import numpy as np; from spotlights.geometry.rig import make_rig; import hashlib, json, sys; "
        "r = make_rig(32, 64, kind='box', box=json.loads(sys.argv[1])); "
        "print(hashlib.sha256(np.ascontiguousarray(r.directions).tobytes()).hexdigest())"
    )
    env_path = src_pythonpath()
    out = subprocess.run(
        [sys.executable, "-c", code, json.dumps(CAR.tolist())],
        capture_output=True,
        text=True,
        env={"PYTHONPATH": env_path, "PATH": ""},
        check=True,
    ).stdout.strip()
    assert out == _digest(a)


def test_cap_rigs_and_their_dicts_are_unchanged():
    r = Rig(32, 64, 60.0)
    assert r.to_dict() == {"kind": "cap", "n_primary": 32, "n_secondary": 64, "angle": 60.0}
    assert r.name == "cap-32x64-60" and r.box is None and r.spec.for_box(None) == r
    assert make_rig(32, 64, 60) == r and RigSpec.from_dict(r.to_dict()).for_box(CAR) == r
    assert make_rig_spec(32, 64).to_dict() == r.to_dict()


def test_box_rig_dict_and_name():
    rig = make_rig(32, 64, kind="box", box=CAR, targets="volume", scale=0.9)
    d = rig.to_dict()
    assert d == {
        "kind": "box",
        "n_primary": 32,
        "n_secondary": 64,
        "angle": 60.0,
        "scale": 0.9,
        "targets": "volume",
        "cap_share": 0.0,
        "box": CAR.tolist(),
    }
    assert rig.name == "box-32x64-volume-s0.9"
    assert RigSpec.from_name(rig.name) == rig.spec == RigSpec.from_dict(d)
    assert RigSpec.from_name("cap-32x64-60") == make_rig_spec()
    spec = RigSpec.from_name("box-16x32-ellipsoid-s1-cap0.25@45")
    assert (spec.targets, spec.scale, spec.cap_share, spec.angle) == ("ellipsoid", 1.0, 0.25, 45.0)
    default = make_rig_spec(kind="box")
    assert (default.targets, default.scale, default.cap_share) == ("ellipsoid", 1.0, 0.0)


def test_batched_directions_and_decoding_match_per_box_rigs():
    spec = make_rig_spec(8, 32, kind="box", targets="visible", scale=0.8)
    boxes = np.stack(BOXES[:4])
    dirs = spec.directions_for_boxes(boxes)
    assert dirs.shape == (4, 256, 3)
    rng = np.random.default_rng(0)
    depths = rng.random((4, 256)) * (rng.random((4, 256)) > 0.3)
    pts, mask = decode(depths, spec, extents=boxes)
    for b, e in enumerate(boxes):
        rig = spec.for_box(e)
        assert np.array_equal(dirs[b], rig.directions)
        p1, m1 = decode(depths[b], rig)
        assert np.array_equal(mask[b], m1) and np.allclose(pts[b], p1, atol=1e-6)
    assert np.array_equal(spec.origins, spec.for_box(CAR).origins)
    with pytest.raises(ParameterError):
        decode(depths, spec)


@pytest.mark.parametrize(
    "kw",
    [
        dict(kind="box"),
        dict(kind="box", box=[1, 1, 1]),
        dict(kind="box", box=[-0.1, 0.5, 0.5]),
        dict(kind="box", box=[0, 0, 0]),
        dict(kind="box", box=CAR, scale=0),
        dict(kind="box", box=CAR, scale=1.2),
        dict(kind="box", box=CAR, targets="cone"),
        dict(kind="box", box=CAR, cap_share=1.0),
        dict(scale=0.9),
        dict(targets="volume"),
        dict(kind="sphere"),
        dict(kind="box", box=[np.nan, 0.5, 0.5]),
    ],
)
def test_bad_box_parameters_rejected(kw):
    with pytest.raises(ParameterError):
        make_rig(16, 16, **{k: v for k, v in kw.items() if k != "box"}, box=kw.get("box"))


# ---------------------------------------------------------------------------------------------
# encoding, files
# ---------------------------------------------------------------------------------------------
def _box_mesh(size=(4.0, 1.6, 1.2), center=(1.0, -2.0, 0.5)):
    m = trimesh.creation.box(extents=size)
    m.apply_translation(center)
    return m


@pytest.mark.parametrize("targets", BOX_TARGETS)
def test_a_solid_box_is_hit_by_every_ray_at_the_slab_distance(targets):
    mesh = _box_mesh()
    probe = MeshProbe(mesh)
    e = np.array([4.0, 1.6, 1.2]) / np.linalg.norm([4.0, 1.6, 1.2])
    assert np.allclose(probe.box_extents, e)
    spec = make_rig_spec(16, 64, kind="box", targets=targets)
    rig = probe.rig_for(spec)
    assert rig.box == pytest.approx(tuple(e))
    depths = probe.encode(spec)
    assert np.array_equal(depths, probe.encode(rig))
    assert np.all(depths > 0)  # hit ratio 1: every ray goes through the box
    t0, _ = slab_interval(rig.origins, rig.directions, -e, e)
    assert np.allclose(depths, t0 / 2, atol=2e-6)
    pts, mask = decode(depths, rig)
    assert mask.all() and np.allclose(np.max(np.abs(pts) / e, axis=1), 1.0, atol=1e-5)
    cap = probe.encode(make_rig(16, 64, 60))
    assert np.mean(cap > 0) < 0.7  # the paper's rig wastes rays on the same box


def test_encoding_files_round_trip_and_old_files_still_load(tmp_path):
    mesh = _box_mesh()
    probe = MeshProbe(mesh)
    rig = probe.rig_for(make_rig_spec(8, 32, kind="box", targets="volume", scale=0.9))
    depths = probe.encode(rig)
    save_encoding(tmp_path / "box.npz", depths, rig, probe.normalization)
    enc = load_encoding(tmp_path / "box.npz")
    assert enc.rig == rig and np.array_equal(enc.depths, depths)
    with np.load(tmp_path / "box.npz") as z:
        assert np.array_equal(z["directions"], rig.directions.astype(np.float32))
        assert int(z["primary"]) == 8 and int(z["secondary"]) == 32
    pts = enc.points(frame="original")
    assert np.allclose(np.max(np.abs(pts - [1.0, -2.0, 0.5]) / [2.0, 0.8, 0.6], axis=1), 1.0, atol=1e-4)
    with pytest.raises(ParameterError):
        save_encoding(tmp_path / "spec.npz", depths, rig.spec, probe.normalization)
    # a cap encoding as the core has always written it, and an older one without the "rig" key
    cap = make_rig(8, 32, 45)
    cdepths = probe.encode(cap)
    norm = normalization_from_mesh(mesh)
    common = dict(
        depths=cdepths,
        origins=cap.origins.astype(np.float32),
        directions=cap.directions.astype(np.float32),
        center=norm.center,
        radius=np.float64(norm.radius),
        rotation=norm.rotation,
        primary=np.int64(8),
        secondary=np.int64(32),
        angle=np.float64(45.0),
    )
    np.savez(
        tmp_path / "cap.npz",
        rig=np.array(json.dumps({"kind": "cap", "n_primary": 8, "n_secondary": 32, "angle": 45.0})),
        **common,
    )
    np.savez(tmp_path / "legacy.npz", **common)
    for name in ("cap.npz", "legacy.npz"):
        enc = load_encoding(tmp_path / name)
        assert enc.rig == cap and enc.rig.kind == "cap"
        assert np.allclose(enc.points(), decode(cdepths, cap)[0][cdepths > 0], atol=1e-6)


def test_spec_without_box_size_is_a_clear_error():
    mesh = _box_mesh()
    norm = normalization_from_mesh(mesh)
    probe = MeshProbe(mesh, Normalization(norm.center, norm.radius, norm.rotation))  # no size
    with pytest.raises(ParameterError, match="box"):
        probe.encode(make_rig_spec(8, 8, kind="box"))
    assert probe.encode(make_rig_spec(8, 8)).shape == (64,)  # cap specs need no box


# ---------------------------------------------------------------------------------------------
# command line and study
# ---------------------------------------------------------------------------------------------
def test_cli_encode_decode_show_with_a_box_rig(tmp_path):
    ply = tmp_path / "box.ply"
    _box_mesh().export(ply)
    r = run_cli("encode", ply, "--out", tmp_path / "b.npz", "--rig-kind", "box", "-N", "16", "-M", "32")
    assert r.returncode == 0, r.stderr
    assert "box-16x32-ellipsoid-s1" in r.stdout and "hit ratio 1.000" in r.stdout
    r = run_cli("decode", tmp_path / "b.npz", "--out", tmp_path / "b.npy")
    assert r.returncode == 0, r.stderr
    pts = np.load(tmp_path / "b.npy")
    assert len(pts) == 512
    assert np.allclose(np.max(np.abs(pts - [1.0, -2.0, 0.5]) / [2.0, 0.8, 0.6], axis=1), 1.0, atol=1e-4)
    r = run_cli("show", tmp_path / "b.npz", "--out", tmp_path / "b.png")
    assert r.returncode == 0 and "box half-extents" in r.stdout, r.stderr
    assert_user_error(run_cli("encode", ply, "--out", tmp_path / "c.npz", "--box-scale", "0.8"), "--rig-kind box")
    assert_user_error(
        run_cli("encode", ply, "--out", tmp_path / "c.npz", "--rig-kind", "box", "--box-scale", "2"), "scale"
    )


@pytest.mark.slow
def test_study_command_on_small_meshes(tmp_path):
    root = tmp_path / "shapes"
    for cat, make in (
        ("boxes", lambda j: trimesh.creation.box(extents=[1 + j, 1, 0.5])),
        ("spheres", lambda j: trimesh.creation.icosphere(subdivisions=2, radius=1 + j)),
        ("few", lambda j: trimesh.creation.box()),
    ):
        (root / cat).mkdir(parents=True)
        for j in range(5 if cat != "few" else 2):
            make(j).export(root / cat / f"{cat}{j}.ply")
    out = tmp_path / "study"
    r = run_cli("study", "rigs", "--out", out, "--meshes", root, "--rays", "128")
    assert r.returncode == 0, r.stderr
    import pandas as pd

    per = pd.read_csv(out / "rigs_per_mesh.csv.gz")
    assert set(per.category) == {"boxes", "spheres"}  # "few" has fewer than 5 meshes
    box = per[(per.category == "boxes") & (per.family == "box") & ~per.label.str.contains("cap")]
    assert np.allclose(box.hit_ratio, 1.0)  # solid boxes: every box-targeted ray hits
    summary = pd.read_csv(out / "rigs.csv")
    assert {"all", "boxes", "spheres"} <= set(summary.category)
    assert (out / "rigs.md").read_text().startswith("# Rig study")
    assert (out / "rigs.png").read_bytes()[:4] == b"\x89PNG"
    before = (out / "rigs.csv").read_bytes()
    r = run_cli("study", "rigs", "--out", out, "--meshes", root, "--rays", "128")  # resumes from the cache
    assert r.returncode == 0 and (out / "rigs.csv").read_bytes() == before
    assert_user_error(run_cli("study", "rigs", "--out", out, "--meshes", root, "--rays", "100"), "multiple of")
    assert_user_error(run_cli("study", "rigs", "--out", out, "--meshes", tmp_path / "nope"), "nope")
    (root / "boxes" / "broken.ply").write_text("not a mesh")
    assert_user_error(
        run_cli("study", "rigs", "--out", out, "--meshes", root, "--rays", "64", "--workers", "2"), "broken.ply"
    )


def test_cli_offers_every_target_set_and_mixes_keep_a_box_ray():
    from spotlights.cli import build_parser

    enc = build_parser()._subparsers._group_actions[0].choices["encode"]
    action = next(a for a in enc._actions if a.dest == "box_targets")
    assert tuple(sorted(action.choices)) == tuple(sorted(BOX_TARGETS))
    rig = make_rig(4, 8, kind="box", box=CAR, cap_share=0.99)  # round(0.99 * 8) = 8: one ray stays on the box
    assert np.array_equal(rig.directions.reshape(4, 8, 3)[:, :7], make_rig(4, 7).directions.reshape(4, 7, 3))
    from spotlights.geometry.rig import check_extents

    assert check_extents(np.stack([CAR, CAR])) == (tuple(CAR.tolist()),) * 2
    with pytest.raises(ParameterError, match="unit sphere"):
        check_extents(np.stack([CAR, 2 * CAR]))
