"""Readers on the shared real data (skipped when absent) and their errors on malformed input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from spotlights.data.real import open_reader
from spotlights.data.real.extract import ExtractConfig, extract, points_in_box
from spotlights.errors import InputFileError

from helpers import LIDAR, need

AV2 = LIDAR / "argoverse2"
AV2_LOG = AV2 / "7fab2350-7eaf-3b7e-a39d-6937a4c1bede"
KITTI = LIDAR / "kitti-object"
needs_av2 = pytest.mark.skipif(not AV2_LOG.is_dir(), reason=f"shared data not found at {AV2_LOG}")
needs_kitti = pytest.mark.skipif(not KITTI.is_dir(), reason=f"shared data not found at {KITTI}")


@needs_av2
def test_av2_boxes_hold_exactly_the_annotated_points():
    """AV2 annotations carry num_interior_pts: our boxes (no margin, no ground cut) must count the same."""
    import pyarrow.feather as feather

    reader = open_reader(AV2, "av2")
    assert len(reader.frame_keys()) == 3  # two sweeps of one log, one of the other
    checked = 0
    for key in reader.frame_keys():
        frame = reader.load(key)
        ann = feather.read_table(frame.label_path).to_pandas()
        want = dict(zip(*(ann[ann.timestamp_ns == frame.timestamp][c] for c in ("track_uuid", "num_interior_pts"))))
        pts = frame.points.astype(np.float64)
        for box in frame.boxes:
            near = pts[np.sum((pts - box.center) ** 2, axis=1) <= (box.radius + 0.01) ** 2]
            assert int(points_in_box(near, box, 0.0, 0.0).sum()) == want[box.track_id]
            checked += 1
    assert checked == 209


@needs_av2
def test_av2_track_pairing():
    import pyarrow.feather as feather

    ann = feather.read_table(AV2_LOG / "annotations.feather").to_pandas()
    t0, t1 = sorted(int(p.stem) for p in (AV2_LOG / "sensors" / "lidar").glob("*.feather"))
    vehicle = {"REGULAR_VEHICLE", "BOX_TRUCK", "TRUCK", "TRUCK_CAB", "LARGE_VEHICLE", "VEHICULAR_TRAILER"}
    a0, a1 = ann[ann.timestamp_ns == t0], ann[ann.timestamp_ns == t1]
    both = set(a0[a0.category.isin(vehicle)].track_uuid) & set(a1[a1.category.isin(vehicle)].track_uuid)
    assert len(both) == 47  # the data README's count
    obs = extract(
        open_reader(AV2_LOG, "av2"), ExtractConfig(min_points=50, margin=0.0, ground_clearance=0.0), progress=False
    )
    from spotlights.metrics.consistency import consecutive_pairs

    pairs = consecutive_pairs(obs.object_keys(), obs.timestamp)
    # README: 16 vehicle tracks with >= 50 points in both sweeps; two of them are one car annotated
    # twice (two track uuids, the same cuboid in both sweeps): scored once
    assert obs.meta["skipped"]["duplicate_box"] == 2
    assert len(pairs) == 15
    for i, j in pairs:
        assert obs.track_id[i] == obs.track_id[j] and obs.track_id[i] in both
        assert (obs.timestamp[i], obs.timestamp[j]) == (t0, t1)
        # ego poses: the same object 0.1 s later is within 3 m in the city frame
        ci = obs.sensor_to_world[i] @ np.r_[obs.box_center[i], 1.0]
        cj = obs.sensor_to_world[j] @ np.r_[obs.box_center[j], 1.0]
        assert np.linalg.norm(ci - cj) < 3.0
    # the ego vehicle moved between the sweeps, so ego-frame centres alone would not line up as well
    ego_motion = np.linalg.norm(obs.sensor_to_world[pairs[0][0]][:3, 3] - obs.sensor_to_world[pairs[0][1]][:3, 3])
    assert ego_motion > 0.0


@needs_kitti
def test_kitti_shared_frames():
    reader = open_reader(KITTI / "training-fov-cropped", "kitti")
    assert reader.velodyne == "velodyne_reduced"
    frame = reader.load(("", "002155"))
    vehicles = [b for b in frame.boxes if b.cls is not None]
    assert len(vehicles) == 13  # the data README: 002155 has 13 vehicles
    assert {b.cls for b in vehicles} == {"car", "caravan"}
    obs = extract(reader, progress=False)
    sk = obs.meta["skipped"]
    assert len(obs) + sum(sk.values()) == obs.meta["n_boxes"]
    # parent folder with training/ inside works too
    assert open_reader(KITTI, "kitti").root.endswith("training")


# ---- malformed input -------------------------------------------------------------------------


def kitti_copy(tmp_path) -> Path:
    need(KITTI)
    dst = tmp_path / "training"
    shutil.copytree(KITTI / "training", dst)
    for p in dst.rglob("*"):
        p.chmod(0o644 if p.is_file() else 0o755)
    return dst


def test_kitti_malformed_label_line(tmp_path):
    root = kitti_copy(tmp_path)
    lab = root / "label_2" / "000001.txt"
    lines = lab.read_text().splitlines()
    lines[1] = "Car 0.00 0 1.85 387.63 181.54 423.81 203.12 1.67 1.87 3.69"
    lab.write_text("\n".join(lines) + "\n")
    reader = open_reader(root, "kitti")
    with pytest.raises(InputFileError, match=r"label_2/000001.txt: line 2: expected 15 or 16 fields.*got 11"):
        reader.load(("", "000001"))
    lines[1] = "Car 0.00 0 1.85 387.63 181.54 423.81 203.12 1.67 1.87 x -16.53 2.39 58.49 1.57"
    lab.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputFileError, match="line 2: non-numeric field"):
        reader.load(("", "000001"))


def test_kitti_missing_calib_and_scan(tmp_path):
    root = kitti_copy(tmp_path)
    (root / "calib" / "000002.txt").unlink()
    with pytest.raises(InputFileError, match=r"calib/000002.txt: calibration file not found"):
        open_reader(root, "kitti")
    root2 = kitti_copy(tmp_path / "b")
    (root2 / "velodyne" / "000000.bin").unlink()
    with pytest.raises(InputFileError, match=r"velodyne/000000.bin: scan file not found"):
        open_reader(root2, "kitti")
    root3 = kitti_copy(tmp_path / "c")
    (root3 / "calib" / "000000.txt").write_text("P0: 1 2 3\n")
    with pytest.raises(InputFileError, match="calib/000000.txt: missing R0_rect"):
        open_reader(root3, "kitti").load(("", "000000"))
    (root3 / "velodyne" / "000001.bin").write_bytes(b"\0" * 10)
    with pytest.raises(InputFileError, match="000001.bin: size 10 bytes is not a multiple of 16"):
        open_reader(root3, "kitti").load(("", "000001"))


def test_not_a_dataset_folder(tmp_path):
    with pytest.raises(InputFileError, match="not a folder"):
        open_reader(tmp_path / "nope", "kitti")
    with pytest.raises(InputFileError, match="no label_2/"):
        open_reader(tmp_path, "kitti")
    with pytest.raises(InputFileError, match="not an Argoverse 2 folder"):
        open_reader(tmp_path, "av2")
    with pytest.raises(InputFileError, match="no data_3d_raw/"):
        open_reader(tmp_path, "kitti360")


def test_av2_missing_column(tmp_path):
    import pyarrow as pa
    import pyarrow.feather as feather

    log = tmp_path / "log"
    (log / "sensors" / "lidar").mkdir(parents=True)
    feather.write_feather(
        pa.table({"x": np.zeros(3, np.float32), "y": np.zeros(3, np.float32), "z": np.zeros(3, np.float32)}),
        log / "sensors" / "lidar" / "100.feather",
    )
    feather.write_feather(pa.table({"timestamp_ns": np.array([100]), "track_uuid": ["t"]}), log / "annotations.feather")
    with pytest.raises(InputFileError, match=r"annotations.feather: annotations lacks column\(s\) category"):
        open_reader(log, "av2")


def test_generic_malformed_boxes(tmp_path):
    np.save(tmp_path / "s.npy", np.zeros((10, 3), np.float32))
    cases = [
        ("not json", "not valid JSON"),
        (json.dumps({"a": 1}), "expected a JSON list of boxes"),
        (json.dumps([{"center": [0, 0, 0], "label": "car", "yaw": 0}]), "box 0 has no 'size'"),
        (
            json.dumps([{"center": [0, 0], "size": [1, 1, 1], "label": "car", "yaw": 0}]),
            r"box 0 center must be three finite numbers, got shape \(2,\)",
        ),
        (json.dumps([{"center": [0, 0, 0], "size": [1, 1, 1], "label": "car"}]), "needs 'yaw' or 'rotation'"),
        (
            json.dumps(
                [
                    {
                        "center": [0, 0, 0],
                        "size": [1, 1, 1],
                        "label": "car",
                        "rotation": [[2, 0, 0], [0, 1, 0], [0, 0, 1]],
                    }
                ]
            ),
            "not a proper rotation",
        ),
    ]
    for text, msg in cases:
        (tmp_path / "s.json").write_text(text)
        with pytest.raises(InputFileError, match=msg):
            open_reader(tmp_path / "s.npy", "generic")
