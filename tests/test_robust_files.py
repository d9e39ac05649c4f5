"""Hostile and mistaken files: a LAS/LAZ file of random bytes, an .npz zip bomb, a huge cloud to draw, a broken link
in a scan folder, a dataset folder or a folder given where files go, timestamps in nanoseconds. Each is one line
(exit 2, or a typed error), fast and bounded in memory, whatever the bytes."""

from __future__ import annotations

import json
import os
import random
import resource
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from spotlights.errors import InputFileError, ParameterError

from helpers import assert_user_error, run_cli, src_pythonpath, write_box_scan

#: address space of the child that reads hostile files: far above what a 4 KB file needs, far below a runaway
CHILD_MEMORY_BYTES = 3 << 30


def _limited_memory():
    resource.setrlimit(resource.RLIMIT_AS, (CHILD_MEMORY_BYTES, CHILD_MEMORY_BYTES))


def _read_each_in_a_child(paths) -> list[str]:
    """One line per file from a child Python under a memory limit: the InputFileError's message or the shape read."""
    code = (
        "import sys\n"
        "from spotlights.errors import InputFileError\n"
        "from spotlights.geometry.io import load_points\n"
        "for p in sys.argv[1:]:\n"
        "    try:\n"
        "        print('read', load_points(p).shape, flush=True)\n"
        "    except InputFileError as exc:\n"
        "        print('error', str(exc).splitlines()[0], flush=True)\n"
    )
    env = dict(os.environ, PYTHONPATH=src_pythonpath())
    proc = subprocess.run(
        [sys.executable, "-c", code, *map(str, paths)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,  # generous: the runaway never ended (4.6 GB after 300 s); a bounded read takes well under 1 s
        preexec_fn=_limited_memory,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.splitlines()


@pytest.mark.timeout(400)
def test_las_and_laz_files_of_random_bytes_are_one_line_each(tmp_path):
    pytest.importorskip("laspy")
    paths = []
    for seed in range(12):
        r = random.Random(seed)
        p = tmp_path / f"garbage{seed}.{'laz' if seed % 2 else 'las'}"
        p.write_bytes(b"LASF" + bytes(r.getrandbits(8) for _ in range(4092)))
        paths.append(p)
    lines = _read_each_in_a_child(paths)
    assert len(lines) == len(paths), lines
    for p, line in zip(paths, lines):
        assert line.startswith(f"error {p}: ") and "not a readable LAS/LAZ file" in line, line


@pytest.mark.timeout(400)
def test_a_laz_header_declaring_a_billion_vlrs_is_refused_by_the_cli(tmp_path):
    pytest.importorskip("laspy")
    import struct

    head = bytearray(b"LASF" + bytes(223))
    head[24:26] = bytes([1, 2])  # LAS 1.2
    struct.pack_into("<HII", head, 94, 227, 4096, 1_000_000_000)  # header size, offset to points, VLR count
    struct.pack_into("<BH", head, 104, 3 | 0x80, 34)  # point format 3, compressed
    (tmp_path / "vlrs.laz").write_bytes(bytes(head) + bytes(4096 - 227))
    env_box = write_box_scan(tmp_path)
    proc = subprocess.run(
        [sys.executable, "-m", "spotlights", "complete", str(tmp_path / "vlrs.laz"), "--boxes", str(env_box["box"])]
        + ["--out", str(tmp_path / "c.ply")],
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONPATH=src_pythonpath(), MPLBACKEND="Agg"),
        timeout=300,
        preexec_fn=_limited_memory,
    )
    assert_user_error(proc, "vlrs.laz", "1,000,000,000 VLRs")
    assert not (tmp_path / "c.ply").exists()


def test_a_valid_laz_file_still_reads_its_points(tmp_path):
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [0.001] * 3
    las = laspy.LasData(header)
    xyz = np.random.default_rng(0).uniform(0, 10, size=(3000, 3)).round(3)
    las.x, las.y, las.z = xyz.T
    try:
        las.write(tmp_path / "ok.laz")
        path = tmp_path / "ok.laz"
    except Exception:  # noqa: BLE001 - no LAZ backend: the LAS file covers the reader
        las.write(tmp_path / "ok.las")
        path = tmp_path / "ok.las"
    from spotlights.geometry.io import load_points

    np.testing.assert_allclose(load_points(path), xyz, atol=1e-6)


def _npz_bomb(path, key: str, nbytes: int) -> None:
    """An .npz whose member ``key`` is a float64 .npy of ``nbytes`` of zeros, streamed: ~nbytes / 1000 on disk."""
    header = {"descr": "<f8", "fortran_order": False, "shape": (nbytes // 24, 3)}
    text = repr(header).encode("latin1")
    text += b" " * (63 - (10 + len(text)) % 64) + b"\n"
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        with zf.open(f"{key}.npy", "w", force_zip64=True) as fh:
            fh.write(b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text)
            block = bytes(1 << 20)
            for _ in range(nbytes >> 20):
                fh.write(block)


@pytest.mark.timeout(300)
def test_an_npz_zip_bomb_is_refused_from_its_directory(tmp_path):
    from spotlights.geometry.encode import load_encoding
    from spotlights.geometry.io import load_points

    bomb = tmp_path / "bomb.npz"
    _npz_bomb(bomb, "points", 256 << 20)
    assert bomb.stat().st_size < 2 << 20  # 256 MB of zeros in less than 2 MB
    with pytest.raises(InputFileError, match=r"bomb\.npz: member 'points\.npy' would unpack .* zip bomb"):
        load_points(bomb)
    enc = tmp_path / "enc.npz"
    _npz_bomb(enc, "depths", 256 << 20)
    with pytest.raises(InputFileError, match=r"enc\.npz: member 'depths\.npy' would unpack .* zip bomb"):
        load_encoding(enc)
    proc = run_cli("show", bomb, "--out", tmp_path / "b.png")
    assert_user_error(proc, "bomb.npz", "zip bomb")
    # an ordinary compressed cloud still reads
    pts = np.random.default_rng(0).normal(size=(1000, 3))
    np.savez_compressed(tmp_path / "ok.npz", points=pts)
    np.testing.assert_array_equal(load_points(tmp_path / "ok.npz"), pts)


def test_an_npz_that_is_no_zip_is_one_line(tmp_path):
    from spotlights.geometry.io import load_points

    (tmp_path / "x.npz").write_bytes(b"PK\x03\x04" + bytes(100))
    with pytest.raises(InputFileError, match=r"x\.npz: not a readable NPZ point cloud"):
        load_points(tmp_path / "x.npz")


def test_a_picture_draws_at_most_its_stated_points():
    from spotlights.viz.points import MAX_DRAWN_POINTS, Layer, figure_layers, thin_layers

    rng = np.random.default_rng(0)
    big, small = rng.normal(size=(300_000, 3)), rng.normal(size=(100_000, 3))
    values = np.arange(300_000, dtype=np.float64)
    thinned = thin_layers([Layer(big, values), Layer(small, "red"), Layer(np.zeros((0, 3)))], 200_000)
    # in proportion: 300k and 100k of 400k keep 150k and 50k rows, evenly spaced, first and last rows included
    assert [len(layer.points) for layer in thinned] == [150_000, 50_000, 0]
    np.testing.assert_array_equal(thinned[0].points[[0, -1]], big[[0, -1]])
    np.testing.assert_array_equal(
        thinned[0].color, thinned[0].points[:, 0] * 0 + np.linspace(0, 299_999, 150_000).astype(np.int64)
    )
    assert thin_layers([Layer(small)], 200_000)[0].points is small  # a cloud that fits is drawn whole
    fig = figure_layers([Layer(big), Layer(small, "red")])
    drawn = [len(c.get_offsets()) for ax in fig.axes for c in ax.collections]
    assert drawn and max(drawn) <= MAX_DRAWN_POINTS


def test_show_help_states_the_cap():
    proc = run_cli("show", "--help")
    assert "200000 points" in " ".join(proc.stdout.split())


def test_a_broken_link_in_a_scan_folder_is_reported(tmp_path):
    from spotlights.data.real import open_reader

    write_box_scan(tmp_path)
    os.symlink(tmp_path / "gone.npy", tmp_path / "frame2.npy")
    os.symlink(tmp_path / "gone.txt", tmp_path / "notes.md")  # not a scan name: still ignored
    with pytest.raises(InputFileError, match=r"frame2\.npy: a broken symbolic link") as info:
        open_reader(tmp_path, "generic")
    assert "\n" not in str(info.value)


def test_complete_of_a_nuscenes_folder_points_to_real_complete(tmp_path):
    root = tmp_path / "nuscenes"
    (root / "v1.0-mini").mkdir(parents=True)
    (root / "v1.0-mini" / "sample_annotation.json").write_text("[]")
    (root / "SOURCE.txt").write_text("where the data came from\n")
    proc = run_cli("complete", root, "--out", tmp_path / "out")
    assert_user_error(proc, "nuScenes folder", "real complete", "--format nuscenes")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "layout, fmt",
    [
        ("label_2", "kitti"),
        ("training/label_2", "kitti"),
        ("data_3d_raw", "kitti360"),
        ("samples/LIDAR_TOP", "nuscenes"),
    ],
)
def test_dataset_layouts_are_named(tmp_path, layout, fmt):
    from spotlights.data.real.generic import dataset_layout

    (tmp_path / layout).mkdir(parents=True)
    assert dataset_layout(tmp_path) == fmt
    assert dataset_layout(tmp_path / layout) is None or layout.startswith("training")


def test_view_and_show_of_a_folder_say_it_is_a_folder(tmp_path):
    pytest.importorskip("plotly")
    for proc in (
        run_cli("view", tmp_path, "--out", tmp_path / "v.html"),
        run_cli("show", tmp_path, "--out", tmp_path / "s.png"),
    ):
        assert_user_error(proc, str(tmp_path), "is a folder")
    assert not (tmp_path / "v.html").exists() and not (tmp_path / "s.png").exists()


def test_nanosecond_timestamps_get_a_hint_about_units():
    from spotlights.data.tracks import check_track

    t0 = 1_700_000_000_000_000_000
    with pytest.raises(ParameterError, match=r"look like nanoseconds \(divide them by 1e\+09"):
        check_track([t0 + k * 66_700_000 for k in range(5)])
    with pytest.raises(ParameterError, match="look like microseconds"):
        check_track([k * 100_000.0 for k in range(5)])
    with pytest.raises(ParameterError) as info:  # seconds with one real gap: no hint about units
        check_track([0.0, 0.1, 0.2, 5.0])
    assert "look like" not in str(info.value) and "gap of 4.8 s" in str(info.value)


def test_generic_sequence_in_nanoseconds_is_one_line_with_the_hint(tmp_path):
    """A sequence whose frames carry nanosecond timestamps (aiMotive's convention), fused per track."""
    rng = np.random.default_rng(0)
    frames = []
    for k in range(3):
        pts = rng.uniform([-2.0, -0.9, 0.0], [2.0, 0.9, 1.5], size=(400, 3)) + [10.0 + k * 0.5, 0.0, 0.0]
        np.save(tmp_path / f"f{k}.npy", pts.astype(np.float32))
        box = {"center": [10.0 + k * 0.5, 0.0, 0.75], "size": [4.0, 1.8, 1.5], "yaw": 0.0, "label": "car"}
        frames.append(
            {
                "scan": f"f{k}.npy",
                "timestamp": 1_700_000_000_000_000_000 + k * 100_000_000,
                "boxes": [dict(box, track_id="a")],
            }
        )
    (tmp_path / "seq.json").write_text(json.dumps({"sequence": "s", "frames": frames}))
    proc = run_cli("complete", tmp_path / "seq.json", "--fuse", "past:5", "--out", tmp_path / "out")
    assert_user_error(proc, "track a of s", "look like nanoseconds")
    assert not (tmp_path / "out").exists()
