"""Hostile box numbers (fuzzer findings): huge but finite centres and sizes, NaN in KITTI labels, matrices that
are not rotations. Each is one line naming the file (or parameter) it came from, exit 2, no traceback and no
numpy RuntimeWarning; the bounds are :data:`~spotlights.geometry.boxes.MAX_BOX_CENTER_M` and
:data:`~spotlights.geometry.boxes.MAX_BOX_SIZE_M` (one owner: the box), and for meshes
:data:`~spotlights.geometry.frames.MAX_COORDINATE`."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from spotlights.errors import InputFileError, ParameterError
from spotlights.geometry.box_json import box_from_dict
from spotlights.geometry.boxes import MAX_BOX_CENTER_M, MAX_BOX_SIZE_M, Box, box_range_problem
from spotlights.geometry.rotations import orthonormalize, rotation_z

from builders import write_mini_nuscenes
from helpers import assert_user_error, run_cli

KITTI_CALIB = (
    "R0_rect: 0.9999128 0.01009263 -0.008511932 -0.01012729 0.9999406 -0.004037671 0.008470675 0.004123522 0.9999556\n"
    "Tr_velo_to_cam: 0.006927964 -0.9999722 -0.002757829 -0.02457729 -0.001162982 0.002749836 -0.9999955 "
    "-0.06127237 0.9999753 0.006931141 -0.001143899 -0.3321029\n"
)
KITTI_GOOD = "Car 0.00 0 0 0 0 0 0 1.5 1.8 4.0 0 1.65 10 0"


def clean_error(proc, *fragments: str) -> None:
    """:func:`assert_user_error`, and no warning lines (numpy overflow) around it."""
    assert_user_error(proc, *fragments)
    assert "RuntimeWarning" not in proc.stderr and "overflow" not in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr


@pytest.fixture
def scan(tmp_path) -> Path:
    """A small scan (N, 3) float32 .npy with a car-sized blob at (10, 0, -0.9) metres."""
    rng = np.random.default_rng(0)
    p = tmp_path / "scan.npy"
    np.save(p, (rng.uniform(-1, 1, (300, 3)) * [2, 0.9, 0.7] + [10, 0, -0.9]).astype(np.float32))
    return p


@pytest.fixture
def kitti(tmp_path) -> Path:
    """A KITTI object folder (one frame) whose label is replaced per test."""
    root = tmp_path / "kitti"
    for sub in ("label_2", "calib", "velodyne"):
        (root / sub).mkdir(parents=True)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (300, 3)) * [2, 0.9, 0.7] + [10, 0, -0.9]
    np.c_[pts, np.zeros(len(pts))].astype("<f4").tofile(root / "velodyne" / "000000.bin")
    (root / "calib" / "000000.txt").write_text(KITTI_CALIB)
    (root / "label_2" / "000000.txt").write_text(KITTI_GOOD + "\n")
    return root


# ---------------------------------------------------------------------------- one box: --center/--size, --box


@pytest.mark.parametrize(
    "center, size, what",
    [
        (["1e200", "0", "0"], ["4", "1.8", "1.4"], "centre"),
        (["0", "5e8", "0"], ["4", "1.8", "1.4"], "centre"),
        (["10", "0", "0"], ["1e200", "1.8", "1.4"], "size"),
    ],
)
def test_huge_center_or_size_on_the_command_line(tmp_path, scan, center, size, what):
    out = tmp_path / "o" / "c.ply"
    proc = run_cli("complete", scan, "--center", *center, "--size", *size, "-o", out)
    clean_error(proc, "--center/--size", what, "out of range")
    assert not out.exists() and not out.parent.exists()


@pytest.mark.parametrize(
    "box, what",
    [
        ({"center": [1e300, 0, 0], "size": [4, 1.8, 1.4], "yaw": 0}, "centre"),
        ({"center": [10, 0, 0], "size": [1e200, 1e200, 1e200], "yaw": 0}, "size"),
        ({"center": [10, 0, 0], "size": [4, 1.8, 1e5], "yaw": 0}, "size"),
    ],
)
def test_huge_box_json(tmp_path, scan, box, what):
    f = tmp_path / "hostile_box.json"
    f.write_text(json.dumps(box))
    clean_error(run_cli("complete", scan, "--box", f, "-o", tmp_path / "c.ply"), "hostile_box.json", what)
    boxes = tmp_path / "hostile_boxes.json"
    boxes.write_text(json.dumps([{**box, "label": "car"}]))
    proc = run_cli("complete", scan, "--boxes", boxes, "-o", tmp_path / "c.ply")
    clean_error(proc, "hostile_boxes.json", "box 0", what)


# ---------------------------------------------------------------------------- KITTI labels

BAD_LABELS = {
    "nan-rotation_y": ("Car 0 0 0 0 0 0 0 1.5 1.8 4.0 0 1.65 10 nan", "rotation_y"),
    "nan-w": ("Car 0 0 0 0 0 0 0 1.5 nan 4.0 0 1.65 10 0", "w"),
    "inf-h": ("Car 0 0 0 0 0 0 0 inf 1.8 4.0 0 1.65 10 0", "h"),
    "inf-x": ("Car 0.00 0 0 0 0 0 0 1.5 1.8 4.0 inf 1.65 10 0", "x"),
    "nan-z": ("Car 0.00 0 0 0 0 0 0 1.5 1.8 4.0 0 1.65 NaN 0", "z"),
    "nan-alpha": ("Car 0.00 0 nan 0 0 0 0 1.5 1.8 4.0 0 1.65 10 0", "alpha"),
    "huge-location": ("Car 0.00 0 0 0 0 0 0 1.5 1.8 4.0 1e300 1.65 10 0", "out of range"),
    "huge-dimensions": ("Car 0.00 0 0 0 0 0 0 1e308 1e308 1e308 0 1.65 10 0", "out of range"),
}


@pytest.mark.parametrize("name", sorted(BAD_LABELS))
def test_kitti_label_file_with_bad_numbers(tmp_path, kitti, name):
    line, fragment = BAD_LABELS[name]
    label = tmp_path / "label.txt"
    label.write_text(KITTI_GOOD + "\n" + line + "\n")
    calib = kitti / "calib" / "000000.txt"
    proc = run_cli(
        "complete", kitti / "velodyne" / "000000.bin", "--boxes", label, "--calib", calib, "-o", tmp_path / "c.ply"
    )
    clean_error(proc, "label.txt", "line 2", fragment)


@pytest.mark.parametrize("command", ["extract", "complete"])
def test_kitti_reader_with_nan_label(tmp_path, kitti, command):
    (kitti / "label_2" / "000000.txt").write_text(BAD_LABELS["nan-rotation_y"][0] + "\n")
    out = ["-o", tmp_path / "k.h5"] if command == "extract" else ["-o", tmp_path / "rc"]
    proc = run_cli("real", command, kitti, "--format", "kitti", *out, "-q")
    clean_error(proc, "000000.txt", "line 1", "rotation_y")


def test_kitti_reader_api_names_file_and_line(kitti):
    from spotlights.data.real.kitti import read_calib, read_labels, velo_from_rect

    label = kitti / "label_2" / "000000.txt"
    label.write_text(KITTI_GOOD + "\n\n" + BAD_LABELS["huge-location"][0] + "\n")
    t = velo_from_rect(read_calib(kitti / "calib" / "000000.txt"))
    with pytest.raises(InputFileError, match=r"000000\.txt: line 3: box centre .* out of range"):
        read_labels(label, t)


# ---------------------------------------------------------------------------- nuScenes, AV2


@pytest.mark.parametrize(
    "change, fragment",
    [({"translation": [1e300, 0.0, 0.0]}, "translation"), ({"size": [1e200, 1e200, 1.5]}, "size")],
)
def test_nuscenes_huge_annotation(tmp_path, change, fragment):
    write_mini_nuscenes(tmp_path / "ns")
    table = tmp_path / "ns" / "v1.0-mini" / "sample_annotation.json"
    rows = json.loads(table.read_text())
    rows[0].update(change)
    table.write_text(json.dumps(rows))
    proc = run_cli("real", "extract", tmp_path / "ns", "--format", "nuscenes", "-o", tmp_path / "o.h5", "-q")
    clean_error(proc, "sample_annotation.json", fragment, "out of range")


def _av2_log(root: Path, **change) -> Path:
    import pyarrow as pa
    import pyarrow.feather as feather

    log = root / "log"
    (log / "sensors" / "lidar").mkdir(parents=True)
    z = np.zeros(5, np.float32)
    feather.write_feather(pa.table({"x": z, "y": z, "z": z}), log / "sensors" / "lidar" / "100.feather")
    ann = dict(
        timestamp_ns=np.array([100, 100]),
        track_uuid=["a", "b"],
        category=["REGULAR_VEHICLE", "REGULAR_VEHICLE"],
        length_m=[4.0, 4.0],
        width_m=[1.8, 1.8],
        height_m=[1.5, 1.5],
        qw=[1.0, 1.0],
        qx=[0.0, 0.0],
        qy=[0.0, 0.0],
        qz=[0.0, 0.0],
        tx_m=[10.0, -10.0],
        ty_m=[0.0, 0.0],
        tz_m=[0.0, 0.0],
    )
    for k, v in change.items():
        ann[k] = [ann[k][0], v]
    feather.write_feather(pa.table({k: np.asarray(v) for k, v in ann.items()}), log / "annotations.feather")
    return log


@pytest.mark.parametrize(
    "change, fragment",
    [
        ({"qw": float("nan")}, "qw must be finite"),
        ({"tx_m": float("inf")}, "tx_m must be finite"),
        ({"qw": 0.0}, "quaternion (qw, qx, qy, qz) is zero"),
    ],
)
def test_av2_corrupt_annotation_numbers(tmp_path, change, fragment):
    pytest.importorskip("pyarrow")
    from spotlights.data.real import open_reader

    log = _av2_log(tmp_path, **change)
    with pytest.raises(InputFileError, match=r"annotations\.feather: row 1: ") as info:
        reader = open_reader(log, "av2")
        reader.load(reader.frame_keys()[0])
    assert fragment in str(info.value)


def test_av2_huge_annotation(tmp_path):
    pytest.importorskip("pyarrow")
    from spotlights.data.real import open_reader

    reader = open_reader(_av2_log(tmp_path, tx_m=1e300), "av2")
    with pytest.raises(InputFileError, match=r"annotations\.feather: row 1: box centre .* out of range"):
        reader.load(reader.frame_keys()[0])


# ---------------------------------------------------------------------------- meshes


def test_mesh_with_huge_vertices(tmp_path):
    mesh = tmp_path / "huge.obj"
    mesh.write_text("v 0 0 0\nv 1e300 0 0\nv 0 1e300 0\nv 0 0 1e300\nf 1 2 3\nf 1 3 4\nf 1 2 4\n")
    out = tmp_path / "x.npz"
    clean_error(run_cli("encode", mesh, "-o", out), "huge.obj", "out of range")
    assert not out.exists()


# ---------------------------------------------------------------------------- the Box itself


def test_box_refuses_what_is_not_a_rotation():
    for bad in (np.ones((3, 3)), np.diag([1.0, 1.0, -1.0]), np.zeros((3, 3)), 2 * np.eye(3), np.full((3, 3), 1e300)):
        with pytest.raises(ParameterError, match="box rotation"):
            Box([0, 0, 0], [4, 2, 1.5], bad)
    # a rotation from a file, rounded (float32) or a little off, is kept as it is
    for near in (rotation_z(0.4).astype(np.float32), rotation_z(1.0) + 2e-4):
        Box([0, 0, 0], [4, 2, 1.5], near)


def test_box_refuses_non_numbers_in_one_line():
    for kwargs in (
        dict(center="abc", size=[1, 1, 1]),
        dict(center=[0, 0, 0], size=["a", 1, 1]),
        dict(center=[0, 0, 0], size=[1, 1, 1], yaw="north"),
        dict(center=[0, 0, 0], size=[1, 1, 1], rotation=[["a"] * 3] * 3),
        dict(center=[0, 0, {}], size=[1, 1, 1]),
    ):
        with pytest.raises(ParameterError) as info:
            Box(**kwargs)
        assert "\n" not in str(info.value)


def test_box_bounds():
    Box([MAX_BOX_CENTER_M, -MAX_BOX_CENTER_M, 0], [MAX_BOX_SIZE_M] * 3)  # the bounds themselves are in range
    with pytest.raises(ParameterError, match="centre .* out of range"):
        Box([0, 0, -1.01 * MAX_BOX_CENTER_M], [4, 2, 1.5])
    with pytest.raises(ParameterError, match="size .* out of range"):
        Box([0, 0, 0], [4, 2, 1.01 * MAX_BOX_SIZE_M])
    assert box_range_problem([6.4e6, 4.2e6, 100.0], [4, 2, 1.5]) is None  # a georeferenced (UTM-like) box
    # non-finite numbers are refused (a degenerate box of zero sides is made, and skipped as "invalid_box")
    with pytest.raises(ParameterError, match="center must be finite"):
        Box([np.nan, 0, 0], [4, 2, 1.5])
    assert not Box([0, 0, 0], [4, 0, 1.5]).transformed(np.eye(4)).is_valid()
    with pytest.raises(InputFileError, match=r"b\.json: box 2 centre .* out of range"):
        box_from_dict({"center": [1e9, 0, 0], "size": [1, 1, 1], "yaw": 0}, "b.json", "box 2")


def test_orthonormalize_refuses_nan():
    with pytest.raises(ParameterError, match="NaN or infinite"):
        orthonormalize(np.full((3, 3), np.nan))
    np.testing.assert_allclose(orthonormalize(rotation_z(0.3) * 1.001), rotation_z(0.3), atol=1e-12)
    assert math.isclose(np.linalg.det(orthonormalize(np.diag([1.0, 1.0, -1.0]))), 1.0)
