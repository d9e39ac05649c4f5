"""KITTI 3D object benchmark reader (``training/`` or ``testing/`` folders).

Layout (the standard KITTI object format)::

    ROOT/velodyne/000123.bin          N x 4 float32: x, y, z, reflectance (Velodyne frame)
    ROOT/velodyne_reduced/000123.bin  the same, cropped to the camera field of view
    ROOT/label_2/000123.txt           one object per line, boxes in the rectified camera frame
    ROOT/calib/000123.txt             P0..P3, R0_rect, Tr_velo_to_cam, Tr_imu_to_velo

``ROOT`` may also be the KITTI folder that contains ``training/``.

A ``label_2`` line has 15 fields (16 with a detection score)::

    type truncated occluded alpha  x1 y1 x2 y2  h w l  x y z  rotation_y [score]

``(x, y, z)`` is the **bottom centre** of the box in the rectified camera frame
(x right, y down, z forward), ``h w l`` its height, width and length in metres,
``rotation_y`` the heading about the camera's y axis (0 = facing the camera's
+x). Boxes are brought into the Velodyne frame with

    p_velo = Tr_velo_to_cam^-1 @ R0_rect^-1 @ p_rect        (4x4 homogeneous forms)

(the inverse of the devkit's ``p_rect = R0_rect @ Tr_velo_to_cam @ p_velo``).
In the rectified camera frame the box's axes are forward
``(cos ry, 0, -sin ry)``, left ``(sin ry, 0, cos ry)`` and up ``(0, -1, 0)``.

Classes: ``Car`` -> car, ``Van`` -> caravan (van/caravan), ``Truck`` -> truck;
``Pedestrian``, ``Person_sitting``, ``Cyclist``, ``Tram``, ``Misc`` and
``DontCare`` are not vehicles of interest. KITTI object frames are independent
snapshots: boxes carry no track id.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ...errors import InputFileError, ParameterError
from ...geometry.boxes import MAX_BOXES_PER_FRAME, Box, box_range_problem
from ...geometry.rotations import orthonormalize
from .base import Frame, SceneReader, lookup_class
from .scans import read_kitti_bin  # noqa: F401  (read_kitti_bin re-exported: the KITTI scan format)

CLASS_MAP: dict[str, str | None] = {"car": "car", "van": "caravan", "truck": "truck"}

VELODYNE_FOLDERS = ("velodyne", "velodyne_reduced")


def read_calib(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Parse a KITTI ``calib/*.txt``; returns ``{"R0_rect": (3,3), "Tr_velo_to_cam": (3,4)}`` float64.

    Also accepts the tracking benchmark's names ``R_rect`` and ``Tr_velo_cam``.
    Raises :class:`InputFileError` when the file is missing or lacks either matrix.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "calibration file not found (every label_2 frame needs calib/<frame>.txt)")
    values: dict[str, list[float]] = {}
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            line = line.strip()
            if not line:
                continue
            key, sep, rest = line.partition(":")
            if not sep:
                key, _, rest = line.partition(" ")
            try:
                values[key.strip()] = [float(v) for v in rest.split()]
            except ValueError:
                raise InputFileError(path, f"line {lineno}: non-numeric value in {key.strip()!r}") from None
    out = {}
    for name, aliases, shape in (
        ("R0_rect", ("R0_rect", "R_rect"), (3, 3)),
        ("Tr_velo_to_cam", ("Tr_velo_to_cam", "Tr_velo_cam"), (3, 4)),
    ):
        found = next((values[a] for a in aliases if a in values), None)
        if found is None:
            raise InputFileError(path, f"missing {name} in calibration file")
        if len(found) != shape[0] * shape[1]:
            raise InputFileError(path, f"{name} has {len(found)} values, expected {shape[0] * shape[1]}")
        m = np.array(found, dtype=np.float64).reshape(shape)
        if not np.all(np.isfinite(m)):
            raise InputFileError(path, f"{name} holds a non-finite value")
        if np.linalg.cond(m[:, :3]) > 1e6:  # a rotation (condition number 1), never near singular
            raise InputFileError(path, f"{name} is singular: its 3x3 part is not a rotation")
        out[name] = m
    return out


def velo_from_rect(calib: dict[str, np.ndarray]) -> np.ndarray:
    """(4, 4) float64 transform rectified-camera frame -> Velodyne frame."""
    r0 = np.eye(4)
    r0[:3, :3] = calib["R0_rect"]
    tr = np.eye(4)
    tr[:3, :4] = calib["Tr_velo_to_cam"]
    return np.linalg.inv(tr) @ np.linalg.inv(r0)


#: The 14 numeric fields of a ``label_2`` line, in order (after the type).
LABEL_FIELDS = (
    "truncated", "occluded", "alpha", "x1", "y1", "x2", "y2", "h", "w", "l", "x", "y", "z", "rotation_y",
)  # fmt: skip


def parse_label_line(line: str, path, lineno: int) -> tuple[str, np.ndarray]:
    """Split one ``label_2`` line into (type, 14 float64 values); raises InputFileError if malformed:
    a wrong field count, a non-numeric field, or a NaN or infinite one (KITTI's own placeholders, such as
    DontCare's -1 and -1000, are finite)."""
    fields = line.split()
    if len(fields) not in (15, 16):
        raise InputFileError(
            path, f"line {lineno}: expected 15 or 16 fields (type, 14 numbers[, score]), got {len(fields)}"
        )
    try:
        nums = np.array([float(v) for v in fields[1:15]], dtype=np.float64)
    except ValueError:
        raise InputFileError(path, f"line {lineno}: non-numeric field in {line.strip()!r}") from None
    bad = np.flatnonzero(~np.isfinite(nums))
    if len(bad):
        k = int(bad[0])
        raise InputFileError(path, f"line {lineno}: {LABEL_FIELDS[k]} must be a finite number, got {fields[k + 1]!r}")
    return fields[0], nums


def box_from_label(kind: str, nums: np.ndarray, t_velo_rect: np.ndarray, track_id: str = "") -> Box:
    """A KITTI label (type + 14 numbers) -> :class:`Box` in the Velodyne frame.

    ``nums`` = truncated, occluded, alpha, x1, y1, x2, y2, h, w, l, x, y, z, rotation_y
    (camera-frame bottom centre, metres; rotation_y radians); ``t_velo_rect`` from :func:`velo_from_rect`.
    Raises :class:`ParameterError` for non-finite numbers or a box out of the range of
    :func:`~spotlights.geometry.boxes.box_range_problem` (:func:`read_labels` names the file and line).
    """
    if not np.all(np.isfinite(nums)):
        raise ParameterError("a KITTI label's numbers must be finite")
    problem = box_range_problem(nums[10:13], nums[7:10])  # before the transform: no overflow on the way
    h, w, length = nums[7:10]
    x, y, z = nums[10:13]
    ry = nums[13]
    if problem:
        raise ParameterError(f"box {problem}")
    c, s = np.cos(ry), np.sin(ry)
    axes_rect = np.array([[c, s, 0.0], [0.0, 0.0, -1.0], [-s, c, 0.0]])  # columns: forward, left, up
    center_rect = np.array([x, y - h / 2.0, z])  # camera y points down: centre is h/2 above the bottom
    rot = orthonormalize(t_velo_rect[:3, :3] @ axes_rect)
    center = t_velo_rect[:3, :3] @ center_rect + t_velo_rect[:3, 3]
    return Box(center, np.array([length, w, h], dtype=np.float64), rot, kind, lookup_class(kind, CLASS_MAP), track_id)


def read_labels(path: str | os.PathLike, t_velo_rect: np.ndarray) -> list[Box]:
    """Read a ``label_2`` file: every line as a :class:`Box` in the Velodyne frame (including ``DontCare``)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "label file not found")
    boxes = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            if not line.strip():
                continue
            if len(boxes) >= MAX_BOXES_PER_FRAME:
                raise InputFileError(path, f"more than {MAX_BOXES_PER_FRAME:,} boxes in one frame")
            kind, nums = parse_label_line(line, path, lineno)
            try:
                boxes.append(box_from_label(kind, nums, t_velo_rect))
            except ParameterError as exc:  # out of range (the box's own checks), here naming the file and line
                raise InputFileError(path, f"line {lineno}: {exc}") from None
    return boxes


class KittiReader(SceneReader):
    """KITTI object frames: one :class:`Frame` per ``label_2/*.txt``.

    Parameters
    ----------
    root : the ``training`` (or ``testing``) folder, or the folder containing ``training/``.
    velodyne : ``"auto"`` (``velodyne/`` if present, else ``velodyne_reduced/``),
        ``"velodyne"`` or ``"velodyne_reduced"``.
    """

    format = "kitti"

    def __init__(self, root: str | os.PathLike, velodyne: str = "auto"):
        root = Path(root)
        if not root.is_dir():
            raise InputFileError(root, "not a folder")
        if not (root / "label_2").is_dir() and (root / "training" / "label_2").is_dir():
            root = root / "training"
        if not (root / "label_2").is_dir():
            raise InputFileError(root, "not a KITTI object folder: no label_2/ inside")
        if velodyne == "auto":
            found = [v for v in VELODYNE_FOLDERS if (root / v).is_dir()]
            if not found:
                raise InputFileError(root, "no velodyne/ or velodyne_reduced/ folder")
            velodyne = found[0]
        elif velodyne not in VELODYNE_FOLDERS:
            raise InputFileError(root, f"unknown velodyne folder {velodyne!r} (velodyne or velodyne_reduced)")
        elif not (root / velodyne).is_dir():
            raise InputFileError(root / velodyne, "folder not found")
        self.root = str(root)
        self.velodyne = velodyne
        self._frames = sorted(p.stem for p in (root / "label_2").glob("*.txt"))
        if not self._frames:
            raise InputFileError(root / "label_2", "no label files (*.txt)")
        # Check every frame's companions up front: a missing calib or scan is an
        # error naming the file before any work is done.
        for stem in self._frames:
            for sub, ext, what in (("calib", ".txt", "calibration file"), (velodyne, ".bin", "scan file")):
                p = root / sub / f"{stem}{ext}"
                if not p.is_file():
                    raise InputFileError(p, f"{what} not found for label_2/{stem}.txt")

    def frame_keys(self) -> list[tuple[str, str]]:
        return [("", stem) for stem in self._frames]

    def load(self, key: tuple[str, str]) -> Frame:
        stem = key[1]
        root = Path(self.root)
        calib = read_calib(root / "calib" / f"{stem}.txt")
        t = velo_from_rect(calib)
        label_path = root / "label_2" / f"{stem}.txt"
        boxes = read_labels(label_path, t)
        scan_path = root / self.velodyne / f"{stem}.bin"
        points = read_kitti_bin(scan_path)
        index = int(stem) if stem.isdigit() else 0
        return Frame(
            sequence="",
            frame_id=stem,
            timestamp=index,
            points=points,
            boxes=boxes,
            sensor_to_world=None,
            scan_path=str(scan_path),
            label_path=str(label_path),
        )
