"""Box files a user brings: a generic JSON box list, or a KITTI ``label_2`` file with its calibration.

Generic JSON (``*.json``), one of:

- a list of boxes ``[{"center": ..., "size": ..., "yaw": ..., "label": "car", "track_id": 7}, ...]``;
- a per-frame object ``{"boxes": [...], "timestamp": 0.1, "frame_index": 3, "frame_id": "0003",
  "sequence": "drive-a", "sensor_to_world": 4x4}`` (every key but ``boxes`` optional);
- a single box object (with ``center``).

A box's keys are those of :func:`spotlights.geometry.box_json.box_from_dict` (centre, size
l/w/h, ``yaw`` or a full ``rotation``, ``label``, optional ``track_id``). Labels map to
classes with :data:`CLASS_MAP`: the class names themselves, ``van``, and every label of
the KITTI, KITTI-360, Argoverse 2 and nuScenes readers, case-insensitively.

KITTI (``*.txt``): a ``label_2`` file (15 fields per line, or 16 with a detection
score) in the rectified camera frame; it needs the frame's ``calib`` file to be
put in the Velodyne frame (:mod:`spotlights.data.real.kitti`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import InputFileError
from ...geometry.box_json import box_from_dict
from ...geometry.boxes import MAX_BOXES_PER_FRAME, Box, holds_non_numbers
from ...geometry.rotations import is_rotation
from ...inputs import read_json
from . import av2, kitti, kitti360, nuscenes
from .base import CLASSES, lookup_class

CLASS_MAP: dict[str, str | None] = {
    **kitti360.CLASS_MAP,
    **kitti.CLASS_MAP,
    **av2.CLASS_MAP,
    **nuscenes.CLASS_MAP,
    **{c: c for c in CLASSES},
    "van": "caravan",
}

FRAME_KEYS = ("timestamp", "frame_index", "frame_id", "sequence", "sensor_to_world")


@dataclass
class BoxFile:
    """The boxes of one file plus the per-frame keys it may carry (``None`` when absent).

    ``timestamp`` is kept as given (an int or a float), ``frame_index`` an int; ``sensor_to_world`` (4, 4) float64.
    """

    path: Path
    boxes: list[Box]
    timestamp: float | None = None
    frame_index: int | None = None
    frame_id: str | None = None
    sequence: str | None = None
    sensor_to_world: np.ndarray | None = None
    extra: dict = field(default_factory=dict)


def with_class(box: Box) -> Box:
    """The box with ``cls`` looked up from its label in :data:`CLASS_MAP` (None when not a vehicle class)."""
    return box.replace(cls=lookup_class(box.label, CLASS_MAP))


def parse_boxes(items, path, require_label: bool = True, axes=None, what: str = "box") -> list[Box]:
    """A JSON list of boxes -> :class:`Box` list with classes (see :func:`box_from_dict`)."""
    if not isinstance(items, list):
        raise InputFileError(path, "expected a JSON list of boxes")
    if len(items) > MAX_BOXES_PER_FRAME:
        raise InputFileError(path, f"{len(items):,} boxes in one frame; at most {MAX_BOXES_PER_FRAME:,} are read")
    return [
        with_class(box_from_dict(d, path, f"{what} {j}", require_label=require_label, axes=axes))
        for j, d in enumerate(items)
    ]


def _number(v, path, what, cast=float):
    if isinstance(v, (bool, str)):  # true is not 1 and "3" is not 3 in a box file
        raise InputFileError(path, f"{what} must be a number, got {v!r:.60}")
    try:
        x = cast(v)
    except (TypeError, ValueError):
        raise InputFileError(path, f"{what} must be a number, got {v!r}") from None
    if not np.isfinite(x):
        raise InputFileError(path, f"{what} must be finite")
    if cast is int and float(v) != x:
        raise InputFileError(path, f"{what} must be a whole number, got {v!r}")
    return x


def parse_frame_keys(d: dict, path, what: str = "frame") -> dict:
    """The optional per-frame keys of a JSON object, validated (see :class:`BoxFile`)."""
    out = {}
    if d.get("timestamp") is not None:  # kept as given: an int stays exact, a float is not cut
        ts = d["timestamp"]
        out["timestamp"] = (
            ts if isinstance(ts, int) and not isinstance(ts, bool) else _number(ts, path, f"{what} timestamp")
        )
    if d.get("frame_index") is not None:
        out["frame_index"] = _number(d["frame_index"], path, f"{what} frame_index", int)
    for key in ("frame_id", "sequence"):
        v = d.get(key)
        if v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, (str, int)):  # a list or an object is no name
            raise InputFileError(path, f"{what} {key} must be a string, got {v!r:.60}")
        out[key] = str(v)
    if d.get("sensor_to_world") is not None:
        try:
            m = np.asarray(d["sensor_to_world"], dtype=np.float64)
        except (TypeError, ValueError):
            m = np.zeros(0)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)) or holds_non_numbers(d["sensor_to_world"]):
            raise InputFileError(path, f"{what} sensor_to_world must be a finite 4x4 matrix")
        if not is_rotation(m[:3, :3]) or not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
            raise InputFileError(  # a singular or scaled pose would fuse frames into a collapsed or stretched world
                path,
                f"{what} sensor_to_world must be a rigid transform (a rotation, orthonormal within 1e-3 with "
                "determinant +1, a translation, and the last row 0 0 0 1)",
            )
        out["sensor_to_world"] = m
    return out


def read_json_boxes(path: str | os.PathLike, require_label: bool = True, axes=None) -> BoxFile:
    """Read a generic JSON box file (list, per-frame object, or one box): see the module docstring."""
    p = Path(path)
    data = read_json(p)
    if isinstance(data, list):
        return BoxFile(p, parse_boxes(data, p, require_label, axes))
    if isinstance(data, dict) and "boxes" in data:
        return BoxFile(p, parse_boxes(data["boxes"], p, require_label, axes), **parse_frame_keys(data, p))
    if isinstance(data, dict) and "center" in data:
        return BoxFile(p, [with_class(box_from_dict(data, p, "box", require_label=require_label, axes=axes))])
    raise InputFileError(p, 'expected a JSON list of boxes, {"boxes": [...]} or one box with a "center"')


def read_kitti_label_file(path: str | os.PathLike, calib: str | os.PathLike | None) -> BoxFile:
    """A KITTI ``label_2`` file in the Velodyne frame of its ``calib`` file (required)."""
    p = Path(path)
    if calib is None:
        raise InputFileError(
            p, "a KITTI label file is in the camera frame: give its calibration with --calib calib/FRAME.txt"
        )
    t = kitti.velo_from_rect(kitti.read_calib(calib))
    return BoxFile(p, kitti.read_labels(p, t))


def read_box_file(
    path: str | os.PathLike, calib: str | os.PathLike | None = None, require_label: bool = True, axes=None
) -> BoxFile:
    """Any box file of the module docstring, by suffix: ``.json`` generic, ``.txt`` KITTI ``label_2``.

    ``calib`` is required for (and only allowed with) a KITTI label file. ``axes``: see
    :func:`box_from_dict` (JSON boxes given in a scan with another up/forward axis).
    """
    p = Path(path)
    if not p.exists():
        raise InputFileError(p, "box file not found")
    suffix = p.suffix.lower()
    if suffix == ".txt":
        return read_kitti_label_file(p, calib)
    if calib is not None:
        raise InputFileError(p, "--calib applies to KITTI label_2 .txt box files only")
    if suffix == ".json":
        return read_json_boxes(p, require_label=require_label, axes=axes)
    raise InputFileError(p, f"unknown box file type {suffix!r} (generic .json, or a KITTI label_2 .txt with --calib)")
