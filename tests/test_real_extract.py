"""Vehicle extraction: a synthetic scan with known boxes round-trips; skips are counted; HDF5 file."""

from __future__ import annotations

import hashlib
import json

import h5py
import numpy as np
import pytest

from spotlights.data.real import open_reader
from spotlights.data.real.extract import ExtractConfig, extract, read_observations, write_observations
from spotlights.errors import InputFileError, ParameterError

from builders import CENTER, SIZE, YAW, car_surface, make_scene


def test_synthetic_scan_round_trip(tmp_path):
    scan, car_obj = make_scene(tmp_path)
    obs = extract(open_reader(tmp_path / "scan.npy", "generic"), ExtractConfig(), progress=False)
    assert len(obs) == 1
    assert obs.cls == ["car"] and obs.label == ["Car"] and obs.track_id == ["a"]
    assert obs.n_points_raw[0] == len(car_obj)  # every car point, no ground point, no clutter
    r_box = 0.5 * np.linalg.norm(SIZE)
    unit = obs.partial[0].astype(np.float64)
    assert unit.shape == (256, 3)
    # unit frame = object frame / R: the points are the car's surface points
    obj = unit * r_box
    d = np.linalg.norm(obj[:, None] - car_obj[None], axis=2).min(axis=1)
    assert d.max() < 1e-5
    assert len(np.unique(np.round(unit, 6), axis=0)) == 256  # 500 -> 256: a subset without repeats
    # unit -> sensor transform brings them back onto the scan's points
    m = obs.unit_to_sensor[0]
    sensor = unit @ m[:3, :3].T + m[:3, 3]
    d = np.linalg.norm(sensor[:, None] - scan[None].astype(np.float64), axis=2).min(axis=1)
    assert d.max() < 1e-5
    np.testing.assert_allclose(obs.box_center[0], CENTER)
    np.testing.assert_allclose(obs.box_size[0], SIZE)
    assert obs.box_yaw[0] == pytest.approx(YAW)
    assert np.all(np.isnan(obs.sensor_to_world[0]))
    assert obs.meta["skipped"] == {
        "class_excluded": 1,
        "invalid_box": 1,
        "empty_box": 1,
        "too_few_points": 1,
        "duplicate_box": 0,
    }
    assert obs.meta["skipped_labels"] == {"Pedestrian": 1}
    assert obs.meta["n_boxes"] == 5


def test_ground_removed_and_margin(tmp_path):
    make_scene(tmp_path)
    # no ground cut (bottom plane 0.1 m below the box bottom): the ground points under the footprint come in
    loose = extract(
        open_reader(tmp_path / "scan.npy", "generic"), ExtractConfig(ground_clearance=-0.1, margin=0.01), progress=False
    )
    rng = np.random.default_rng(0)
    car_surface(rng, 500)  # replay the scene's generator up to the ground points
    g = np.c_[rng.uniform(-3, 3, (400, 2)), rng.uniform(-0.03, 0.03, 400) - SIZE[2] / 2]
    under = np.sum((np.abs(g[:, 0]) <= SIZE[0] / 2 + 0.01) & (np.abs(g[:, 1]) <= SIZE[1] / 2 + 0.01))
    assert under > 50
    assert loose.n_points_raw[0] == 500 + under


def test_resampling_deterministic_and_upsampling(tmp_path):
    make_scene(tmp_path, n_car=40)
    reader = open_reader(tmp_path / "scan.npy", "generic")
    a = extract(reader, ExtractConfig(seed=3), progress=False)
    b = extract(reader, ExtractConfig(seed=3), progress=False)
    c = extract(reader, ExtractConfig(seed=4), progress=False)
    np.testing.assert_array_equal(a.partial, b.partial)
    assert not np.array_equal(a.partial, c.partial)
    assert a.n_points_raw[0] == 40
    assert len(np.unique(a.partial[0], axis=0)) == 40  # all 40 points, plus 216 repeats


def test_min_points_threshold(tmp_path):
    make_scene(tmp_path)
    obs = extract(open_reader(tmp_path / "scan.npy", "generic"), ExtractConfig(min_points=5), progress=False)
    assert sorted(obs.cls) == ["car", "caravan"]  # the 5-point van now passes
    assert obs.meta["skipped"]["too_few_points"] == 0
    with pytest.raises(ParameterError):
        ExtractConfig(min_points=0)
    with pytest.raises(ParameterError):
        ExtractConfig(classes=("tram",))  # bus is a class since nuScenes; tram is none


def test_hdf5_schema_round_trip_and_bytes(tmp_path):
    make_scene(tmp_path)
    reader = open_reader(tmp_path / "scan.npy", "generic")
    obs = extract(reader, ExtractConfig(min_points=5), progress=False)
    p1, p2 = tmp_path / "a.h5", tmp_path / "b.h5"
    write_observations(p1, obs)
    write_observations(p2, extract(reader, ExtractConfig(min_points=5), progress=False))
    assert hashlib.sha256(p1.read_bytes()).digest() == hashlib.sha256(p2.read_bytes()).digest()
    with h5py.File(p1) as f:
        assert f.attrs["format"] == "spotlights-real-observations"
        assert json.loads(f.attrs["skipped_json"])["empty_box"] == 1
        g = f["observations"]
        assert g["partial"].shape == (2, 256, 3) and g["partial"].dtype == np.float32
        assert g["unit_to_sensor"].shape == (2, 4, 4)
        assert g["cls"].asstr()[()].tolist() == obs.cls
    back = read_observations(p1)
    np.testing.assert_array_equal(back.partial, obs.partial)
    np.testing.assert_array_equal(back.unit_to_sensor, obs.unit_to_sensor)
    assert back.track_id == obs.track_id and back.scan_path == obs.scan_path
    assert back.meta["config"]["min_points"] == 5
    assert not list(tmp_path.glob(".*part*"))  # no temporary left behind


def test_read_observations_rejects_other_files(tmp_path):
    bad = tmp_path / "x.h5"
    bad.write_text("hello")
    with pytest.raises(InputFileError, match="x.h5: not an HDF5 file"):
        read_observations(bad)
    with h5py.File(tmp_path / "y.h5", "w") as f:
        f.attrs["format"] = "spotlights-completion"
    with pytest.raises(InputFileError, match="y.h5: not a real-observation file"):
        read_observations(tmp_path / "y.h5")
    with pytest.raises(InputFileError, match="file not found"):
        read_observations(tmp_path / "none.h5")


def test_duplicate_annotations_are_scored_once(tmp_path):
    """The same car annotated twice (two track ids, one box) gives one observation, the same track in every frame."""
    make_scene(tmp_path)
    boxes = json.loads((tmp_path / "scan.json").read_text())
    twin = dict(boxes[0], track_id="0-twin")  # sorts before "a": the kept copy
    near = dict(boxes[0], center=(CENTER + [0.2, 0, 0]).tolist(), track_id="n")  # 0.2 m away: another box
    (tmp_path / "scan.json").write_text(json.dumps([boxes[0], twin, near]))
    obs = extract(open_reader(tmp_path / "scan.npy", "generic"), ExtractConfig(), progress=False)
    assert sorted(obs.track_id) == ["0-twin", "n"]
    assert obs.meta["skipped"]["duplicate_box"] == 1
    # order of the annotations does not change which copy is kept
    (tmp_path / "scan.json").write_text(json.dumps([twin, near, boxes[0]]))
    obs = extract(open_reader(tmp_path / "scan.npy", "generic"), ExtractConfig(), progress=False)
    assert sorted(obs.track_id) == ["0-twin", "n"] and obs.meta["skipped"]["duplicate_box"] == 1


def test_duplicate_boxes_chain_and_tolerance():
    from spotlights.data.real.base import Box
    from spotlights.data.real.extract import DUPLICATE_TOLERANCE_M, duplicate_boxes

    def car(x, tid, yaw=0.0):
        return Box.from_yaw([x, 0.0, 0.0], [4.0, 1.8, 1.5], yaw, "Car", "car", tid)

    # a chain 4 cm apart: b repeats a (kept), c is 8 cm from a, so it is another box
    assert duplicate_boxes([car(0.0, "a"), car(0.04, "b"), car(0.08, "c")]) == {1}
    # the kept copy is the smallest track id, wherever it is in the list
    assert duplicate_boxes([car(0.0, "z"), car(0.01, "m"), car(0.02, "q")]) == {0, 2}
    # just outside the tolerance, or turned by 90 degrees: not a duplicate
    assert duplicate_boxes([car(0.0, "a"), car(DUPLICATE_TOLERANCE_M + 0.01, "b")]) == set()
    assert duplicate_boxes([car(0.0, "a"), car(0.0, "b", yaw=np.pi / 2)]) == set()
    assert duplicate_boxes([car(0.0, "a")]) == set()
