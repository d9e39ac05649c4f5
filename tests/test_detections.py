"""Detections as input: the box score, nuScenes result JSON, KITTI results with scores, the generic JSON with scores,
the class map and the score filter, against hand-computed boxes; damaged files are one line naming the file."""

from __future__ import annotations

import json
import math
import pickle

import numpy as np
import pytest

from spotlights.errors import InputFileError, ParameterError
from spotlights.geometry.box_json import box_from_dict
from spotlights.geometry.boxes import Box
from spotlights.tracking.detections import (
    DetectionFrame,
    detector_class,
    filter_detections,
    read_detections,
    read_generic_detections,
    read_kitti_detections,
    read_nuscenes_detections,
)

from builders import quat_z, write_mini_nuscenes

# --- the box score ------------------------------------------------------------------------------------------


def test_box_score_is_optional_checked_and_kept():
    b = Box([1, 2, 3], [4, 2, 1.5], yaw=0.3)
    assert b.score is None and "score" not in b.to_dict()
    s = b.replace(score=0.25)
    assert s.score == 0.25 and s.to_dict()["score"] == 0.25
    assert pickle.loads(pickle.dumps(s)).score == 0.25
    assert s.flipped().score == 0.25 and s.transformed(np.eye(4)).score == 0.25
    for bad in (1.5, -0.1, float("nan"), float("inf"), "high"):
        with pytest.raises(ParameterError, match="score"):
            Box([0, 0, 0], [1, 1, 1], score=bad)
    assert box_from_dict({"center": [0, 0, 0], "size": [1, 1, 1], "yaw": 0, "score": 0.5}).score == 0.5
    assert box_from_dict({"center": [0, 0, 0], "size": [1, 1, 1], "yaw": 0}).score is None
    with pytest.raises(InputFileError, match="score must be a number in"):
        box_from_dict({"center": [0, 0, 0], "size": [1, 1, 1], "yaw": 0, "score": 2}, "f.json")


def test_class_map():
    assert detector_class("car") == "car" and detector_class("Car") == "car"
    assert detector_class("construction_vehicle") == "construction"
    assert detector_class("Van") == "caravan" and detector_class("Truck") == "truck"
    assert detector_class("bus") == "bus" and detector_class("trailer") == "trailer"
    for other in ("pedestrian", "Cyclist", "traffic_cone", "barrier", "bicycle", "DontCare", "zeppelin"):
        assert detector_class(other) is None


def test_filter_by_score_and_class():
    boxes = [
        Box([0, 0, 0], [4, 2, 1.5], label="car", cls="car", score=0.9),
        Box([5, 0, 0], [4, 2, 1.5], label="car", cls="car", score=0.1),
        Box([9, 0, 0], [0.5, 0.5, 1.7], label="pedestrian", cls=None, score=0.9),
        Box([9, 5, 0], [4, 2, 1.5], label="car", cls="car"),  # no score: counts as 1
    ]
    frames, counts = filter_detections([DetectionFrame("s", "0", 0.0, boxes)], min_score=0.5)
    assert [b.center[0] for b in frames[0].boxes] == [0, 9]
    assert counts == {"kept": 2, "low_score": 1, "other_class": 1}
    frames, counts = filter_detections([DetectionFrame("s", "0", 0.0, boxes)], 0.0, classes=None)
    assert counts["kept"] == 4
    with pytest.raises(ParameterError, match="min_score"):
        filter_detections([], 1.5)


# --- nuScenes ------------------------------------------------------------------------------------------------


def _nus_result(token: str, **over) -> dict:
    d = {
        "sample_token": token,
        "translation": [110.0, 201.0, 1.0],  # the mini folder's sensor sees it at (10, 0, -1)
        "size": [2.0, 4.0, 1.5],  # w, l, h
        "rotation": quat_z(30),
        "velocity": [0.0, 0.0],
        "detection_name": "car",
        "detection_score": 0.7,
        "attribute_name": "vehicle.moving",
    }
    d.update(over)
    return d


def test_nuscenes_results_in_the_sensor_frame(tmp_path):
    data = tmp_path / "nus"
    write_mini_nuscenes(data)
    res = {"smp0": [_nus_result("smp0"), _nus_result("smp0", detection_name="pedestrian", detection_score=0.2)]}
    path = tmp_path / "det.json"
    path.write_text(json.dumps({"meta": {}, "results": res}))
    frames = read_nuscenes_detections(path, data)
    assert [f.frame_id for f in frames] == ["smp0", "smp1"] and frames[1].boxes == []
    assert frames[0].sequence == "scene-0001" and frames[0].timestamp == pytest.approx(1000e-6)
    car, ped = frames[0].boxes
    np.testing.assert_allclose(car.center, [10.0, 0.0, -1.0], atol=1e-9)
    np.testing.assert_allclose(car.size, [4.0, 2.0, 1.5])  # (l, w, h)
    assert car.yaw == pytest.approx(math.radians(30))
    assert (car.label, car.cls, car.score, car.track_id) == ("car", "car", 0.7, "")
    assert (ped.cls, ped.score) == (None, 0.2)
    assert frames[0].sensor_to_world is not None and frames[0].scan_path.endswith("1000.pcd.bin")


def test_nuscenes_velocities_turn_with_the_boxes(tmp_path):
    """A result's global-frame velocity, in the sensor frame as its box is; none (no key, null, NaN, exactly 0):
    NaN rows."""
    data = tmp_path / "nus"
    write_mini_nuscenes(data)
    no_key = _nus_result("smp0")
    del no_key["velocity"]
    rows = [_nus_result("smp0", velocity=[3.0, -1.0]), _nus_result("smp0", velocity=[None, None]), no_key]
    rows.append(_nus_result("smp0", velocity=[float("nan"), float("nan")], detection_name="pedestrian"))
    rows.append(_nus_result("smp0", velocity=[0, 0]))  # what exporters write for a velocity they do not estimate
    path = tmp_path / "det.json"
    path.write_text(json.dumps({"meta": {}, "results": {"smp0": rows}}))
    frames = read_nuscenes_detections(path, data)
    f = frames[0]
    assert f.velocities.shape == (5, 3) and frames[1].velocities.shape == (0, 3)
    np.testing.assert_allclose(f.sensor_to_world[:3, :3] @ f.velocities[0], [3.0, -1.0, 0.0], atol=1e-9)
    assert np.isnan(f.velocities[1:]).all()
    kept, _ = filter_detections(frames)  # the pedestrian is left out, with its velocity
    assert len(kept[0].boxes) == 4 and kept[0].velocities.shape == (4, 3)
    np.testing.assert_allclose(kept[0].velocities[0], f.velocities[0])


@pytest.mark.parametrize(
    "doc, problem",
    [
        ({"results": []}, "not a nuScenes result file"),
        ({"results": {"other": [_nus_result("other")]}}, "no sample token"),
        ({"results": {"smp0": {}}}, "is not a list"),
        ({"results": {"smp0": [_nus_result("smp0", size=[2.0, 4.0])]}}, "size (w, l, h) must be 3"),
        ({"results": {"smp0": [_nus_result("smp0", size=[2.0, 0.0, 1.0])]}}, "must be positive"),
        ({"results": {"smp0": [_nus_result("smp0", rotation=[0, 0, 0, 0])]}}, "quaternion is zero"),
        ({"results": {"smp0": [_nus_result("smp0", detection_score=1.5)]}}, "outside [0, 1]"),
        ({"results": {"smp0": [_nus_result("smp0", detection_score="x")]}}, "detection_score must be a finite"),
        ({"results": {"smp0": [{"translation": [0, 0, 0]}]}}, "has no 'size'"),
        ({"results": {"smp0": [_nus_result("smp0", velocity=[1.0])]}}, "velocity must be [vx, vy]"),
        ({"results": {"smp0": [_nus_result("smp0", velocity=["a", 1.0])]}}, "velocity must be two numbers"),
        ({"results": {"smp0": [_nus_result("smp0", velocity=[1e6, 0.0])]}}, "velocity is out of range"),
    ],
)
def test_nuscenes_damaged_results(tmp_path, doc, problem):
    data = tmp_path / "nus"
    write_mini_nuscenes(data)
    path = tmp_path / "det.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputFileError) as err:
        read_nuscenes_detections(path, data)
    assert str(path) in str(err.value) and problem in str(err.value) and "\n" not in str(err.value)


def test_nuscenes_needs_its_folder(tmp_path):
    with pytest.raises(ParameterError, match="data"):
        read_detections(tmp_path / "x.json", "nuscenes")
    path = tmp_path / "det.json"
    path.write_text("{not json")
    write_mini_nuscenes(tmp_path / "nus")
    with pytest.raises(InputFileError, match="not valid JSON"):
        read_detections(path, "nuscenes", data=tmp_path / "nus")


# --- KITTI ---------------------------------------------------------------------------------------------------

#: KITTI's camera axes from the Velodyne's: x_cam = -y_velo, y_cam = -z_velo, z_cam = x_velo (no offset).
CALIB = "P0: 1 0 0 0 0 1 0 0 0 0 1 0\nR0_rect: 1 0 0 0 1 0 0 0 1\nTr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n"


def _label(kind="Car", x=1.0, y=2.0, z=10.0, ry=0.0, score=0.8, h=1.5, w=1.8, length=4.0) -> str:
    return f"{kind} 0 0 0 0 0 50 50 {h} {w} {length} {x} {y} {z} {ry} {score}"


def test_kitti_per_frame_files(tmp_path):
    (tmp_path / "det").mkdir()
    (tmp_path / "det" / "000000.txt").write_text(_label() + "\n" + _label("Pedestrian", score=0.3) + "\n")
    (tmp_path / "det" / "000002.txt").write_text(_label(ry=math.pi / 2) + "\n")
    (tmp_path / "calib.txt").write_text(CALIB)
    frames = read_kitti_detections(tmp_path / "det", tmp_path / "calib.txt")
    assert [(f.frame_id, f.timestamp) for f in frames] == [("000000", 0.0), ("000002", pytest.approx(0.2))]
    car = frames[0].boxes[0]
    # camera bottom centre (1, 2, 10), h 1.5: centre (1, 1.25, 10) in the camera = (10, -1, -1.25) in the Velodyne
    np.testing.assert_allclose(car.center, [10.0, -1.0, -1.25], atol=1e-12)
    np.testing.assert_allclose(car.size, [4.0, 1.8, 1.5])
    assert car.yaw == pytest.approx(-math.pi / 2)  # ry = 0: forward along the camera's x = the Velodyne's -y
    assert (car.cls, car.score) == ("car", 0.8)
    assert frames[0].boxes[1].cls is None
    assert abs(frames[1].boxes[0].yaw) == pytest.approx(math.pi)  # ry = pi/2: forward along the camera's -z


def test_kitti_tracking_file_and_logits(tmp_path):
    rows = [f"0 -1 {_label(score=2.0)}", f"3 -1 {_label('Van', score=-1.0)}", f"3 {_label(score=0.0)}"]
    (tmp_path / "0007.txt").write_text("\n".join(rows) + "\n")
    (tmp_path / "calib").mkdir()
    (tmp_path / "calib" / "0007.txt").write_text(
        CALIB.replace("R0_rect", "R_rect").replace("Tr_velo_to_cam", "Tr_velo_cam")
    )
    frames = read_kitti_detections(tmp_path / "0007.txt", tmp_path / "calib", logit_scores=True)
    assert [len(f.boxes) for f in frames] == [1, 0, 0, 2] and frames[3].frame_id == "000003"
    assert {f.sequence for f in frames} == {"0007"}
    assert frames[0].boxes[0].score == pytest.approx(1 / (1 + math.exp(-2.0)))
    assert frames[3].boxes[0].cls == "caravan" and frames[3].boxes[1].score == pytest.approx(0.5)
    with pytest.raises(InputFileError, match="outside"):
        read_kitti_detections(tmp_path / "0007.txt", tmp_path / "calib")


@pytest.mark.parametrize(
    "text, problem",
    [
        ("Car 0 0 0 0 0 50 50 1.5 1.8 4.0 1 2 10 0\n", "expected a type, 14 numbers and a score"),
        (_label(score=1.5) + "\n", "outside [0, 1]"),
        (_label(h=0.0) + "\n", "must be positive"),
        (_label().replace("10.0", "ten") + "\n", "non-numeric"),
        (_label().replace("10.0", "nan") + "\n", "finite"),
    ],
)
def test_kitti_damaged_files(tmp_path, text, problem):
    (tmp_path / "det").mkdir()
    bad = tmp_path / "det" / "000001.txt"
    bad.write_text(text)
    (tmp_path / "calib.txt").write_text(CALIB)
    with pytest.raises(InputFileError) as err:
        read_kitti_detections(tmp_path / "det", tmp_path / "calib.txt")
    assert str(bad) in str(err.value) and problem in str(err.value) and "\n" not in str(err.value)


def test_kitti_damaged_tracking_file_and_calib(tmp_path):
    (tmp_path / "calib.txt").write_text(CALIB)
    f = tmp_path / "seq.txt"
    f.write_text(f"x -1 {_label()}\n")
    with pytest.raises(InputFileError, match="frame must be a whole number"):
        read_kitti_detections(f, tmp_path / "calib.txt")
    f.write_text("0 -1 Car 1 2\n")
    with pytest.raises(InputFileError, match="expected 18 fields"):
        read_kitti_detections(f, tmp_path / "calib.txt")
    (tmp_path / "calib.txt").write_text("R0_rect: 1 0 0\n")
    f.write_text(f"0 -1 {_label()}\n")
    with pytest.raises(InputFileError, match="calib.txt"):
        read_kitti_detections(f, tmp_path / "calib.txt")
    with pytest.raises(ParameterError, match="calib"):
        read_detections(f, "kitti")


# --- generic -------------------------------------------------------------------------------------------------


def _box(x, score=None, label="car", **extra) -> dict:
    d = {"center": [x, 0.0, 0.0], "size": [4.0, 2.0, 1.5], "yaw": 0.0, "label": label, **extra}
    if score is not None:
        d["score"] = score
    return d


def test_generic_sequence_folder_and_file(tmp_path):
    seq = {
        "sequence": "a",
        "frames": [{"timestamp": 0.5, "boxes": [_box(1, 0.9)]}, {"timestamp": 0.0, "boxes": [_box(2)]}],
    }
    (tmp_path / "seq.json").write_text(json.dumps(seq))
    frames = read_generic_detections(tmp_path / "seq.json")
    assert [f.timestamp for f in frames] == [0.0, 0.5]  # time order
    assert frames[1].boxes[0].score == 0.9 and frames[0].boxes[0].score is None
    assert frames[1].boxes[0].cls == "car"
    (tmp_path / "d").mkdir()
    for k in (10, 2):
        (tmp_path / "d" / f"{k}.json").write_text(json.dumps({"frame_index": k, "boxes": [_box(k, 0.5)]}))
    frames = read_detections(tmp_path / "d", "generic")
    assert [(f.frame_id, f.timestamp) for f in frames] == [("2", pytest.approx(0.2)), ("10", pytest.approx(1.0))]
    (tmp_path / "one.json").write_text(json.dumps([_box(3, 0.4, label="bus")]))
    (f,) = read_detections(tmp_path / "one.json", "generic")
    assert f.boxes[0].cls == "bus" and f.boxes[0].score == 0.4


@pytest.mark.parametrize(
    "doc, problem",
    [
        ({"frames": [{"boxes": [_box(1, 1.5)]}]}, "score must be a number in [0, 1]"),
        ({"frames": [{"boxes": [_box(1, "x")]}]}, "score must be a number in [0, 1]"),
        ({"frames": [{"scan": "a.bin"}]}, "needs 'boxes'"),
        ({"frames": [{"boxes": [{"center": [0, 0, 0], "size": [1, 1, 1], "yaw": 0}]}]}, "has no 'label'"),
        ({"frames": [{"boxes": [_box(1)], "timestamp": 0}, {"boxes": [_box(1)]}]}, "mixes frames"),
        ({"frames": [{"boxes": "../../x.json"}]}, "leads outside"),
    ],
)
def test_generic_damaged_files(tmp_path, doc, problem):
    path = tmp_path / "seq.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputFileError) as err:
        read_generic_detections(path)
    assert str(path) in str(err.value) and problem in str(err.value) and "\n" not in str(err.value)


def test_caps_are_enforced(tmp_path, monkeypatch):
    import spotlights.tracking.detections as det

    monkeypatch.setattr(det, "MAX_BOXES_PER_FRAME", 2)
    path = tmp_path / "seq.json"
    path.write_text(json.dumps({"frames": [{"boxes": [_box(1), _box(2), _box(3)]}]}))
    with pytest.raises(InputFileError, match="3 boxes in one frame, more than the cap of 2"):
        read_generic_detections(path)


def test_generic_frames_at_one_time_are_the_files_error(tmp_path):
    """Two frames of a sequence at the same time cannot be tracked: the file's one line (not the tracker's)."""
    import json

    from spotlights.errors import InputFileError
    from spotlights.tracking.detections import read_detections

    box = {"center": [10.0, 0.0, 0.0], "size": [4.2, 1.8, 1.5], "yaw": 0.0, "label": "car", "score": 0.9}
    frames = [{"frame_id": f, "timestamp": 1.0, "boxes": [box]} for f in ("a", "b")]
    (tmp_path / "d.json").write_text(json.dumps({"frames": frames}))
    with pytest.raises(InputFileError, match=r"d\.json: sequence '': frames 'a' and 'b' share the time 1 s"):
        read_detections(tmp_path / "d.json", "generic")
