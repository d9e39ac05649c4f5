"""Hostile option values and paths found by a fuzzer, each answered in one line with exit code 2.

Absurd ``--threads`` (torch's OpenMP segfaulted at 100000), ``--device mps`` without an Apple GPU, an output that
is an input or another output (the scan, the box file, a per-object file), ``--max-gap`` NaN, negative or given
without ``--fuse``, and a FIFO given as the scan (the read blocked for ever).
"""

from __future__ import annotations

import json
import os
import threading

import numpy as np
import pytest

from spotlights.data.tracks import MAX_GAP_S
from spotlights.errors import InputFileError, ParameterError
from spotlights.options import MAX_THREADS, check_threads

from helpers import assert_user_error, run_cli, run_cli_subprocess, write_box_scan


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    """A scan (.npy) of a car-sized box's surface at x = 10 m, its box file (.json): {name: path}."""
    root = tmp_path_factory.mktemp("hostile")
    return write_box_scan(root)


def _complete(scan, *extra):
    return run_cli("complete", scan["scan"], "--box", scan["box"], *extra)


def _unchanged(scan):
    """The inputs are as the fixture wrote them."""
    assert np.load(scan["scan"]).shape == (600, 3)
    assert json.loads(scan["box"].read_text())["size"] == [4.0, 1.8, 1.5]


# ---------------------------------------------------------------------------- --threads


@pytest.mark.parametrize("n", ["100000", "20000", str(MAX_THREADS + 1)])
def test_complete_refuses_absurd_thread_counts(scan, tmp_path, n):
    proc = _complete(scan, "-o", tmp_path / "c.ply", "--threads", n)
    assert_user_error(proc, "--threads", f"1..{MAX_THREADS}")
    assert not (tmp_path / "c.ply").exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["real", "complete", "{root}", "--format", "generic", "--out", "{root}/r"],
        ["train", "--model", "sanet", "--data", "{root}/d.h5", "-o", "{root}/run"],
        ["evaluate", "--data", "{root}/d.h5", "--checkpoint", "x.pt"],
        ["bench", "models", "--models", "sanet"],
    ],
    ids=["real-complete", "train", "evaluate", "bench"],
)
def test_every_threads_option_is_bounded(scan, argv):
    proc = run_cli(*[a.format(root=scan["root"]) for a in argv], "--threads", "100000")
    assert_user_error(proc, "--threads", f"1..{MAX_THREADS}")


def test_the_bound_is_four_per_cpu_at_least_64():
    assert MAX_THREADS == max(64, 4 * (os.cpu_count() or 1))
    from spotlights.cli import build_parser

    args = build_parser().parse_args(["complete", "s.npy", "--box", "b.json", "-o", "c.ply", "--threads", "64"])
    assert args.threads == 64


def test_api_thread_counts_are_checked(scan, tmp_path):
    assert check_threads(None) is None and check_threads(8) == 8
    for bad in (0, -1, 100000, 2.5, True, "4"):
        with pytest.raises(ParameterError, match="threads"):
            check_threads(bad)
    from spotlights.completion.scan import CompletionOptions, ScanSettings, complete_scan

    with pytest.raises(ParameterError, match="`threads`"):
        CompletionOptions(threads=100000).load_completer()
    s = ScanSettings(input=str(scan["scan"]), box=str(scan["box"]), out=str(tmp_path / "c.ply"), threads=100000)
    with pytest.raises(ParameterError, match="`threads`"):
        complete_scan(s, completer=object())  # a model given: the count is checked all the same, before any work
    assert not (tmp_path / "c.ply").exists()


# ---------------------------------------------------------------------------- --device mps


def _mps_available() -> bool:
    import torch

    mps = getattr(torch.backends, "mps", None)
    return bool(mps is not None and mps.is_available())


@pytest.mark.skipif(_mps_available(), reason="this machine has an Apple GPU")
def test_mps_without_an_apple_gpu_is_one_line(scan, tmp_path):
    from spotlights.learning.device import resolve_device
    from spotlights.learning.runtime import load_completer

    for device in ("mps", "mps:0"):
        with pytest.raises(ParameterError, match=r"'mps.*not available.*available: cpu"):
            resolve_device(device)
    with pytest.raises(ParameterError, match="MPS"):
        load_completer(device="mps")
    proc = _complete(scan, "-o", tmp_path / "c.ply", "--device", "mps")
    assert_user_error(proc, "'mps'", "not available", "available: cpu")
    assert not (tmp_path / "c.ply").exists()


# ---------------------------------------------------------------------------- outputs that are inputs


def test_out_is_the_scan(scan):
    proc = _complete(scan, "-o", scan["scan"])
    assert_user_error(proc, "--out", "SCAN", str(scan["scan"]))
    _unchanged(scan)


def test_summary_is_the_box_file(scan, tmp_path):
    proc = _complete(scan, "-o", tmp_path / "c.ply", "--summary", scan["box"])
    assert_user_error(proc, "--summary", "--box")
    _unchanged(scan)
    assert not (tmp_path / "c.ply").exists()


def test_a_link_to_the_scan_is_the_scan(scan, tmp_path):
    link = tmp_path / "link.npy"
    link.symlink_to(scan["scan"])
    proc = _complete(scan, "-o", link)
    assert_user_error(proc, "--out", "SCAN")
    assert link.is_symlink()
    _unchanged(scan)


def test_out_among_the_per_object_files(scan, tmp_path):
    proc = _complete(scan, "-o", tmp_path / "objs" / "object_0.ply", "--per-object", tmp_path / "objs")
    assert_user_error(proc, "--out", "--per-object")
    assert not (tmp_path / "objs").exists()


def test_a_multi_frame_scene_is_not_written_into_its_own_folder(tmp_path):
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "0000.json").write_text("[]")
    proc = run_cli("complete", scene, "-o", scene)
    assert_user_error(proc, "--out", "SCAN")
    assert sorted(os.listdir(scene)) == ["0000.json"]


def test_decode_refuses_its_own_encoding_as_out(tmp_path):
    enc = tmp_path / "enc.npz"
    np.savez(enc, depths=np.ones((2, 2), np.float32))
    before = enc.read_bytes()
    proc = run_cli("decode", enc, "--out", enc)
    assert_user_error(proc, "--out", "FILE.npz")
    assert enc.read_bytes() == before


def test_distinct_outputs_still_work(scan, tmp_path):
    proc = _complete(scan, "-o", tmp_path / "c.ply", "--summary", tmp_path / "c.json", "--per-object", tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "c.json").exists() and (tmp_path / "object_0.ply").exists()


# ---------------------------------------------------------------------------- --max-gap


@pytest.mark.parametrize("value", ["nan", "-1", "0", "inf"])
@pytest.mark.parametrize("command", ["complete", "real"])
def test_max_gap_must_be_a_positive_number(scan, tmp_path, command, value):
    if command == "complete":
        argv = ["complete", scan["scan"], "--box", scan["box"], "-o", tmp_path / "c.ply"]
    else:
        argv = ["real", "complete", scan["root"], "--format", "generic", "-o", tmp_path / "r"]
    proc = run_cli(*argv, "--fuse", "all", "--max-gap", value)
    assert_user_error(proc, "--max-gap")
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("fuse", [[], ["--fuse", "none"]])
def test_max_gap_goes_with_fuse(scan, tmp_path, fuse):
    proc = _complete(scan, "-o", tmp_path / "c.ply", *fuse, "--max-gap", "1")
    assert_user_error(proc, "--max-gap", "--fuse")
    assert not (tmp_path / "c.ply").exists()


def test_max_gap_default_is_the_documented_one():
    from spotlights.cli import build_parser
    from spotlights.completion.scan import ScanSettings
    from spotlights.options import settings_from_namespace

    parser = build_parser()
    args = parser.parse_args(["complete", "scene", "-o", "out", "--fuse", "all"])
    assert settings_from_namespace(ScanSettings, args).max_gap == MAX_GAP_S
    args = parser.parse_args(["complete", "scene", "-o", "out", "--fuse", "all", "--max-gap", "0.5"])
    assert settings_from_namespace(ScanSettings, args).max_gap == 0.5


# ---------------------------------------------------------------------------- a FIFO as the scan


def test_a_fifo_scan_is_refused_not_waited_on(scan, tmp_path):
    fifo = tmp_path / "ff.npy"
    os.mkfifo(fifo)
    proc = run_cli_subprocess("complete", fifo, "--box", scan["box"], "-o", tmp_path / "c.ply", timeout=60)
    assert_user_error(proc, str(fifo), "not a regular file")
    assert not (tmp_path / "c.ply").exists()


def test_point_and_mesh_readers_refuse_a_fifo(tmp_path):
    from spotlights.geometry.io import load_mesh, load_points

    fifo = tmp_path / "ff.ply"
    os.mkfifo(fifo)
    errors = []

    def read_all():
        for load in (load_points, load_mesh):
            try:
                load(fifo)
            except InputFileError as exc:
                errors.append(str(exc))

    reader = threading.Thread(target=read_all, daemon=True)  # before the fix it blocked for ever in open()
    reader.start()
    reader.join(30)
    assert not reader.is_alive(), "reading a FIFO blocked"
    assert len(errors) == 2 and all("not a regular file" in e for e in errors), errors


@pytest.mark.parametrize("name", ["ff.bin", "ff.pcd.bin", "ff.feather"])
def test_sensor_scan_readers_refuse_a_fifo_and_say_so(tmp_path, name):
    """KITTI .bin, nuScenes .pcd.bin and AV2 feather scans (what the dataset readers read): a FIFO is "not a
    regular file" (before: "scan file not found" for a file that exists), one line naming it."""
    from spotlights.data.real.scans import read_scan

    fifo = tmp_path / name
    os.mkfifo(fifo)
    kind = {"ff.bin": "kitti", "ff.pcd.bin": "nuscenes", "ff.feather": "av2"}[name]
    with pytest.raises(InputFileError, match=r"ff\..*: not a regular file \(a FIFO, socket or device\)"):
        read_scan(fifo, kind)


def test_sensor_scan_readers_drop_rows_that_are_not_finite(tmp_path):
    """A KITTI .bin and a nuScenes .pcd.bin with NaN and infinite rows: the readers (every dataset reader reads
    through them) return the finite rows alone, in order (before: the NaN reached the frame loop and stopped it)."""
    from spotlights.data.real.scans import read_kitti_bin, read_nuscenes_bin

    rng = np.random.default_rng(0)
    xyz = rng.uniform(-20, 20, (50, 3)).astype(np.float32)
    xyz[[3, 17]] = [np.nan, 0, 0], [0, np.inf, 0]
    keep = np.ones(50, bool)
    keep[[3, 17]] = False
    kitti = np.c_[xyz, np.zeros(50, np.float32)]
    (tmp_path / "s.bin").write_bytes(kitti.astype("<f4").tobytes())
    nusc = np.c_[xyz, np.zeros(50, np.float32), rng.integers(0, 32, 50).astype(np.float32)]
    (tmp_path / "s.pcd.bin").write_bytes(nusc.astype("<f4").tobytes())
    for got in (read_kitti_bin(tmp_path / "s.bin"), read_nuscenes_bin(tmp_path / "s.pcd.bin")):
        np.testing.assert_array_equal(got, xyz[keep])
