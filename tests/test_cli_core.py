"""`spotlights encode / decode / show` end to end, and their bad inputs."""

import math

import numpy as np
import pytest
import trimesh

from spotlights.geometry import load_points

from helpers import KENNEY, assert_user_error, need, run_cli


@pytest.fixture(scope="module")
def sphere_ply(tmp_path_factory):
    d = tmp_path_factory.mktemp("meshes")
    m = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    m.apply_translation([1, 2, 3])
    m.export(d / "sphere.ply")
    return d / "sphere.ply"


@pytest.mark.slow
def test_encode_decode_show_round_trip(sphere_ply, tmp_path):
    r = run_cli("encode", sphere_ply, "--out", tmp_path / "s.npz")
    assert r.returncode == 0, r.stderr
    assert "hit ratio 0.37" in r.stdout  # ~0.367 for a sphere of radius 1/sqrt(3) at 60 deg
    for fmt in ("ply", "pcd", "npy", "xyz"):
        r = run_cli("decode", tmp_path / "s.npz", "--out", tmp_path / f"p.{fmt}")
        assert r.returncode == 0, r.stderr
        pts = load_points(tmp_path / f"p.{fmt}")
        assert np.allclose(np.linalg.norm(pts - [1, 2, 3], axis=1), 0.5, atol=1e-3)
    r = run_cli("decode", tmp_path / "s.npz", "--out", tmp_path / "u.npy", "--frame", "unit")
    assert np.allclose(np.linalg.norm(np.load(tmp_path / "u.npy"), axis=1), 1 / math.sqrt(3), atol=1e-3)
    for src in ("s.npz", "p.ply"):
        r = run_cli("show", tmp_path / src, "--out", tmp_path / f"{src}.png")
        assert r.returncode == 0, r.stderr
        assert (tmp_path / f"{src}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = run_cli("show", sphere_ply, "--out", tmp_path / "mesh.png")
    assert r.returncode == 0 and "mesh" in r.stdout


def test_encode_several_meshes_into_folder(sphere_ply, tmp_path):
    box = tmp_path / "box.obj"
    trimesh.creation.box(extents=[2, 1, 1]).export(box)
    r = run_cli("encode", sphere_ply, box, "--out", tmp_path / "enc", "-N", "8", "-M", "16", "--angle", "45")
    assert r.returncode == 0, r.stderr
    with np.load(tmp_path / "enc" / "box.npz") as z:
        assert z["depths"].shape == (128,) and float(z["angle"]) == 45


def test_kenney_glb_scene_is_flattened_and_axes_applied(tmp_path):
    glb = need(KENNEY) / "sedan.glb"
    r = run_cli("encode", glb, "--up", "y", "--forward", "z", "--out", tmp_path / "k.npz")
    assert r.returncode == 0, r.stderr
    with np.load(tmp_path / "k.npz") as z:
        assert (z["depths"] > 0).mean() > 0.2


def test_help_everywhere_has_examples():
    r = run_cli("--help")
    assert r.returncode == 0 and "encode" in r.stdout
    for cmd in ("encode", "decode", "show"):
        r = run_cli(cmd, "--help")
        assert r.returncode == 0 and "example:" in r.stdout
    assert run_cli("--version").stdout.startswith("spotlights ")


def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "make, fragment",
    [
        (lambda d: d / "missing.ply", "no such file"),
        (lambda d: _write(d / "junk.ply", "this is not a ply file\n"), "cannot read"),
        (lambda d: _write(d / "empty.obj", "# nothing\n"), "empty"),
        (lambda d: _write(d / "nan.obj", "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n"), "NaN"),
        (lambda d: _write(d / "flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"), "degenerate"),
        (lambda d: _write(d / "point.obj", "v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n"), "zero-size"),
        (lambda d: d, "folder"),
    ],
)
def test_bad_meshes_one_line_error_no_output(tmp_path, make, fragment):
    src = make(tmp_path)
    out = tmp_path / "out" / "x.npz"
    r = run_cli("encode", src, "--out", out)
    assert_user_error(r, fragment, src.name)
    assert not out.exists()
    assert not list((tmp_path / "out").glob("*")) if (tmp_path / "out").exists() else True


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["-N", "0"], "N must be"),
        (["-M", "-3"], "M must be"),
        (["--angle", "95"], "(0, 90]"),
        (["--angle", "0"], "(0, 90]"),
        (["--radius", "2.5"], "radius"),
        (["-M", "100000000"], "rays is more than"),
    ],
)
def test_bad_rig_parameters(sphere_ply, tmp_path, args, fragment):
    r = run_cli("encode", sphere_ply, "--out", tmp_path / "x.npz", *args)
    assert_user_error(r, fragment)
    assert not (tmp_path / "x.npz").exists()


def test_bad_decode_inputs(tmp_path):
    np.savez(tmp_path / "other.npz", foo=np.zeros(3))
    assert_user_error(run_cli("decode", tmp_path / "other.npz", "--out", tmp_path / "a.ply"), "missing key")
    (tmp_path / "trunc.npz").write_bytes(b"PK\x03\x04garbage")
    assert_user_error(run_cli("decode", tmp_path / "trunc.npz", "--out", tmp_path / "a.ply"), "trunc.npz")
    assert_user_error(run_cli("show", tmp_path / "nope.pcd"), "no such file")
    (tmp_path / "g.npz").write_text("garbage")
    assert_user_error(run_cli("show", tmp_path / "g.npz"), "g.npz", "not a readable")
    _write(
        tmp_path / "h.ply",
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
        "property float z\nelement face abc\nend_header\n0 0 0\n",
    )
    assert_user_error(run_cli("show", tmp_path / "h.ply"), "h.ply")
    assert not (tmp_path / "a.ply").exists()


def test_decode_refuses_out_of_range_clip_and_empty_output(sphere_ply, tmp_path):
    assert run_cli("encode", sphere_ply, "--out", tmp_path / "s.npz").returncode == 0
    assert_user_error(run_cli("decode", tmp_path / "s.npz", "--out", tmp_path / "a.ply", "--clip", "2"), "[0, 1]")
    assert_user_error(run_cli("decode", tmp_path / "s.npz", "--out", tmp_path / "a.ply", "--clip", "nan"), "[0, 1]")
    assert_user_error(run_cli("decode", tmp_path / "s.npz", "--out", tmp_path / "a.ply", "--clip", "1"), "no ray hit")
    assert not (tmp_path / "a.ply").exists()


def test_encode_into_existing_folder(sphere_ply, tmp_path):
    (tmp_path / "enc").mkdir()
    assert run_cli("encode", sphere_ply, "--out", tmp_path / "enc").returncode == 0
    assert (tmp_path / "enc" / "sphere.npz").exists()


def test_bad_point_clouds(tmp_path):
    from spotlights.errors import InputFileError

    _write(tmp_path / "nan.xyz", "0 0 0\n1 nan 2\n")
    _write(tmp_path / "empty.xyz", "\n")
    np.save(tmp_path / "bad.npy", np.zeros((4, 2)))
    for name, frag in [("nan.xyz", "NaN"), ("empty.xyz", "empty"), ("bad.npy", "shape")]:
        with pytest.raises(InputFileError, match=frag):
            load_points(tmp_path / name)
