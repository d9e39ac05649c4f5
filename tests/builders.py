"""Scenes, drives and datasets that several test modules build (no test module imports another)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import trimesh

from spotlights.completion.fusion import TrackPlan
from spotlights.completion.scene_config import SceneConfig
from spotlights.data.real import open_reader
from spotlights.data.real.extract import ExtractConfig, extract
from spotlights.data.synthetic import BuildConfig, build_dataset
from spotlights.data.tracks import TrackFrame, parse_window
from spotlights.geometry.boxes import Box

BOX_YAW = math.radians(30.0)


CENTER_S = np.array([10.0, 0.0, -1.0])  # the box centre in the sensor frame, by construction below


LWH = np.array([4.0, 2.0, 1.5])


def quat_z(deg: float) -> list[float]:
    """Scalar-first quaternion (w, x, y, z) of a rotation by ``deg`` degrees about +z."""
    h = math.radians(deg) / 2
    return [math.cos(h), 0.0, 0.0, math.sin(h)]


def rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def write_mini_nuscenes(root: Path, break_table: str | None = None) -> dict:
    """A two-keyframe nuScenes folder in the release layout with one car, one bicycle and one truck.

    Ego pose: yaw 90 degrees at (100, 200, 0); LIDAR_TOP mounted at (1, 0, 2) in the ego frame, turned
    by -90 degrees (as the real sensor: x right, y forward). So global <- sensor has no rotation and the
    sensor sits at (100, 201, 2): a global point (110, 201, 1) is (10, 0, -1) in the sensor frame.
    """
    tables = root / "v1.0-mini"
    (root / "samples" / "LIDAR_TOP").mkdir(parents=True)
    tables.mkdir()
    rng = np.random.default_rng(0)
    r = rz(BOX_YAW)
    inside_obj = rng.uniform(-0.95, 0.95, (120, 3)) * (LWH / 2)
    outside_obj = np.array([[2.3, 0, 0], [0, 1.2, 0], [0, 0, 0.9], [-2.1, 0.5, 0.0], [1.0, -1.1, 0.2]])
    clutter = rng.uniform(-40, 40, (300, 3)) * [1, 1, 0] + [0, 0, -1.9] + [0, 30, 0]
    pts = np.concatenate([inside_obj @ r.T + CENTER_S, outside_obj @ r.T + CENTER_S, clutter])
    files = []
    for k in range(2):
        data = np.c_[pts + [0.1 * k, 0, 0], rng.uniform(0, 100, len(pts)), rng.integers(0, 32, len(pts))].astype("<f4")
        name = f"samples/LIDAR_TOP/n000__LIDAR_TOP__{1000 + k}.pcd.bin"
        data.tofile(root / name)
        files.append(name)
    t = {
        "sensor": [
            {"token": "s-lidar", "channel": "LIDAR_TOP", "modality": "lidar"},
            {"token": "s-cam", "channel": "CAM_FRONT", "modality": "camera"},
        ],
        "calibrated_sensor": [
            {"token": "cs-lidar", "sensor_token": "s-lidar", "translation": [1.0, 0.0, 2.0], "rotation": quat_z(-90)},
            {
                "token": "cs-cam",
                "sensor_token": "s-cam",
                "translation": [1.5, 0.0, 1.5],
                "rotation": [0.5, -0.5, 0.5, -0.5],
            },
        ],
        "ego_pose": [
            {
                "token": f"e{k}",
                "timestamp": 1000 + k,
                "translation": [100.0 + 0.1 * k, 200.0, 0.0],
                "rotation": quat_z(90),
            }
            for k in range(2)
        ],
        "scene": [
            {"token": "sc", "name": "scene-0001", "first_sample_token": "smp0", "log_token": "l", "nbr_samples": 2}
        ],
        "sample": [
            {"token": f"smp{k}", "timestamp": 1000 + k, "scene_token": "sc", "prev": "", "next": ""} for k in range(2)
        ],
        "sample_data": [
            *(
                {
                    "token": f"sd{k}",
                    "sample_token": f"smp{k}",
                    "ego_pose_token": f"e{k}",
                    "calibrated_sensor_token": "cs-lidar",
                    "timestamp": 1000 + k,
                    "is_key_frame": True,
                    "filename": files[k],
                    "fileformat": "pcd",
                }
                for k in range(2)
            ),
            {
                "token": "cam0",
                "sample_token": "smp0",
                "ego_pose_token": "e0",
                "calibrated_sensor_token": "cs-cam",
                "timestamp": 1000,
                "is_key_frame": True,
                "filename": "samples/CAM_FRONT/x.jpg",
                "fileformat": "jpg",
            },
            {
                "token": "sweep",
                "sample_token": "smp0",
                "ego_pose_token": "e0",
                "calibrated_sensor_token": "cs-lidar",
                "timestamp": 1050,
                "is_key_frame": False,
                "filename": "sweeps/LIDAR_TOP/absent.pcd.bin",
                "fileformat": "pcd",
            },
        ],
        "category": [
            {"token": "c-car", "name": "vehicle.car"},
            {"token": "c-bike", "name": "vehicle.bicycle"},
            {"token": "c-truck", "name": "vehicle.truck"},
        ],
        "instance": [
            {"token": "i-car", "category_token": "c-car"},
            {"token": "i-bike", "category_token": "c-bike"},
            {"token": "i-truck", "category_token": "c-truck"},
        ],
        "sample_annotation": [],
    }
    for k in range(2):
        t["sample_annotation"] += [
            {
                "token": f"a-car{k}",
                "sample_token": f"smp{k}",
                "instance_token": "i-car",
                "translation": [110.0 + 0.1 * k, 201.0, 1.0],
                "size": [2.0, 4.0, 1.5],
                "rotation": quat_z(30),
                "num_lidar_pts": 120,
            },
            {
                "token": f"a-bike{k}",
                "sample_token": f"smp{k}",
                "instance_token": "i-bike",
                "translation": [90.0, 190.0, 1.0],
                "size": [0.6, 1.8, 1.4],
                "rotation": quat_z(0),
                "num_lidar_pts": 0,
            },
            {
                "token": f"a-truck{k}",
                "sample_token": f"smp{k}",
                "instance_token": "i-truck",
                "translation": [400.0, 600.0, 1.5],
                "size": [2.5, 8.0, 3.0],
                "rotation": quat_z(0),
                "num_lidar_pts": 0,
            },
        ]
    if break_table == "sample_annotation":
        del t["sample_annotation"][0]["size"]
    for name, rows in t.items():
        (tables / f"{name}.json").write_text(json.dumps(rows))
    if break_table == "ego_pose":
        (tables / "ego_pose.json").write_text('[{"token": "e0", "translation": [1, 2')
    return t


CENTER = np.array([12.0, -3.0, -0.8])


SIZE = np.array([4.2, 1.8, 1.5])


YAW = 0.7


def rot(yaw):
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def car_surface(rng, n):
    """n points on the sides and top of the box (object frame), none below 0.2 m above its bottom."""
    p = rng.uniform(-0.5, 0.5, (n, 3)) * SIZE
    face = rng.integers(0, 3, n)
    p[face == 0, 0] = np.sign(p[face == 0, 0]) * SIZE[0] / 2
    p[face == 1, 1] = np.sign(p[face == 1, 1]) * SIZE[1] / 2
    p[face == 2, 2] = SIZE[2] / 2
    p[:, 2] = np.maximum(p[:, 2], -SIZE[2] / 2 + 0.2)
    return p


def make_scene(tmp_path, n_car=500, seed=0):
    """A scan (.npy) with one car (n_car surface points), ground under it, clutter, and its box list (.json)."""
    rng = np.random.default_rng(seed)
    car_obj = car_surface(rng, n_car)
    ground_obj = np.c_[rng.uniform(-3, 3, (400, 2)), rng.uniform(-0.03, 0.03, 400) - SIZE[2] / 2]
    clutter = rng.uniform(-30, 30, (1000, 3)) + [0, 0, 40]  # far above: never in a box
    r = rot(YAW)
    scan = np.concatenate([car_obj @ r.T + CENTER, ground_obj @ r.T + CENTER, clutter])
    few = np.array([[30.0, 5.0, -1.0]]) + rng.normal(scale=0.2, size=(5, 3))  # 5 points in a small box
    scan = np.concatenate([scan, few]).astype(np.float32)
    np.save(tmp_path / "scan.npy", scan)
    boxes = [
        {"center": CENTER.tolist(), "size": SIZE.tolist(), "yaw": YAW, "label": "Car", "track_id": "a"},
        {"center": [-20.0, 0.0, -0.8], "size": [4.0, 1.8, 1.5], "yaw": 0.0, "label": "Car"},  # empty
        {"center": [30.0, 5.0, -1.0], "size": [4.0, 1.8, 1.5], "yaw": 0.0, "label": "van"},  # 5 points
        {"center": [5.0, 5.0, -1.0], "size": [0.6, 0.6, 1.8], "yaw": 0.0, "label": "Pedestrian"},
        {"center": [8.0, 8.0, -1.0], "size": [4.0, 0.0, 1.5], "yaw": 0.0, "label": "truck"},  # zero width
    ]
    (tmp_path / "scan.json").write_text(json.dumps(boxes))
    return scan, car_obj


def scan_folder(root: Path) -> Path:
    """A generic-format scan (.npy) with one car box (.json) holding 600 points on its surface."""
    rng = np.random.default_rng(0)
    size = np.array([4.2, 1.8, 1.5])
    car = rng.uniform(-0.5, 0.5, (600, 3)) * size
    face = rng.integers(0, 3, 600)
    for k in range(3):
        car[face == k, k] = np.sign(car[face == k, k]) * size[k] / 2
    center = np.array([10.0, 3.0, -0.9])
    clutter = rng.uniform(-30, 30, (300, 3)) + [0, 0, 40]
    root.mkdir(parents=True, exist_ok=True)
    np.save(root / "f0.npy", np.concatenate([car + center, clutter]).astype(np.float32))
    box = {"center": center.tolist(), "size": size.tolist(), "yaw": 0.0, "label": "car"}
    (root / "f0.json").write_text(json.dumps([box]))
    return root


def three_frames(root: Path) -> Path:
    """:func:`scan_folder` with its frame copied twice: f0, f1, f2."""
    scans = scan_folder(root)
    for k in (1, 2):
        shutil.copy(scans / "f0.npy", scans / f"f{k}.npy")
        shutil.copy(scans / "f0.json", scans / f"f{k}.json")
    return scans


class Identity:
    model_name = "identity"
    n_params = 0

    def complete(self, partials):
        return [p.copy() for p in partials]


def tracked_scene(tmp_path, points_per_car: int = 150, seed: int = 5, seen_once: bool = True):
    """Two frames of one sequence: a car (track 'a') and a van (track 'v') that move, ``points_per_car`` each; with
    ``seen_once`` a car seen in the first frame only; their observations as ``real extract`` gives them."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    frames = []
    for f in range(2):
        pts, boxes = [rng.uniform(-50, 50, (200, 3)) + [0, 0, 30]], []
        for tid, label, c, size in (
            ("a", "Car", [10.0 + f, 2.0, -0.8], [4.2, 1.8, 1.5]),
            ("v", "Van", [-8.0, 6.0 - f, -0.6], [5.0, 2.0, 2.0]),
        ):
            obj = rng.uniform(-0.5, 0.5, (points_per_car, 3)) * size
            obj[:, 2] = np.abs(obj[:, 2])
            pts.append(obj + c)
            boxes.append({"center": c, "size": size, "yaw": 0.0, "label": label, "track_id": tid})
        if f == 0 and seen_once:
            pts.append(rng.uniform(-0.5, 0.5, (80, 3)) * [4, 1.8, 1.4] + [0, -10, -0.8])
            boxes.append(
                {"center": [0, -10, -0.8], "size": [4, 1.8, 1.4], "yaw": 0.0, "label": "Car", "track_id": "once"}
            )
        np.save(tmp_path / f"s{f}.npy", np.concatenate(pts).astype(np.float32))
        frames.append({"scan": f"s{f}.npy", "timestamp": f, "sequence": "seq", "boxes": boxes})
    (tmp_path / "scene.json").write_text(json.dumps({"frames": frames}))
    return extract(open_reader(tmp_path / "scene.json", "generic"), ExtractConfig(), progress=False)


def visible_surface(box: Box, origin: np.ndarray, density: float, rng: np.random.Generator) -> np.ndarray:
    """Points (K, 3) in the scan frame, uniform on the faces of ``box`` that face ``origin`` (a sensor there
    sees exactly those faces of a convex box): ``density`` points per square metre."""
    o = box.to_object(origin)
    half = 0.5 * box.size
    out = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            if sign * o[axis] <= half[axis]:  # the sensor is not outside this face's plane: face hidden
                continue
            a, b = [k for k in range(3) if k != axis]
            n = int(density * box.size[a] * box.size[b])
            p = np.zeros((n, 3))
            p[:, axis] = sign * half[axis]
            p[:, a] = rng.uniform(-half[a], half[a], n)
            p[:, b] = rng.uniform(-half[b], half[b], n)
            out.append(p)
    return box.from_object(np.concatenate(out))


def drive_past(perturb: dict[int, tuple[float, float, float]], n: int = 7, seed: int = 0):
    """A 4.4 x 1.8 x 1.5 m box driving past a sensor 1.8 m high (true boxes 5 m apart along x from -15 m, 6 m
    to the left: three frames see its front, three its back, one only its side), each frame's visible faces sampled; ``perturb`` {frame: (dx, dy, dyaw)} moves the given boxes."""
    rng = np.random.default_rng(seed)
    origin = np.array([0.0, 0.0, 1.8])
    frames, truth = [], []
    for k in range(n):
        b = Box([-15.0 + 5.0 * k, 6.0, 0.75], [4.4, 1.8, 1.5], yaw=0.05 * k)
        pts = visible_surface(b, origin, 150.0, rng)
        dx, dy, dyaw = perturb.get(k, (0.0, 0.0, 0.0))
        given = b.replace(
            center=b.center + [dx, dy, 0.0], rotation=Box([0, 0, 0], [1, 1, 1], yaw=b.yaw + dyaw).rotation
        )
        frames.append(TrackFrame(pts, given, origin, 0.1 * k))
        truth.append(b)
    return frames, truth


DRIVE_SIZE = [4.2, 1.8, 1.5]
"""The two cars' box size in :func:`write_drive` (metres)."""


def write_drive(folder, times, track_ids=("a", "b"), rng=None):
    """Generic frames: two cars (track ids ``track_ids``; "" = none) as box-surface points, plus ground."""
    rng = rng or np.random.default_rng(0)
    folder.mkdir(parents=True, exist_ok=True)
    for k, t in enumerate(times):
        boxes, pts = [], [rng.uniform(-30, 30, (300, 3)) * [1, 1, 0] - [0, 0, 1.7]]
        for tid, c in zip(track_ids, ([10.0 + 2.0 * t, 2.0, -0.9], [-6.0, -5.0, -0.9])):
            obj = rng.uniform(-0.5, 0.5, (300, 3)) * DRIVE_SIZE
            obj[:, 0] = np.sign(obj[:, 0]) * DRIVE_SIZE[0] / 2  # front and back faces
            obj[:, 2] = rng.uniform(-DRIVE_SIZE[2] / 2 + 0.12, DRIVE_SIZE[2] / 2, 300)  # above the ground cut (0.10 m)
            pts.append(obj + c)
            box = {"center": c, "size": DRIVE_SIZE, "yaw": 0.0, "label": "car"}
            if tid:
                box["track_id"] = tid
            boxes.append(box)
        np.save(folder / f"f{k}.npy", np.concatenate(pts).astype(np.float32))
        (folder / f"f{k}.json").write_text(json.dumps({"timestamp": t, "boxes": boxes}))
    return folder


def brute_force_crop(points: np.ndarray, box: Box, margin: float, clearance: float) -> np.ndarray:
    """Indices of the points inside the box grown by ``margin``, bottom raised by ``clearance``, by hand."""
    idx = []
    half = 0.5 * box.size
    for i, p in enumerate(points):
        q = box.rotation.T @ (p - box.center)
        if (
            abs(q[0]) <= half[0] + margin
            and abs(q[1]) <= half[1] + margin
            and q[2] <= half[2] + margin
            and q[2] >= -half[2] + clearance
        ):
            idx.append(i)
    return np.array(idx, dtype=np.int64)


def track_plan(src, window: str, worker: bool) -> tuple[TrackPlan, list]:
    reader = open_reader(src, "generic")
    keys = reader.frame_keys()
    return TrackPlan(parse_window(window), SceneConfig(), refine=True, worker=worker).build(reader, keys), keys


def track_inputs(plan: TrackPlan, keys) -> list:
    """Per frame (in order): its boxes (centre, rotation) and fused points, as the frame loop gets them."""
    out = []
    for key in keys:
        boxes, extra = plan.frame_inputs(key, plan.take(key).boxes)
        out.append(
            ([(b.center.tolist(), b.rotation.tolist()) for b in boxes], {i: v.tolist() for i, v in extra.items()})
        )
    return out


BOXES = {  # file -> (extents, centre) in the object frame, metres
    "boxes/box_a.ply": ((4.5, 1.8, 1.5), (0.2, 0.0, 0.75)),
    "boxes/box_b.obj": ((4.0, 1.7, 1.6), (0.0, 0.1, 0.0)),
}


def write_box_meshes(root: Path) -> Path:
    """Three small models in two categories (sub-folders) under ``root``: two boxes of :data:`BOXES` and an
    ellipsoid."""
    for rel, (ext, c) in BOXES.items():
        m = trimesh.creation.box(extents=ext)
        m.apply_translation(c)
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        m.export(root / rel)
    e = trimesh.creation.icosphere(subdivisions=2)
    e.apply_scale((2.2, 0.9, 0.75))
    (root / "blobs").mkdir()
    e.export(root / "blobs" / "ellipsoid.ply")
    return root


def small_cfg(meshes, **kw):
    """A 6-view build of ``meshes`` (split 1/1/1, seed 3, one extra cap rig), ``kw`` replacing fields."""
    base = dict(meshes=str(meshes), views=6, split="1/1/1", seed=3, extra_rigs=["64x32@60"])
    base.update(kw)
    return BuildConfig(**base)


def build_reference(meshes: Path, out: Path) -> Path:
    """:func:`small_cfg`'s dataset of ``meshes`` built with one worker into ``out``, checked whole."""
    rep = build_dataset(small_cfg(meshes), out, workers=1, progress=False, log=lambda m: None)
    assert rep.units_computed == rep.units_total and not Path(str(out) + ".parts").exists()
    return out
