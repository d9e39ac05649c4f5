"""KITTI-360 reader: raw Velodyne scans with the 3D bounding boxes of ``data_3d_bboxes``.

Written from the public format description (kitti360scripts, the dataset's
documentation); tested on small synthetic files in that format, since KITTI-360
itself is not shipped with the project. Layout::

    ROOT/data_3d_raw/<SEQ>/velodyne_points/data/0000000123.bin   N x 4 float32 (Velodyne frame)
    ROOT/data_3d_bboxes/train/<SEQ>.xml        (also train_full/, or ROOT/data_3d_bboxes/<SEQ>.xml)
    ROOT/data_poses/<SEQ>/poses.txt            per line: frame index + 12 numbers (3x4 IMU -> world)
    ROOT/calibration/calib_cam_to_pose.txt     "image_00: 12 numbers" (3x4 camera 0 -> IMU/GPS pose frame)
    ROOT/calibration/calib_cam_to_velo.txt     12 numbers (3x4 camera 0 -> Velodyne)

with ``SEQ`` like ``2013_05_28_drive_0000_sync``.

Boxes. The XML (OpenCV storage) holds one element per object with
``semanticId`` (a KITTI-360 id: car 13, truck 14, trailer 15, caravan 16),
``instanceId``, ``start_frame``/``end_frame``, ``timestamp`` (-1 for a static
object, else the frame index of this box of a moving object), an optional
``label`` name, and the OpenCV matrices ``transform`` (4x4) and ``vertices``
(8x3). The world-frame corners are ``transform[:3,:3] @ v + transform[:3,3]``.
``transform[:3,:3]`` is a rotation times a scale: its polar decomposition
``U @ P`` gives the box orientation ``U`` and the box extent
``diag(P) * (max - min of the template vertices)``. In each frame the box axes
are then ordered as our object frame wants them, whatever the template's
convention: up = the axis closest to the Velodyne's +z (made to point up), forward = the
longer of the two others (its template sign kept: front and back of a box
cannot be told apart), left = up x forward.

Frames. A static box (``timestamp == -1``) belongs to every frame from
``start_frame`` to ``end_frame``; a dynamic one to the frame ``timestamp``. The
Velodyne -> world transform of frame f is

    world_T_velo = poses[f] @ calib_cam_to_pose[image_00] @ calib_cam_to_velo^-1

and world boxes are moved into the Velodyne frame with its inverse. Frames
without a pose or without a scan are left out. Track id = ``"<semanticId>-<instanceId>"``.

Classes: car -> car, truck -> truck, caravan -> caravan, trailer -> trailer, bus -> bus.
Only objects of KITTI-360's vehicle category are read (the five above plus
train, motorcycle, bicycle, unknown vehicle, counted as excluded by the
extraction); scene objects such as buildings, poles or signs are ignored.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ...errors import InputFileError, ParameterError
from ...geometry.boxes import Box
from ...geometry.rotations import orthonormalize
from .base import Frame, SceneReader, lookup_class
from .scans import read_kitti_bin

CLASS_MAP: dict[str, str | None] = {
    "car": "car",
    "truck": "truck",
    "caravan": "caravan",
    "trailer": "trailer",
    "bus": "bus",
}

#: KITTI-360 ``semanticId`` (the "kittiId" of kitti360scripts' label table) -> label name,
#: for the instance classes (used when an XML object has no ``label`` element).
KITTI360_ID_NAMES: dict[int, str] = {
    11: "building",
    12: "garage",
    13: "car",
    14: "truck",
    15: "trailer",
    16: "caravan",
    17: "motorcycle",
    18: "bicycle",
    19: "person",
    20: "rider",
    21: "pole",
    22: "smallpole",
    23: "traffic light",
    24: "traffic sign",
    25: "lamp",
    26: "trash bin",
    27: "vending machine",
    28: "box",
    29: "stop",
    33: "train",
    34: "bus",
    35: "unknown construction",
    36: "unknown vehicle",
    37: "unknown object",
}


#: Labels of the KITTI-360 "vehicle" category: the only objects read as boxes.
VEHICLE_LABELS = frozenset(
    {"car", "truck", "bus", "caravan", "trailer", "train", "motorcycle", "bicycle", "unknown vehicle"}
)


def _matrix(node, path, what: str) -> np.ndarray:
    """Parse an OpenCV-storage matrix element (rows, cols, data) into a float64 array."""
    try:
        rows = int(node.find("rows").text)
        cols = int(node.find("cols").text)
        data = np.array([float(v) for v in node.find("data").text.split()], dtype=np.float64)
    except (AttributeError, TypeError, ValueError):
        raise InputFileError(path, f"{what}: malformed OpenCV matrix (rows, cols, data expected)") from None
    if data.size != rows * cols:
        raise InputFileError(path, f"{what}: {data.size} values for a {rows}x{cols} matrix")
    if not np.all(np.isfinite(data)):
        raise InputFileError(path, f"{what}: holds a NaN or infinite value")
    return data.reshape(rows, cols)


def _int(child, tag, path, what, default=None) -> int:
    node = child.find(tag)
    if node is None or node.text is None:
        if default is not None:
            return default
        raise InputFileError(path, f"{what}: missing <{tag}>")
    try:
        return int(node.text.strip())
    except ValueError:
        raise InputFileError(path, f"{what}: <{tag}> is not an integer") from None


def parse_bboxes_xml(path: str | os.PathLike) -> list[dict]:
    """Read a KITTI-360 ``data_3d_bboxes`` XML file.

    Returns one dict per object element that has a ``transform``: ``label``
    (str), ``semantic_id``, ``instance_id``, ``start_frame``, ``end_frame``,
    ``timestamp`` (ints; -1 = static), ``center`` (3,), ``size`` (3,) = extent
    along the template's x, y, z, ``rotation`` (3, 3) = those template axes (columns),
    all float64 in the **world** frame (the axes are ordered into forward, left,
    up later, in the Velodyne frame: see :func:`vehicle_axes`).
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "bounding-box XML not found")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise InputFileError(path, f"not valid XML ({exc})") from None
    out = []
    for child in root:
        if child.find("transform") is None:
            continue
        what = f"<{child.tag}>"
        transform = _matrix(child.find("transform"), path, f"{what} transform")
        if transform.shape != (4, 4):
            raise InputFileError(path, f"{what} transform is {transform.shape[0]}x{transform.shape[1]}, expected 4x4")
        vnode = child.find("vertices")
        if vnode is None:
            raise InputFileError(path, f"{what}: missing <vertices>")
        verts = _matrix(vnode, path, f"{what} vertices")
        if verts.ndim != 2 or verts.shape[1] != 3 or verts.shape[0] < 2:
            raise InputFileError(path, f"{what} vertices must be n x 3")
        sem = _int(child, "semanticId", path, what)
        lab = child.find("label")
        label = lab.text.strip() if lab is not None and lab.text else KITTI360_ID_NAMES.get(sem, f"id{sem}")
        a = transform[:3, :3]
        u, s, vt = np.linalg.svd(a)  # polar decomposition a = (u vt) (v s vt)
        rot = u @ vt
        p = vt.T @ np.diag(s) @ vt
        if np.linalg.det(rot) < 0:
            raise InputFileError(path, f"{what} transform is a reflection (negative determinant)")
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        center_local = 0.5 * (lo + hi)
        out.append(
            dict(
                label=label,
                semantic_id=sem,
                instance_id=_int(child, "instanceId", path, what),
                start_frame=_int(child, "start_frame", path, what, default=-1),
                end_frame=_int(child, "end_frame", path, what, default=-1),
                timestamp=_int(child, "timestamp", path, what, default=-1),
                center=a @ center_local + transform[:3, 3],
                size=np.diag(p) * (hi - lo),
                rotation=rot,
            )
        )
    return out


def vehicle_axes(rot: np.ndarray, extent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Order a box's axes as (forward, left, up): up = the axis closest to the frame's +z
    (sign made positive; used in the z-up Velodyne frame), forward = the longer of the other two (template sign
    kept), left = up x forward. Returns (rotation (3,3), size (3,) = l, w, h)."""
    rot = orthonormalize(rot)
    k_up = int(np.argmax(np.abs(rot[2, :])))
    rest = [k for k in range(3) if k != k_up]
    k_fwd = max(rest, key=lambda k: (extent[k], -k))
    k_left = rest[0] if rest[1] == k_fwd else rest[1]
    up = rot[:, k_up] * np.sign(rot[2, k_up])
    fwd = rot[:, k_fwd]
    left = np.cross(up, fwd)
    return np.stack([fwd, left, up], axis=1), np.array([extent[k_fwd], extent[k_left], extent[k_up]])


def _read_rigid(path: Path, key: str | None) -> np.ndarray:
    """A 3x4 rigid transform from a calibration file -> (4, 4) float64."""
    if not path.is_file():
        raise InputFileError(path, "calibration file not found")
    vals = None
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if key is None:
                if line.strip():
                    vals = line.split()
                    break
            elif line.strip().startswith(key + ":"):
                vals = line.split(":", 1)[1].split()
                break
    if vals is None:
        raise InputFileError(path, f"no {key or 'matrix'} line")
    try:
        nums = [float(v) for v in vals]
    except ValueError:
        raise InputFileError(path, f"non-numeric value in {key or 'matrix'}") from None
    if len(nums) != 12:
        raise InputFileError(path, f"{key or 'matrix'} has {len(nums)} values, expected 12 (3x4)")
    if not all(math.isfinite(v) for v in nums):
        raise InputFileError(path, f"{key or 'matrix'} holds a NaN or infinite value")
    t = np.eye(4)
    t[:3, :4] = np.array(nums).reshape(3, 4)
    return t


def read_poses(path: Path) -> dict[int, np.ndarray]:
    """``poses.txt``: {frame index: (4, 4) float64 IMU -> world}."""
    if not path.is_file():
        raise InputFileError(path, "poses file not found")
    out = {}
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            f = line.split()
            if not f:
                continue
            if len(f) != 13:
                raise InputFileError(path, f"line {lineno}: expected 13 numbers (frame + 3x4 pose), got {len(f)}")
            try:
                nums = [float(v) for v in f]
            except ValueError:
                raise InputFileError(path, f"line {lineno}: non-numeric value") from None
            if not all(math.isfinite(v) for v in nums):
                raise InputFileError(path, f"line {lineno}: NaN or infinite value")
            t = np.eye(4)
            t[:3, :4] = np.array(nums[1:]).reshape(3, 4)
            out[int(nums[0])] = t
    return out


def _bbox_xml(root: Path, seq: str) -> Path | None:
    for sub in ("train", "train_full", "val", "test", ""):
        p = root / "data_3d_bboxes" / sub / f"{seq}.xml"
        if p.is_file():
            return p
    return None


def _default_sequences(root: Path, raw: Path) -> list[str]:
    """Every sequence (sorted) with both a scan folder and a box XML; raises InputFileError if none."""
    sequences = sorted(
        p.name for p in raw.iterdir() if (p / "velodyne_points" / "data").is_dir() and _bbox_xml(root, p.name)
    )
    if not sequences:
        raise InputFileError(
            root, "no sequence has both data_3d_raw/<seq>/velodyne_points/data and data_3d_bboxes/*/<seq>.xml"
        )
    return sequences


def _vehicle_objects(objs: list[dict]) -> tuple[list[dict], np.ndarray, dict[int, list[dict]]]:
    """The vehicle objects of a box XML: ``(static objects, their (N, 2) int64 first/last frames,
    {frame: dynamic objects})``."""
    # Scene objects (buildings, poles, signs, ...) are not road users: only objects of
    # the vehicle category become boxes (car, truck, caravan, trailer, and bus, train,
    # motorcycle, bicycle, unknown vehicle, which the extraction counts as excluded).
    objs = [o for o in objs if o["label"] in VEHICLE_LABELS]
    static = [o for o in objs if o["timestamp"] < 0]
    dynamic: dict[int, list[dict]] = {}
    for o in objs:
        if o["timestamp"] >= 0:
            dynamic.setdefault(o["timestamp"], []).append(o)
    span = np.array([[o["start_frame"], o["end_frame"]] for o in static], dtype=np.int64).reshape(-1, 2)
    return static, span, dynamic


def _read_sequence(root: Path, raw: Path, seq: str, frames) -> tuple[dict, list[int]]:
    """One sequence's scans, poses and vehicle objects, and its frame indices (those with a scan
    and a pose, within ``frames``); raises InputFileError for a missing scan folder or XML."""
    data = raw / seq / "velodyne_points" / "data"
    if not data.is_dir():
        raise InputFileError(data, "scan folder not found")
    xml = _bbox_xml(root, seq)
    if xml is None:
        raise InputFileError(root / "data_3d_bboxes" / "train" / f"{seq}.xml", "bounding-box XML not found")
    poses = read_poses(root / "data_poses" / seq / "poses.txt")
    objs = parse_bboxes_xml(xml)
    scans = {int(p.stem): p for p in data.glob("*.bin") if p.stem.isdigit()}
    idx = sorted(i for i in scans if i in poses)
    if frames is not None:
        start, stop, step = frames
        idx = [i for i in idx if i >= start and (stop is None or i < stop) and (i - start) % step == 0]
    static, span, dynamic = _vehicle_objects(objs)
    return dict(scans=scans, poses=poses, static=static, span=span, dynamic=dynamic, xml=str(xml)), idx


class Kitti360Reader(SceneReader):
    """KITTI-360 sequences: one :class:`Frame` per Velodyne scan that has a pose.

    Parameters
    ----------
    root : the KITTI-360 folder (with ``data_3d_raw/``, ``data_3d_bboxes/``, ``data_poses/``, ``calibration/``).
    sequences : sequence names to read (default: every sequence with both scans and a box XML).
    frames : optional (start, stop, step) range of frame indices (stop exclusive).
    """

    format = "kitti360"

    def __init__(
        self,
        root: str | os.PathLike,
        sequences: list[str] | None = None,
        frames: tuple[int, int | None, int] | None = None,
    ):
        root = Path(root)
        if not root.is_dir():
            raise InputFileError(root, "not a folder")
        raw = root / "data_3d_raw"
        if not raw.is_dir():
            raise InputFileError(root, "not a KITTI-360 folder: no data_3d_raw/ inside")
        if sequences is None:
            sequences = _default_sequences(root, raw)
        calib = root / "calibration"
        cam_to_pose = _read_rigid(calib / "calib_cam_to_pose.txt", "image_00")
        cam_to_velo = _read_rigid(calib / "calib_cam_to_velo.txt", None)
        self.pose_T_velo = cam_to_pose @ np.linalg.inv(cam_to_velo)
        self.root = str(root)
        self._seq: dict[str, dict] = {}
        self._keys: list[tuple[str, str]] = []
        for seq in sequences:
            self._seq[seq], idx = _read_sequence(root, raw, seq, frames)
            self._keys.extend((seq, f"{i:010d}") for i in idx)

    def frame_keys(self) -> list[tuple[str, str]]:
        return list(self._keys)

    def load(self, key: tuple[str, str]) -> Frame:
        seq, stem = key
        s = self._seq[seq]
        f = int(stem)
        world_T_velo = s["poses"][f] @ self.pose_T_velo
        velo_T_world = np.linalg.inv(world_T_velo)
        live = np.flatnonzero((s["span"][:, 0] <= f) & (f <= s["span"][:, 1]))
        objs = [s["static"][k] for k in live] + s["dynamic"].get(f, [])
        boxes = []
        for o in objs:
            center = velo_T_world[:3, :3] @ o["center"] + velo_T_world[:3, 3]
            rot, size = vehicle_axes(velo_T_world[:3, :3] @ o["rotation"], o["size"])
            try:
                box = Box(
                    center,
                    size,
                    rot,
                    o["label"],
                    lookup_class(o["label"], CLASS_MAP),
                    f"{o['semantic_id']}-{o['instance_id']}",
                )
            except ParameterError as exc:  # out of range (the box's own checks), here naming the file and object
                raise InputFileError(s["xml"], f"object {o['semantic_id']}-{o['instance_id']}: {exc}") from None
            boxes.append(box)
        return Frame(
            sequence=seq,
            frame_id=stem,
            timestamp=f,
            points=read_kitti_bin(s["scans"][f]),
            boxes=boxes,
            sensor_to_world=world_T_velo,
            scan_path=str(s["scans"][f]),
            label_path=s["xml"],
        )
