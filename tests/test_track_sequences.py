"""Simulated drive-past sequences (spotlights.data.synthetic.sequences, ``dataset sequences``)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from spotlights.cli import main
from spotlights.data.lidar import sensor_preset
from spotlights.data.real import open_reader
from spotlights.data.synthetic.sequences import BoxNoise, SequenceSpec, simulate_sequence
from spotlights.errors import ParameterError

EXTENTS = (4.0, 1.8, 1.5)


@pytest.fixture
def box_mesh(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    mesh = trimesh.creation.box(extents=EXTENTS)
    path = tmp_path / "box.ply"
    mesh.export(path)
    return mesh, path


def test_sequence_geometry_and_noise_model(box_mesh):
    mesh, _ = box_mesh
    spec = SequenceSpec(n_frames=60, noise=BoxNoise(0.1, 2.0, 0.03))
    seq = simulate_sequence(
        np.asarray(mesh.vertices), np.asarray(mesh.faces), sensor_preset("hdl32e"), spec, np.random.default_rng(3)
    )
    frames = seq["frames"]
    assert [f["timestamp"] for f in frames] == pytest.approx([k / 10.0 for k in range(60)])
    traj = seq["trajectory"]
    centers = np.array([f["true_box"].center for f in frames])
    # straight line at the drawn lateral offset, the drawn speed, the box bottom on the ground (z = -1.84 + h/2)
    np.testing.assert_allclose(centers[:, 1], traj["lateral_m"], atol=1e-9)
    np.testing.assert_allclose(np.abs(np.diff(centers[:, 0])), traj["speed_mps"] / 10.0, rtol=1e-9)
    np.testing.assert_allclose(centers[:, 2], -1.84 + EXTENTS[2] / 2, atol=1e-9)
    for f in frames:
        tb = f["true_box"]
        np.testing.assert_allclose(tb.size, EXTENTS, atol=1e-9)
        assert f["points"].dtype == np.float32 and len(f["points"]) > 50
        # every return lies on the true box (range noise 2 cm along the ray)
        assert tb.contains(f["points"].astype(np.float64), margin=0.1).all()
    # the noisy boxes: centre and heading errors with the stated sigmas, heights kept
    d = np.array([f["noisy_box"].center - f["true_box"].center for f in frames])
    assert np.all(d[:, 2] == 0.0)
    assert 0.07 < d[:, :2].std() < 0.13
    dyaw = np.degrees([math.remainder(f["noisy_box"].yaw - f["true_box"].yaw, 2 * math.pi) for f in frames])
    assert 1.4 < dyaw.std() < 2.6
    rel = np.array([f["noisy_box"].size / f["true_box"].size - 1 for f in frames])
    assert 0.02 < rel.std() < 0.04
    with pytest.raises(ParameterError, match="box noise yaw_deg"):
        BoxNoise(0.1, -1.0, 0.0)


def test_dataset_sequences_same_seed_same_bytes_and_readable(box_mesh, tmp_path, capsys):
    _, path = box_mesh
    args = ["dataset", "sequences", "--meshes", str(path), "--sequences", "2", "--frames", "4", "--sensor", "hdl32e"]
    assert main([*args, "--out", str(tmp_path / "a"), "-q"]) == 0
    assert main([*args, "--out", str(tmp_path / "b"), "-q"]) == 0
    assert main([*args, "--out", str(tmp_path / "c"), "--seed", "1", "-q"]) == 0
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert len(files) == 2 * (4 + 3)
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    assert (tmp_path / "a" / "seq0000" / "0000.npy").read_bytes() != (
        tmp_path / "c" / "seq0000" / "0000.npy"
    ).read_bytes()
    # the generic reader takes the sequences: track id "0", the noisy box, times in seconds
    reader = open_reader(
        [tmp_path / "a" / "seq0000" / "sequence.json", tmp_path / "a" / "seq0001" / "sequence.json"], "generic"
    )
    keys = reader.frame_keys()
    assert len(keys) == 8 and {k[0] for k in keys} == {"seq0000", "seq0001"}
    truth = json.loads((tmp_path / "a" / "seq0000" / "truth.json").read_text())
    fr = reader.load(keys[1])
    assert fr.timestamp == pytest.approx(0.1) and fr.boxes[0].track_id == "0" and fr.boxes[0].cls == "car"
    np.testing.assert_allclose(fr.boxes[0].center, truth["frames"][1]["boxes"][0]["center"])
    assert truth["noise"] == {"translation_m": 0.1, "yaw_deg": 2.0, "size_rel": 0.03}
    gt = np.load(tmp_path / "a" / "seq0000" / "gt.npy")
    assert gt.shape == (2048, 3) and np.abs(gt).max(axis=0) == pytest.approx(np.array(EXTENTS) / 2, abs=1e-5)
    # a bad mesh path is one line, nothing written
    assert main(["dataset", "sequences", "--meshes", str(tmp_path / "none.ply"), "--out", str(tmp_path / "d")]) == 2
    assert "no such mesh file or folder" in capsys.readouterr().err and not (tmp_path / "d").exists()


def test_hdf5_sequences_same_bytes_for_any_worker_count(box_mesh, tmp_path):
    """One HDF5 file: the same bytes with 1 and 2 workers; read back, each frame's points lie on its true box,
    the noisy box differs from it, times are k / 10 s, the sensor origin is the scan's origin."""
    from spotlights.data.synthetic.sequences import read_sequences_h5

    _, path = box_mesh
    args = ["dataset", "sequences", "--meshes", str(path), "--sequences", "3", "--frames", "3", "--sensor", "hdl32e"]
    assert main([*args, "--out", str(tmp_path / "one.h5"), "--workers", "1", "-q"]) == 0
    assert main([*args, "--out", str(tmp_path / "two.h5"), "--workers", "2", "-q"]) == 0
    assert (tmp_path / "one.h5").read_bytes() == (tmp_path / "two.h5").read_bytes()
    seqs = read_sequences_h5(tmp_path / "two.h5")
    assert [s["track_id"] for s in seqs] == ["0", "1", "2"] and all(len(s["frames"]) == 3 for s in seqs)
    for s in seqs:
        assert s["gt"].shape == (2048, 3)
        for k, f in enumerate(s["frames"]):
            assert f["timestamp"] == pytest.approx(k / 10.0)
            assert len(f["points"]) > 10 and f["true_box"].contains(f["points"].astype(np.float64), margin=0.1).all()
            np.testing.assert_allclose(f["true_box"].size, EXTENTS, atol=1e-9)
            assert not np.allclose(f["noisy_box"].center, f["true_box"].center)
            assert np.array_equal(f["sensor_origin"], np.zeros(3))
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
