"""Generic reader: point-cloud files plus boxes in JSON.

Two ways to give the data:

1. ``SOURCE`` is a point-cloud file (``.bin`` KITTI-style N x 4 float32,
   ``.feather`` with x, y, z columns, or anything
   :func:`spotlights.geometry.io.load_points` reads: PLY, PCD, NPY, NPZ, XYZ,
   TXT) and ``boxes`` is a JSON file holding a **list of boxes** (default: the
   scan's name with ``.json``, e.g. ``scan.ply`` -> ``scan.json``). One frame.

2. ``SOURCE`` is a JSON **scene** file::

       {"frames": [
          {"scan": "scans/0001.ply",          # relative to the JSON file's folder
           "frame_id": "0001",                 # optional (default: the scan's stem)
           "timestamp": 1,                     # optional integer order key (default: the frame's index)
           "sequence": "drive-a",              # optional (default: "")
           "sensor_to_world": [[...4x4...]],   # optional
           "boxes": [ ...boxes... ]},
          ...]}

A box is an object with ``center`` [x, y, z] (metres, the box centre, in the
scan's frame, z up), ``size`` [length, width, height] (metres), either ``yaw``
(radians about +z, 0 = box x along the scan's x) or ``rotation`` (3x3 nested
list, row-major, whose columns are the box's forward, left, up axes), a
``label`` string, and optionally ``track_id`` (a string or integer; boxes with
the same ``track_id`` in different frames of one sequence are the same object).

Labels map to classes case-insensitively: the class names themselves (car,
truck, caravan, van, trailer) and every label the other readers know (KITTI,
KITTI-360, Argoverse 2) are accepted; anything else is not a vehicle of interest.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ...errors import InputFileError
from . import av2, kitti, kitti360
from .base import Box, Frame, SceneReader, lookup_class, orthonormalize

CLASS_MAP: dict[str, str | None] = {
    **{k: v for k, v in kitti360.CLASS_MAP.items()},
    **{k: v for k, v in kitti.CLASS_MAP.items()},
    **{k: v for k, v in av2.CLASS_MAP.items()},
    "car": "car", "truck": "truck", "caravan": "caravan", "van": "caravan", "trailer": "trailer",
}


def read_points_file(path: str | os.PathLike) -> np.ndarray:
    """Read a point-cloud file of any supported kind: (N, 3) float32 metres."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "scan file not found")
    suffix = path.suffix.lower()
    if suffix == ".bin":
        return kitti.read_kitti_bin(path)
    if suffix == ".feather":
        return av2.read_av2_sweep(path)
    from ...geometry.io import load_points

    return np.asarray(load_points(path), dtype=np.float32)


def _vec(v, n, path, what) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputFileError(path, f"{what} is not numeric") from None
    shape = (n,) if isinstance(n, int) else tuple(n)
    if a.shape != shape:
        raise InputFileError(path, f"{what} has shape {a.shape}, expected {shape}")
    if not np.all(np.isfinite(a)):
        raise InputFileError(path, f"{what} is not finite")
    return a


def parse_box(d, path, what: str) -> Box:
    """One JSON box -> :class:`Box`; raises InputFileError naming ``path`` and ``what`` if malformed."""
    if not isinstance(d, dict):
        raise InputFileError(path, f"{what} is not an object")
    for key in ("center", "size", "label"):
        if key not in d:
            raise InputFileError(path, f"{what} lacks {key!r}")
    center = _vec(d["center"], 3, path, f"{what} center")
    size = _vec(d["size"], 3, path, f"{what} size")
    if "rotation" in d:
        rot = _vec(d["rotation"], (3, 3), path, f"{what} rotation")
        if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-3) or np.linalg.det(rot) < 0:
            raise InputFileError(path, f"{what} rotation is not a proper rotation matrix")
        rot = orthonormalize(rot)
    elif "yaw" in d:
        try:
            yaw = float(d["yaw"])
        except (TypeError, ValueError):
            raise InputFileError(path, f"{what} yaw is not a number") from None
        rot = Box.from_yaw(center, size, yaw, "", None).rotation
    else:
        raise InputFileError(path, f"{what} needs 'yaw' or 'rotation'")
    label = str(d["label"])
    track = d.get("track_id", "")
    return Box(center, size, rot, label, lookup_class(label, CLASS_MAP), "" if track is None else str(track))


def _load_json(path: Path):
    if not path.is_file():
        raise InputFileError(path, "JSON file not found")
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"not valid JSON ({exc})") from None


class GenericReader(SceneReader):
    """A point-cloud file with a JSON box list, or a JSON scene file (see the module doc).

    Parameters
    ----------
    source : the scan file or the scene JSON.
    boxes : for a single scan, its JSON box list (default: ``source`` with ``.json``).
    """

    format = "generic"

    def __init__(self, source: str | os.PathLike, boxes: str | os.PathLike | None = None):
        source = Path(source)
        if not source.exists():
            raise InputFileError(source, "not found")
        self.root = str(source.parent)
        self._frames: list[dict] = []
        if source.suffix.lower() == ".json":
            data = _load_json(source)
            if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
                raise InputFileError(source, 'a scene file must be {"frames": [...]} (a bare box list needs a scan file as SOURCE)')
            for i, fr in enumerate(data["frames"]):
                what = f"frames[{i}]"
                if not isinstance(fr, dict) or "scan" not in fr or not isinstance(fr.get("boxes"), list):
                    raise InputFileError(source, f"{what} needs 'scan' and a 'boxes' list")
                scan = (source.parent / str(fr["scan"])).resolve()
                if not scan.is_file():
                    raise InputFileError(scan, f"scan file of {what} not found")
                pose = fr.get("sensor_to_world")
                self._frames.append(
                    dict(
                        scan=scan,
                        label_path=source,
                        frame_id=str(fr.get("frame_id", scan.stem)),
                        timestamp=int(fr.get("timestamp", i)),
                        sequence=str(fr.get("sequence", "")),
                        pose=None if pose is None else _vec(pose, (4, 4), source, f"{what} sensor_to_world"),
                        boxes=[parse_box(b, source, f"{what} box {j}") for j, b in enumerate(fr["boxes"])],
                    )
                )
        else:
            box_path = Path(boxes) if boxes is not None else source.with_suffix(".json")
            data = _load_json(box_path)
            if not isinstance(data, list):
                raise InputFileError(box_path, "expected a JSON list of boxes")
            self._frames.append(
                dict(scan=source, label_path=box_path, frame_id=source.stem, timestamp=0, sequence="", pose=None,
                     boxes=[parse_box(b, box_path, f"box {j}") for j, b in enumerate(data)])
            )
        if not self._frames:
            raise InputFileError(source, "no frames")
        keys = [(f["sequence"], f["frame_id"]) for f in self._frames]
        if len(set(keys)) != len(keys):
            raise InputFileError(source, "two frames share the same sequence and frame_id")
        order = sorted(range(len(self._frames)), key=lambda i: (self._frames[i]["sequence"], self._frames[i]["timestamp"], i))
        self._frames = [self._frames[i] for i in order]

    def frame_keys(self) -> list[tuple[str, str]]:
        return [(f["sequence"], f["frame_id"]) for f in self._frames]

    def load(self, key: tuple[str, str]) -> Frame:
        f = next(f for f in self._frames if (f["sequence"], f["frame_id"]) == key)
        return Frame(
            sequence=f["sequence"],
            frame_id=f["frame_id"],
            timestamp=f["timestamp"],
            points=read_points_file(f["scan"]),
            boxes=list(f["boxes"]),
            sensor_to_world=f["pose"],
            scan_path=str(f["scan"]),
            label_path=str(f["label_path"]),
        )
