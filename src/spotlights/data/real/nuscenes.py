"""nuScenes reader: LIDAR_TOP keyframes and their 3-D boxes, from the JSON tables (no nuscenes-devkit).

Layout (the nuScenes release format)::

    ROOT/samples/LIDAR_TOP/<name>.pcd.bin   N x 5 float32: x, y, z, intensity, ring index (sensor frame)
    ROOT/<version>/*.json                   the tables (version: v1.0-mini, v1.0-trainval, ...)

Only 9 of nuScenes' 13 tables are read - ``scene``, ``sample``, ``sample_data``,
``sample_annotation``, ``instance``, ``category``, ``ego_pose``,
``calibrated_sensor``, ``sensor`` - so an extract without ``log``, ``map``,
``attribute`` and ``visibility`` (which nuscenes-devkit's ``NuScenes`` class
refuses) reads fine. ``ROOT`` is the folder holding ``samples/`` and the table
folder, or the table folder itself (scans are then looked up in its parent).

Frames. One frame per keyframe (``sample``) of each scene, in time order: its
``sample_data`` row of channel ``LIDAR_TOP`` with ``is_key_frame`` true.
``sequence`` = the scene name (e.g. ``scene-0523``), ``frame_id`` = the sample
token, ``timestamp`` = the LIDAR_TOP ``timestamp`` (integer microseconds).
The sensor frame is the LIDAR_TOP frame the points are stored in (nuScenes:
x right, y forward, z up, as mounted); ``sensor_to_world`` is

    global_T_sensor = global_T_ego(ego_pose of the sweep) @ ego_T_sensor(calibrated_sensor)

with each ``translation`` (metres) and scalar-first ``rotation`` quaternion
(w, x, y, z). Boxes (``sample_annotation``: ``translation`` = centre,
``rotation`` = quaternion, both in the global frame) are moved into the sensor
frame with the inverse. nuScenes gives ``size`` as **(width, length, height)**;
our boxes are (length, width, height) along the box's x (forward, the length),
y, z, so ``size = (size[1], size[0], size[2])``. ``instance_token`` is the
track id. Check (tests): with no margin and no ground cut, a box holds exactly
the annotation's ``num_lidar_pts`` points of its keyframe.

Classes (:data:`CLASS_MAP`): ``vehicle.car`` -> car, ``vehicle.truck`` -> truck,
``vehicle.trailer`` -> trailer, ``vehicle.bus.bendy`` / ``vehicle.bus.rigid`` -> bus,
``vehicle.construction`` -> construction, ``vehicle.emergency.ambulance`` /
``vehicle.emergency.police`` -> emergency. ``vehicle.bicycle`` and
``vehicle.motorcycle`` (two-wheelers: no car-like body to complete), pedestrians,
barriers, cones and debris are not vehicles of interest: left out and counted
per label by ``real extract``. nuScenes has no van/caravan class (vans are cars).
"""

from __future__ import annotations

import os
from collections import defaultdict
from pathlib import Path

import numpy as np

from ...errors import InputFileError, ParameterError
from ...geometry.boxes import MAX_BOX_CENTER_M, Box
from ...geometry.rotations import quaternion_to_matrix, rigid_transform
from ...inputs import path_inside, read_json
from .base import Frame, SceneReader, lookup_class
from .scans import read_nuscenes_bin

CLASS_MAP: dict[str, str | None] = {
    "vehicle.car": "car",
    "vehicle.truck": "truck",
    "vehicle.trailer": "trailer",
    "vehicle.bus.bendy": "bus",
    "vehicle.bus.rigid": "bus",
    "vehicle.construction": "construction",
    "vehicle.emergency.ambulance": "emergency",
    "vehicle.emergency.police": "emergency",
    # the detection challenge's names (detector outputs), for boxes given in JSON
    "construction_vehicle": "construction",
}

LIDAR_CHANNEL = "LIDAR_TOP"

#: table -> keys every row must hold (the only ones read).
TABLE_KEYS: dict[str, tuple[str, ...]] = {
    "scene": ("token", "name", "first_sample_token"),
    "sample": ("token", "timestamp", "scene_token"),
    "sample_data": (
        "token",
        "sample_token",
        "ego_pose_token",
        "calibrated_sensor_token",
        "timestamp",
        "is_key_frame",
        "filename",
    ),
    "sample_annotation": ("token", "sample_token", "instance_token", "translation", "size", "rotation"),
    "instance": ("token", "category_token"),
    "category": ("token", "name"),
    "ego_pose": ("token", "translation", "rotation"),
    "calibrated_sensor": ("token", "sensor_token", "translation", "rotation"),
    "sensor": ("token", "channel"),
}


def find_table_folder(root: Path) -> Path:
    """The folder holding the nuScenes JSON tables under ``root`` (itself or one level down)."""
    if (root / "sample_annotation.json").is_file():
        return root
    cands = sorted(p.parent for p in root.glob("*/sample_annotation.json"))
    if not cands:
        raise InputFileError(root, "not a nuScenes folder: no sample_annotation.json here or in a sub-folder (v1.0-*/)")
    if len(cands) > 1:
        raise InputFileError(
            root, f"several nuScenes table folders ({', '.join(p.name for p in cands)}); give the one to read as SOURCE"
        )
    return cands[0]


def read_table(folder: Path, name: str) -> list[dict]:
    """One nuScenes table: a JSON list of objects with at least :data:`TABLE_KEYS` ``[name]``."""
    path = folder / f"{name}.json"
    if not path.is_file():
        raise InputFileError(path, f"nuScenes table {name}.json not found")
    rows = read_json(path)
    if not isinstance(rows, list):
        raise InputFileError(path, f"a nuScenes table is a JSON list of rows, got {type(rows).__name__}")
    keys = TABLE_KEYS[name]
    for i, r in enumerate(rows):
        if not isinstance(r, dict):
            raise InputFileError(path, f"row {i} is not an object")
        missing = [k for k in keys if k not in r]
        if missing:
            raise InputFileError(path, f"row {i} lacks {', '.join(repr(k) for k in missing)}")
        bad = [k for k in keys if k.endswith("token") and not isinstance(r[k], str)]
        bad += [k for k in keys if k == "timestamp" and (not isinstance(r[k], int) or isinstance(r[k], bool))]
        if bad:
            kind = "a string" if bad[0].endswith("token") else "an integer (microseconds)"
            raise InputFileError(path, f"row {i}: {bad[0]} must be {kind}, got {r[bad[0]]!r:.40}")
    return rows


def _pose(row: dict, path: Path, what: str) -> np.ndarray:
    """(4, 4) float64 transform from a row's ``translation`` (3) and ``rotation`` quaternion (w, x, y, z)."""
    try:
        t = np.asarray(row["translation"], dtype=np.float64)
        q = np.asarray(row["rotation"], dtype=np.float64)
    except (TypeError, ValueError):
        raise InputFileError(path, f"{what} {row.get('token', '?')}: translation/rotation are not numbers") from None
    if (
        t.shape != (3,)
        or q.shape != (4,)
        or not (np.all(np.isfinite(t)) and np.all(np.isfinite(q)))
        or np.linalg.norm(q) < 1e-9
    ):
        raise InputFileError(
            path,
            f"{what} {row.get('token', '?')}: translation must be 3 numbers and rotation a "
            "non-zero quaternion (w, x, y, z)",
        )
    if np.abs(t).max() > MAX_BOX_CENTER_M:  # the bound of a box centre: frames chained to a box stay within it
        raise InputFileError(
            path,
            f"{what} {row.get('token', '?')}: translation {t.tolist()} is out of range (±{MAX_BOX_CENTER_M:.0e} m)",
        )
    return rigid_transform(quaternion_to_matrix(*q), t)


def annotation_box(row: dict, category: str, path: Path | str = "sample_annotation.json") -> Box:
    """A ``sample_annotation`` row as a :class:`Box` in the **global** frame.

    ``size`` (w, l, h) becomes (l, w, h); the rotation's x axis is the box's length.
    """
    try:
        wlh = np.asarray(row["size"], dtype=np.float64)
    except (TypeError, ValueError):
        wlh = np.zeros(0)
    if wlh.shape != (3,) or not np.all(np.isfinite(wlh)):
        raise InputFileError(path, f"annotation {row.get('token', '?')}: size must be 3 finite numbers (w, l, h)")
    t = _pose(row, Path(path), "annotation")
    try:
        return Box(
            t[:3, 3],
            (wlh[1], wlh[0], wlh[2]),
            t[:3, :3],
            category,
            lookup_class(category, CLASS_MAP),
            str(row["instance_token"]),
        )
    except ParameterError as exc:  # out of range (the box's own checks), here naming the file and row
        raise InputFileError(path, f"annotation {row.get('token', '?')}: {exc}") from None


def _instance_categories(t: dict, tables: Path) -> dict[str, str]:
    """``{instance token: category name}`` of the tables ``t``; raises InputFileError for an
    instance whose category is not in ``category.json``."""
    category = {r["token"]: str(r["name"]) for r in t["category"]}
    out = {}
    for r in t["instance"]:
        if r["category_token"] not in category:
            raise InputFileError(
                tables / "instance.json", f"instance {r['token']}: unknown category_token {r['category_token']}"
            )
        out[r["token"]] = category[r["category_token"]]
    return out


def _lidar_keyframes(t: dict, calib: dict, tables: Path) -> dict[str, dict]:
    """``{sample token: its LIDAR_TOP keyframe sample_data row}``; raises InputFileError for a
    keyframe with an unknown calibrated sensor."""
    sensor_channel = {r["token"]: str(r["channel"]) for r in t["sensor"]}
    lidar: dict[str, dict] = {}
    for r in t["sample_data"]:
        if not r["is_key_frame"]:
            continue
        cs = calib.get(r["calibrated_sensor_token"])
        if cs is None:
            raise InputFileError(
                tables / "sample_data.json",
                f"sample_data {r['token']}: unknown calibrated_sensor_token {r['calibrated_sensor_token']}",
            )
        if sensor_channel.get(cs["sensor_token"]) == LIDAR_CHANNEL:
            lidar[r["sample_token"]] = r
    return lidar


def _wanted_scenes(scenes, scene_names: dict[str, str]) -> set[str] | None:
    """The scene names asked for (None: all); raises ParameterError naming those the tables lack."""
    wanted = None if scenes is None else {str(s) for s in scenes}
    if wanted is not None:
        unknown = sorted(wanted - set(scene_names.values()))
        if unknown:
            raise ParameterError(
                f"unknown nuScenes scene(s) {', '.join(unknown)}; the tables hold "
                f"{', '.join(sorted(scene_names.values())[:10])}"
            )
    return wanted


def _samples_of_scenes(t: dict, scene_names: dict[str, str], wanted: set[str] | None, tables: Path):
    """``(sample row, scene name)`` of every sample of the wanted scenes, in table order; raises
    InputFileError for a sample of an unknown scene."""
    for s in t["sample"]:
        name = scene_names.get(s["scene_token"])
        if name is None:
            raise InputFileError(tables / "sample.json", f"sample {s['token']}: unknown scene_token {s['scene_token']}")
        if wanted is None or name in wanted:
            yield s, name


def _frame_record(s: dict, name: str, lidar: dict, ego: dict, data_root: Path, tables: Path) -> tuple:
    """``(scene name, timestamp, sample token, sample_data row, scan path)`` of one sample; raises
    InputFileError when its keyframe, ego pose or scan file is missing."""
    sd = lidar.get(s["token"])
    if sd is None:
        raise InputFileError(tables / "sample_data.json", f"sample {s['token']} has no {LIDAR_CHANNEL} keyframe")
    for key, table in (("ego_pose_token", ego),):
        if sd[key] not in table:
            raise InputFileError(tables / "sample_data.json", f"sample_data {sd['token']}: unknown {key} {sd[key]}")
    scan = path_inside(data_root, sd["filename"], tables / "sample_data.json", f"sample_data {sd['token']} filename")
    if not scan.is_file():
        raise InputFileError(scan, f"{LIDAR_CHANNEL} keyframe scan of sample {s['token']} not found")
    return (name, sd["timestamp"], s["token"], sd, scan)


class NuScenesReader(SceneReader):
    """nuScenes LIDAR_TOP keyframes with their annotated boxes (see the module docstring).

    Parameters
    ----------
    root : the folder with ``samples/`` and the table folder, or the table folder.
    scenes : scene names to read (e.g. ``["scene-0523"]``); default every scene of the tables.
    """

    format = "nuscenes"

    def __init__(self, root: str | os.PathLike, scenes=None):
        root = Path(root)
        if not root.is_dir():
            raise InputFileError(root, "not a folder")
        tables = find_table_folder(root)
        data_root = root if (root / "samples").is_dir() or tables != root else tables.parent
        self.root = str(data_root)
        self.tables = tables
        t = {name: read_table(tables, name) for name in TABLE_KEYS}
        by_token = {name: {r["token"]: r for r in rows} for name, rows in t.items()}
        self._calib = by_token["calibrated_sensor"]
        self._ego = by_token["ego_pose"]
        self._instance_category = _instance_categories(t, tables)
        self._annotations: dict[str, list[dict]] = defaultdict(list)
        for r in t["sample_annotation"]:
            self._annotations[r["sample_token"]].append(r)
        lidar = _lidar_keyframes(t, self._calib, tables)
        scene_names = {r["token"]: str(r["name"]) for r in t["scene"]}
        wanted = _wanted_scenes(scenes, scene_names)
        frames = [
            _frame_record(s, name, lidar, self._ego, data_root, tables)
            for s, name in _samples_of_scenes(t, scene_names, wanted, tables)
        ]
        if not frames:
            raise InputFileError(
                tables, "no LIDAR_TOP keyframe" + (f" in scene(s) {', '.join(sorted(wanted))}" if wanted else "")
            )
        frames.sort(key=lambda f: (f[0], f[1]))
        self._frames = {(f[0], f[2]): f for f in frames}
        self._keys = [(f[0], f[2]) for f in frames]

    def frame_keys(self) -> list[tuple[str, str]]:
        return list(self._keys)

    def sensor_to_world(self, key: tuple[str, str]) -> np.ndarray:
        """(4, 4) float64 global <- LIDAR_TOP sensor transform of one frame."""
        sd = self._frames[key][3]
        return _pose(self._ego[sd["ego_pose_token"]], self.tables / "ego_pose.json", "ego_pose") @ _pose(
            self._calib[sd["calibrated_sensor_token"]], self.tables / "calibrated_sensor.json", "calibrated_sensor"
        )

    def keyframe(self, key: tuple[str, str]) -> tuple[int, str]:
        """(LIDAR_TOP timestamp in integer microseconds, scan file path) of one frame, without reading the scan."""
        f = self._frames[key]
        return f[1], str(f[4])

    def annotations(self, key: tuple[str, str]) -> list[dict]:
        """The raw ``sample_annotation`` rows of one frame (global frame), in table order."""
        return list(self._annotations.get(key[1], []))

    def load(self, key: tuple[str, str]) -> Frame:
        name, ts, sample, sd, scan = self._frames[key]
        world = self.sensor_to_world(key)
        to_sensor = np.linalg.inv(world)
        path = self.tables / "sample_annotation.json"
        boxes = []
        for r in self._annotations.get(sample, []):
            cat = self._instance_category.get(r["instance_token"])
            if cat is None:
                raise InputFileError(path, f"annotation {r['token']}: unknown instance_token {r['instance_token']}")
            boxes.append(annotation_box(r, cat, path).transformed(to_sensor))
        return Frame(
            sequence=name,
            frame_id=sample,
            timestamp=ts,
            points=read_nuscenes_bin(scan),
            boxes=boxes,
            sensor_to_world=world,
            scan_path=str(scan),
            label_path=str(path),
        )
