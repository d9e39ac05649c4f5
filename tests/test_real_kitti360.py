"""KITTI-360 reader on small synthetic files written in the dataset's public format."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from spotlights.data.real import open_reader
from spotlights.data.real.extract import ExtractConfig, extract
from spotlights.errors import InputFileError

SEQ = "2013_05_28_drive_0000_sync"


def rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def rigid(r, t):
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


def opencv(tag, m):
    m = np.atleast_2d(m)
    data = " ".join(f"{v:.10f}" for v in m.ravel())
    return f'<{tag} type_id="opencv-matrix"><rows>{m.shape[0]}</rows><cols>{m.shape[1]}</cols><dt>f</dt><data>{data}</data></{tag}>'


UNIT_CUBE = np.array([[x, y, z] for x in (0.5, -0.5) for y in (0.5, -0.5) for z in (0.5, -0.5)])

# Calibration: camera 0 looks forward (z) with x right, y down; the IMU frame is x forward, y left, z up.
CAM_TO_POSE = rigid(np.array([[0, 0, 1.0], [-1, 0, 0], [0, -1, 0]]), [1.5, 0.0, 1.6])
CAM_TO_VELO = rigid(np.array([[0, 0, 1.0], [-1, 0, 0], [0, -1, 0]]), [0.3, 0.0, -0.1])  # same axes, offset
POSES = {
    0: rigid(rz(0.2), [1000.0, 2000.0, 100.0]),
    1: rigid(rz(0.25), [1001.0, 2000.5, 100.0]),
    3: rigid(rz(0.3), [1003.0, 2001.0, 100.0]),
}

# A parked car (static, frames 0-5): world transform = rotation (yaw 1.0) times scale (4.2, 1.8, 1.5).
CAR_T = rigid(rz(1.0) @ np.diag([4.2, 1.8, 1.5]), [1010.0, 2003.0, 100.5])
# A truck whose template has its length along local y (to test the axis ordering), dynamic (timestamp = frame).
TRUCK_T = {f: rigid(rz(0.5 + 0.01 * f) @ np.diag([2.5, 9.0, 3.4]), [1020.0 + f, 1995.0, 101.0]) for f in (0, 1)}


def world_corners(t):
    return UNIT_CUBE @ t[:3, :3].T + t[:3, 3]


def world_T_velo(f):
    return POSES[f] @ CAM_TO_POSE @ np.linalg.inv(CAM_TO_VELO)


def write_dataset(root: Path, n_car_pts: int = 60) -> None:
    objs = []
    objs.append(("car", 13, 7, 0, 5, -1, CAR_T))
    for f, t in TRUCK_T.items():
        objs.append(("truck", 14, 2, 0, 1, f, t))
    objs.append(("bicycle", 18, 1, 0, 5, -1, rigid(np.diag([1.8, 0.6, 1.2]), [1005.0, 2000.0, 100.6])))
    objs.append(("building", 11, 3, 0, 5, -1, rigid(np.diag([20.0, 10.0, 8.0]), [1100.0, 2100.0, 104.0])))
    parts = ['<?xml version="1.0"?>', "<opencv_storage>"]
    for k, (label, sem, inst, s, e, ts, t) in enumerate(objs):
        parts.append(
            f"<object{k + 1}><label>{label}</label><semanticId>{sem}</semanticId><instanceId>{inst}</instanceId>"
            f"<start_frame>{s}</start_frame><end_frame>{e}</end_frame><timestamp>{ts}</timestamp><dynamic>{int(ts >= 0)}</dynamic>"
            f"<index>{k}</index>{opencv('transform', t)}{opencv('vertices', UNIT_CUBE)}"
            f"{opencv('faces', np.zeros((12, 3)))}</object{k + 1}>"
        )
    parts.append("</opencv_storage>")
    (root / "data_3d_bboxes" / "train").mkdir(parents=True)
    (root / "data_3d_bboxes" / "train" / f"{SEQ}.xml").write_text("\n".join(parts))
    (root / "calibration").mkdir()
    (root / "calibration" / "calib_cam_to_pose.txt").write_text(
        "\n".join(f"image_0{i}: " + " ".join(f"{v:.9f}" for v in CAM_TO_POSE[:3].ravel()) for i in range(4)) + "\n"
    )
    (root / "calibration" / "calib_cam_to_velo.txt").write_text(
        " ".join(f"{v:.9f}" for v in CAM_TO_VELO[:3].ravel()) + "\n"
    )
    (root / "data_poses" / SEQ).mkdir(parents=True)
    (root / "data_poses" / SEQ / "poses.txt").write_text(
        "".join(f"{f} " + " ".join(f"{v:.9f}" for v in POSES[f][:3].ravel()) + "\n" for f in sorted(POSES))
    )
    data = root / "data_3d_raw" / SEQ / "velodyne_points" / "data"
    data.mkdir(parents=True)
    rng = np.random.default_rng(1)
    # points on the parked car, the same in every frame: uniform in the shrunk unit cube, mapped by its transform
    car = rng.uniform(-0.45, 0.45, (n_car_pts, 3)) @ CAR_T[:3, :3].T + CAR_T[:3, 3]
    for f in (0, 1, 2):  # frame 2 has no pose: left out
        world = [car]
        if f in TRUCK_T:
            world.append(rng.uniform(-0.45, 0.45, (200, 3)) @ TRUCK_T[f][:3, :3].T + TRUCK_T[f][:3, 3])
        world = np.concatenate(world)
        t = world_T_velo(f) if f in POSES else np.eye(4)
        velo = (world - t[:3, 3]) @ t[:3, :3]  # inverse rigid transform
        scan = np.concatenate([velo, np.ones((len(velo), 1))], axis=1).astype(np.float32)
        scan.tofile(data / f"{f:010d}.bin")


def same_corner_sets(a, b, atol):
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    return bool(np.all(d.min(1) <= atol) and np.all(d.min(0) <= atol))


def test_kitti360_boxes_in_velodyne_frame(tmp_path):
    write_dataset(tmp_path)
    reader = open_reader(tmp_path, "kitti360")
    assert reader.frame_keys() == [(SEQ, "0000000000"), (SEQ, "0000000001")]  # frame 2 has no pose
    for f in (0, 1):
        frame = reader.load((SEQ, f"{f:010d}"))
        np.testing.assert_allclose(frame.sensor_to_world, world_T_velo(f), atol=1e-9)
        boxes = {b.label: b for b in frame.boxes}
        assert set(boxes) == {"car", "truck", "bicycle"}  # the building is not read
        inv = np.linalg.inv(world_T_velo(f))
        for label, t in (("car", CAR_T), ("truck", TRUCK_T[f])):
            expect = world_corners(t) @ inv[:3, :3].T + inv[:3, 3]
            assert same_corner_sets(boxes[label].corners(), expect, 1e-6), label
        car, truck = boxes["car"], boxes["truck"]
        np.testing.assert_allclose(car.size, [4.2, 1.8, 1.5], atol=1e-9)
        np.testing.assert_allclose(truck.size, [9.0, 2.5, 3.4], atol=1e-9)  # length first, whatever the template axis
        assert np.linalg.det(truck.rotation) == pytest.approx(1.0)
        assert truck.rotation[2, 2] == pytest.approx(1.0)  # up is up
        assert car.track_id == "13-7" and truck.track_id == "14-2"
        assert car.cls == "car" and truck.cls == "truck" and boxes["bicycle"].cls is None


def test_kitti360_extraction_tracks_static_and_dynamic(tmp_path):
    write_dataset(tmp_path)
    obs = extract(open_reader(tmp_path, "kitti360"), ExtractConfig(margin=0.0, ground_clearance=-1.0), progress=False)
    assert sorted(zip(obs.track_id, obs.frame_id)) == [
        ("13-7", "0000000000"),
        ("13-7", "0000000001"),
        ("14-2", "0000000000"),
        ("14-2", "0000000001"),
    ]
    assert all(n in (60, 200) for n in obs.n_points_raw)
    # the static car's unit-frame partials in both frames are the same object points
    assert np.abs(obs.partial).max() <= 1.0 + 1e-6
    assert obs.meta["skipped_labels"] == {"bicycle": 2}
    # The parked car's points are the same world points in both frames (different poses):
    # in the car's unit frame they must coincide. 60 points -> 256 = all 60 plus repeats.
    rows = [i for i, t in enumerate(obs.track_id) if t == "13-7"]
    a, b = (np.unique(np.round(obs.partial[i], 4), axis=0) for i in rows)
    assert len(a) == len(b) == 60
    np.testing.assert_allclose(a, b, atol=2e-4)
    # and they are the generating points: uniform in [-0.45, 0.45] of the box extent, divided by R
    r = 0.5 * np.linalg.norm([4.2, 1.8, 1.5])
    assert np.all(np.abs(a * r) <= 0.45 * np.array([4.2, 1.8, 1.5]) + 1e-3)


def test_kitti360_frame_range_and_errors(tmp_path):
    write_dataset(tmp_path)
    assert open_reader(tmp_path, "kitti360", frames=(1, None, 1)).frame_keys() == [(SEQ, "0000000001")]
    (tmp_path / "calibration" / "calib_cam_to_velo.txt").write_text("1 2 3\n")
    with pytest.raises(InputFileError, match="calib_cam_to_velo.txt.*3 values"):
        open_reader(tmp_path, "kitti360")
    (tmp_path / "calibration" / "calib_cam_to_velo.txt").unlink()
    with pytest.raises(InputFileError, match="calib_cam_to_velo.txt: calibration file not found"):
        open_reader(tmp_path, "kitti360")


def test_kitti360_malformed_xml(tmp_path):
    write_dataset(tmp_path)
    xml = tmp_path / "data_3d_bboxes" / "train" / f"{SEQ}.xml"
    xml.write_text(xml.read_text().replace("<rows>4</rows>", "<rows>3</rows>", 1))
    with pytest.raises(InputFileError, match=r"\.xml: <object1> transform: 16 values for a 3x4 matrix"):
        open_reader(tmp_path, "kitti360")
    xml.write_text("<opencv_storage><object1>")
    with pytest.raises(InputFileError, match="not valid XML"):
        open_reader(tmp_path, "kitti360")
