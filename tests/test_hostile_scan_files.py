"""Hostile files: scans, PLY headers, encodings, box files and checkpoints that hold no valid data, each answered
with one line naming the file (never a traceback, never a silently wrong run)."""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.errors import InputFileError
from spotlights.geometry.encode import load_encoding
from spotlights.geometry.io import load_ply_fields, load_points, ply_has_faces, ply_is_whole, save_ply

from helpers import assert_user_error, run_cli


def _encoding(**changes) -> dict:
    """The arrays of a valid 4 x 8 cap encoding (written without the ``rig`` key: the old layout), then ``changes``
    (a value None removes the key)."""
    arrays = {
        "depths": np.full(32, 0.5, np.float32),
        "center": np.zeros(3),
        "radius": np.float64(2.0),
        "rotation": np.eye(3),
        "primary": np.int64(4),
        "secondary": np.int64(8),
        "angle": np.float64(60.0),
    }
    arrays.update(changes)
    return {k: v for k, v in arrays.items() if v is not None}


@pytest.mark.parametrize(
    "array",
    [
        np.array([["a", "b", "c"]] * 20),  # text
        np.array([[1 + 2j, 0, 0]] * 20),  # complex: the imaginary part was dropped with a ComplexWarning
        np.ones((20, 3), dtype=bool),
        np.array([["2020-01-01"] * 3] * 20, dtype="datetime64[D]"),
        np.zeros(20, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]),  # records: 1-D of a void dtype
    ],
)
def test_scan_arrays_of_no_real_numbers_are_refused(tmp_path, array):
    path = tmp_path / "scan.npy"
    np.save(path, array)
    with pytest.raises(InputFileError, match="scan.npy.*(real numbers|expected)"):
        load_points(path)


def test_integer_and_float_scans_still_read(tmp_path):
    for dtype in (np.int16, np.float32, np.float64):
        path = tmp_path / f"scan_{np.dtype(dtype).name}.npy"
        np.save(path, (np.arange(60).reshape(20, 3) % 7).astype(dtype))
        pts = load_points(path)
        assert pts.dtype == np.float64 and pts.shape == (20, 3) and pts[3, 0] == 9 % 7


def test_checkpoint_with_nan_weights_or_a_bad_threshold_is_refused(tmp_path):
    """A diverged run's checkpoint (NaN weights) passed ``export`` and ``evaluate`` with NaN everywhere; a p(hit)
    threshold of NaN or 2 made ``complete`` say every ray was clipped. Both are now the file's one-line error."""
    torch = pytest.importorskip("torch")
    from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint, save_checkpoint

    from learning_fixtures import make_checkpoint

    path = make_checkpoint(tmp_path / "ok.pt", "sanet-hit")
    ckpt = load_checkpoint(path)
    model_from_checkpoint(ckpt)  # the valid file loads
    state = {k: v.clone() for k, v in ckpt["model_state"].items()}
    first = next(k for k, v in state.items() if v.is_floating_point())
    state[first].view(-1)[0] = float("nan")
    bad = save_checkpoint(tmp_path / "nan.pt", {**ckpt, "model_state": state})
    with pytest.raises(InputFileError, match="nan.pt.*NaN or infinite"):
        model_from_checkpoint(load_checkpoint(bad))
    for value in (float("nan"), 2.0):
        odd = save_checkpoint(tmp_path / "thr.pt", {**ckpt, "hit_threshold": value})
        with pytest.raises(InputFileError, match="threshold"):
            model_from_checkpoint(load_checkpoint(odd))
    assert torch.isfinite(ckpt["model_state"][first]).all()


@pytest.mark.timeout(60)
def test_ply_is_whole_counts_the_bytes_its_header_declares(tmp_path):
    """Independent truth: a binary PLY of K vertices with float32 x, y, z and a uchar holds header + 13 K bytes."""
    path = tmp_path / "frame.ply"
    save_ply(path, np.arange(30.0).reshape(10, 3), {"source": np.ones(10, np.uint8)})
    data = path.read_bytes()
    header = data.index(b"end_header\n") + len(b"end_header\n")
    assert len(data) == header + 10 * 13
    assert ply_is_whole(path)
    for cut in (1, 13, 10 * 13):  # a row's last byte, a whole row, every row
        path.write_bytes(data[:-cut])
        assert not ply_is_whole(path), cut
    path.write_bytes(data + b"\0")
    assert not ply_is_whole(path)
    path.write_bytes(data[: header - 3])  # the header itself cut
    assert not ply_is_whole(path)
    path.unlink()
    assert not ply_is_whole(path)
    save_ply(path, np.zeros((0, 3)))  # an empty frame's cloud is whole
    assert ply_is_whole(path)


@pytest.mark.timeout(60)
def test_ply_is_whole_reads_a_long_header_and_a_comment_that_names_end_header(tmp_path):
    """A busy frame's PLY has a header of many comment lines: over 64 KiB it was judged cut short (and completed
    again by every --resume); a comment holding the word end_header was taken for the header's end."""
    path = tmp_path / "busy.ply"
    comments = ["a comment that holds end_header inside"] + [f"object {k}: car, 4.5 x 1.8 x 1.5 m" for k in range(3000)]
    save_ply(path, np.arange(30.0).reshape(10, 3), {"source": np.ones(10, np.uint8)}, comments=comments)
    data = path.read_bytes()
    header = data.index(b"\nend_header\n") + len(b"\nend_header\n")
    assert header > 65536 and len(data) == header + 10 * 13  # independent truth: the bytes the header declares
    assert ply_is_whole(path)
    assert len(load_ply_fields(path)["x"]) == 10  # a reader that splits at the first end_header reads it too
    assert data.count(b"end_header") == 1 and b"holds end-header inside" in data
    path.write_bytes(data[:-1])
    assert not ply_is_whole(path)
    path.write_bytes(data[: header - 1])  # cut inside the header's last line
    assert not ply_is_whole(path)


@pytest.mark.timeout(60)
def test_ply_has_faces_reads_the_header_up_to_its_own_end(tmp_path):
    path = tmp_path / "mesh.ply"
    head = "ply\nformat ascii 1.0\ncomment end_header in a comment\nelement vertex 3\nproperty float x\n"
    head += "property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
    path.write_text(head + "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    assert ply_has_faces(path)
    path.write_text(head.replace("element face 1", "element face 0") + "end_header\n0 0 0\n1 0 0\n0 1 0\n")
    assert not ply_has_faces(path)
    save_ply(path, np.zeros((2, 3)), comments=["element face 5"])  # a comment is not the header's element line
    assert not ply_has_faces(path)


@pytest.mark.timeout(60)
def test_ply_is_whole_reads_other_plys_whole(tmp_path):
    path = tmp_path / "ascii.ply"
    head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    path.write_text(head + "0 0 0\n1 1 1\n2 2 2\n")
    assert ply_is_whole(path)
    path.write_text(head + "0 0 0\n1 1 1\n")
    assert not ply_is_whole(path)


@pytest.mark.timeout(60)
def test_a_truncated_checkpoint_or_an_onnx_file_is_named_as_such(tmp_path):
    from spotlights.errors import InputFileError
    from spotlights.learning.checkpoint import PRETRAINED, load_checkpoint, resolve_checkpoint

    data = resolve_checkpoint("paper").read_bytes()
    assert "paper" in PRETRAINED
    cut = tmp_path / "last.pt"
    for n in (0, 100, len(data) - 10):
        cut.write_bytes(data[:n])
        with pytest.raises(InputFileError, match="last.pt: truncated \\(its end is missing\\)") as err:
            load_checkpoint(cut)
        assert "internal" not in str(err.value)
    onnx = tmp_path / "m.onnx"
    onnx.write_bytes(b"\x08\x07onnx")
    with pytest.raises(InputFileError, match="m.onnx: is an ONNX model: .*--runtime onnx"):
        load_checkpoint(onnx)


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    "changes, message",
    [
        ({}, None),  # the valid one reads
        ({"depths": np.array(["a"] * 32)}, "depths holds <U1 values, expected real numbers"),
        ({"depths": np.ones(32, bool)}, "depths holds bool values"),
        ({"depths": np.full(32, 0.5 + 0j, np.complex64)}, "depths holds complex64 values"),
        ({"radius": np.ones(5)}, "radius must be a real number, got a float64 array of shape (5,)"),
        ({"primary": np.arange(3)}, "primary must be a whole number"),
        ({"primary": np.float64(4.7)}, "primary must be a whole number"),
        ({"angle": np.str_("sixty")}, "angle must be a real number"),
        ({"rotation": np.eye(2)}, "invalid rig or normalisation"),
        ({"rig": np.str_("[1, 2]")}, "invalid rig or normalisation"),
    ],
)
def test_an_encoding_with_wrong_arrays_is_the_files_one_line_error(tmp_path, changes, message):
    """These were TypeErrors and ValueErrors from deep in the reader (exit 1, a traceback) in decode, show and view."""
    path = tmp_path / "e.npz"
    np.savez(path, **_encoding(**changes))
    if message is None:
        enc = load_encoding(path)
        assert enc.rig.n_rays == 32 and float(enc.depths[0]) == 0.5
        return
    with pytest.raises(InputFileError) as err:
        load_encoding(path)
    assert message in str(err.value) and str(err.value).startswith(str(path)), str(err.value)
    proc = run_cli("decode", path, "--out", tmp_path / "p.ply")
    assert_user_error(proc, message)
    assert not (tmp_path / "p.ply").exists()


@pytest.mark.timeout(60)
def test_a_box_file_with_an_integer_beyond_64_bits_is_one_line(tmp_path):
    """``"center": [10**400, 0, 0]`` in a generic box file was an OverflowError traceback (float64 cannot hold it)."""
    boxes = tmp_path / "boxes.json"
    boxes.write_text('[{"center": [1' + "0" * 400 + ', 0, 0], "size": [4, 2, 1.5], "yaw": 0, "label": "car"}]')
    np.save(tmp_path / "scan.npy", np.zeros((10, 3), np.float32))
    proc = run_cli("complete", tmp_path / "scan.npy", "--box", boxes, "--out", tmp_path / "c.ply", "-q")
    assert_user_error(proc, f"{boxes}: holds an integer beyond 64 bits")
    assert not (tmp_path / "c.ply").exists()
