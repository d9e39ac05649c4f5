"""The LiDAR origin of every real observation, in its box's unit frame: each reader on the shared data against a
hand computation, and the observation file's round trip (old files without the field read as NaN)."""

from __future__ import annotations

import json
from collections import Counter

import h5py
import numpy as np
import pytest

from spotlights.data.real import open_reader
from spotlights.data.real.extract import ExtractConfig, extract, extract_frame, read_observations, write_observations

from helpers import LIDAR, need

CFG = ExtractConfig(min_points=5)


def hand_origin(lidar_xyz, obs_row: dict) -> np.ndarray:
    """The LiDAR at ``lidar_xyz`` (sensor frame, metres) in the unit frame of a box: (p - centre) in the box's axes
    (the rotation's columns), divided by half the box diagonal."""
    rel = np.asarray(lidar_xyz, dtype=np.float64) - obs_row["box_center"]
    return rel @ obs_row["box_rotation"] / (0.5 * np.linalg.norm(obs_row["box_size"]))


def first_rows(reader, frames: int = 3) -> list[dict]:
    """The observations of the first frames that hold any (at most ``frames`` frames read)."""
    rows = []
    for key in reader.frame_keys()[:frames]:
        rows.extend(extract_frame(reader.load(key), CFG, Counter(), Counter()))
        if rows:
            return rows
    raise AssertionError("no vehicle in the first frames")


@pytest.mark.parametrize(
    ("folder", "fmt"), [("kitti-object/training", "kitti"), ("nuscenes", "nuscenes")], ids=["kitti", "nuscenes"]
)
def test_sensor_at_the_scan_origin(folder, fmt):
    """KITTI (Velodyne frame) and nuScenes (LIDAR_TOP frame): the LiDAR is the scan's origin."""
    reader = open_reader(need(LIDAR / folder), fmt)
    for row in first_rows(reader):
        assert np.allclose(row["sensor_origin"], hand_origin(np.zeros(3), row), atol=1e-9)
        # and it is where the box's normalisation puts the origin: unit_to_sensor maps it back to 0
        back = row["unit_to_sensor"] @ np.r_[row["sensor_origin"], 1.0]
        assert np.allclose(back[:3], 0.0, atol=1e-9)


def test_av2_sensor_is_the_up_lidar_of_the_calibration():
    """AV2 sweeps are in the ego frame: the LiDAR is up_lidar's translation in egovehicle_SE3_sensor.feather."""
    import pyarrow.feather as feather

    log = need(LIDAR / "argoverse2" / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede")
    calib = feather.read_table(log / "calibration" / "egovehicle_SE3_sensor.feather").to_pandas()
    up = calib[calib.sensor_name == "up_lidar"].iloc[0]
    lidar = np.array([up.tx_m, up.ty_m, up.tz_m], dtype=np.float64)
    assert 1.0 < lidar[2] < 2.5  # on the roof, not the ego origin
    for row in first_rows(open_reader(log, "av2")):
        assert np.allclose(row["sensor_origin"], hand_origin(lidar, row), atol=1e-9)


def test_av2_log_without_calibration_has_no_sensor_origin():
    log = need(LIDAR / "argoverse2" / "adcf7d18-0510-35b0-a2fa-b4cea13a6d76")
    if (log / "calibration").exists():
        pytest.skip("this log has a calibration")
    for row in first_rows(open_reader(log, "av2")):
        assert np.isnan(row["sensor_origin"]).all()


def test_generic_scan_and_the_file_round_trip(tmp_path):
    """Generic frames: the LiDAR at the scan's origin; observations write and read the field, and a file written
    before it reads as NaN rows."""
    rng = np.random.default_rng(0)
    centre, size, yaw = np.array([8.0, -3.0, -0.8]), np.array([4.4, 1.8, 1.5]), 0.7
    pts = centre + rng.uniform(-0.5, 0.5, (300, 3)) * size * 0.9
    np.save(tmp_path / "scan.npy", pts.astype(np.float32))
    box = {"center": centre.tolist(), "size": size.tolist(), "yaw": yaw, "label": "Car"}
    (tmp_path / "scan.json").write_text(json.dumps([box]))
    obs = extract(open_reader(tmp_path / "scan.npy", "generic"), CFG, progress=False)
    assert len(obs) == 1
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    want = (np.zeros(3) - centre) @ rot / (0.5 * np.linalg.norm(size))
    assert np.allclose(obs.sensor_origin[0], want, atol=1e-9)
    path = write_observations(tmp_path / "obs.h5", obs)
    assert np.array_equal(read_observations(path).sensor_origin, obs.sensor_origin)
    with h5py.File(path, "a") as f:  # a file of an earlier version
        del f["observations/sensor_origin"]
    old = read_observations(path)
    assert old.sensor_origin.shape == (1, 3) and np.isnan(old.sensor_origin).all()


@pytest.mark.timeout(300)
def test_real_complete_of_an_av2_log_without_calibration_uses_the_scan_origin_and_says_so(tmp_path):
    """`real complete` of the log without calibration completes its sweep (it used to stop at the NaN LiDAR place),
    says once that the place is unknown, and completes exactly as the same log with a calibration that puts
    up_lidar at the ego origin."""
    import pyarrow as pa
    import pyarrow.feather as feather

    from helpers import run_cli

    log = need(LIDAR / "argoverse2" / "adcf7d18-0510-35b0-a2fa-b4cea13a6d76")
    if (log / "calibration").exists():
        pytest.skip("this log has a calibration")
    calibrated = tmp_path / "calibrated" / log.name
    (calibrated / "sensors" / "lidar").mkdir(parents=True)
    for f in ("annotations.feather", "city_SE3_egovehicle.feather"):
        (calibrated / f).symlink_to(log / f)
    for sweep in (log / "sensors" / "lidar").glob("*.feather"):
        (calibrated / "sensors" / "lidar" / sweep.name).symlink_to(sweep)
    (calibrated / "calibration").mkdir()
    table = {"sensor_name": ["up_lidar"], "tx_m": [0.0], "ty_m": [0.0], "tz_m": [0.0]}
    feather.write_feather(pa.table(table), calibrated / "calibration" / "egovehicle_SE3_sensor.feather")

    outs = {}
    for name, src in (("unknown", log), ("origin", calibrated)):
        outs[name] = tmp_path / f"out-{name}"
        r = run_cli("real", "complete", str(src), "--format", "av2", "--no-pictures", "--out", str(outs[name]))
        assert r.returncode == 0, r.stderr
        said = r.stderr.count("the LiDAR's place is unknown")
        assert said == (1 if name == "unknown" else 0), r.stderr
    a, b = (sorted(outs[n].glob("*/*.json")) for n in ("unknown", "origin"))
    assert [p.name for p in a] == [p.name for p in b] and a
    for pa_, pb in zip(a, b):
        oa, ob = json.loads(pa_.read_text())["objects"], json.loads(pb.read_text())["objects"]
        assert sum(o["status"] == "completed" for o in oa) > 0
        assert [(o["status"], o["n_completion"], o["fidelity"]) for o in oa] == [
            (o["status"], o["n_completion"], o["fidelity"]) for o in ob
        ]
        assert pa_.with_suffix(".ply").read_bytes() == pb.with_suffix(".ply").read_bytes()
