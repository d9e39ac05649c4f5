"""Writing tracks: the generic sequence format with track ids, and a nuScenes tracking result JSON.

**Generic sequence JSON** (:func:`tracks_document`, the layout :class:`spotlights.data.real.generic.GenericReader`
reads, see :mod:`spotlights.data.real.generic`)::

    {"format": "spotlights-tracks", "format_version": 1,
     "frames": [{"sequence": "scene-0523", "frame_id": "...", "timestamp": 1535639716.699138,
                 "scan": "samples/LIDAR_TOP/....pcd.bin",   # only when the scan lies under the output's folder
                 "sensor_to_world": [[...4x4...]],          # when known
                 "boxes": [{"center": [x, y, z], "size": [l, w, h], "rotation": [[...3x3...]],
                            "label": "car", "track_id": "7", "score": 0.81, "velocity": [vx, vy, vz]}, ...]},
                ...]}

Boxes are in each frame's own coordinates (the dataset reader's sensor frame), metres; ``rotation`` rows, columns =
the box's forward, left, up axes; ``velocity`` m/s in the same frame. Every frame is written (an empty box list
where no track is reported). With ``scan`` on every frame the file is itself a generic sequence:
``real complete tracks.json --format generic --fuse ...`` reads it.

**nuScenes tracking result JSON** (:func:`nuscenes_tracking_document`, the nuScenes tracking challenge's format)::

    {"meta": {"use_camera": false, "use_lidar": true, ...},
     "results": {SAMPLE_TOKEN: [{"sample_token", "translation", "size": [w, l, h], "rotation": [qw, qx, qy, qz],
                                 "velocity": [vx, vy], "tracking_id", "tracking_name", "tracking_score"}, ...]}}

Boxes are moved into the global frame with each frame's ``sensor_to_world`` (boxes of a frame without one are
written as they are); ``frame_id`` is taken as the sample token. ``tracking_name``: the box's label when it is one of
nuScenes' tracking classes (:data:`NUSCENES_TRACKING_NAMES`), else the nuScenes name of its class
(:data:`NUSCENES_NAME_OF_CLASS`); boxes of a class with no nuScenes tracking name (construction) are left out.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..outputs import atomic_output
from .detections import DetectionFrame

TRACKS_FORMAT = "spotlights-tracks"
TRACKS_FORMAT_VERSION = 1

#: The nuScenes tracking challenge's classes.
NUSCENES_TRACKING_NAMES = ("bicycle", "bus", "car", "motorcycle", "pedestrian", "trailer", "truck")

#: The project's classes -> nuScenes tracking names (a van/caravan and an emergency vehicle are nuScenes cars).
NUSCENES_NAME_OF_CLASS = {
    "car": "car",
    "caravan": "car",
    "emergency": "car",
    "truck": "truck",
    "bus": "bus",
    "trailer": "trailer",
}


def _round(v, digits: int = 6) -> list[float]:
    return [round(float(x), digits) for x in v]


def _box_entry(frame: DetectionFrame, k: int) -> dict:
    b = frame.boxes[k]
    d: dict = {
        "center": _round(b.center),
        "size": _round(b.size),
        "rotation": [_round(row, 9) for row in b.rotation],
        "label": b.label,
        "track_id": b.track_id,
    }
    if b.score is not None:
        d["score"] = round(b.score, 6)
    if frame.velocities is not None and len(frame.velocities) == len(frame.boxes):
        d["velocity"] = _round(frame.velocities[k])
    return d


def tracks_document(frames: list[DetectionFrame], out_folder: str | os.PathLike | None = None) -> dict:
    """The generic sequence JSON of tracked frames (module docstring). ``out_folder``: the folder the file goes to;
    a frame's ``scan`` is written, relative to it, only when it lies under it."""
    base = None if out_folder is None else Path(os.path.abspath(out_folder))
    rows = []
    for f in frames:
        row: dict = {"sequence": f.sequence, "frame_id": f.frame_id, "timestamp": float(f.timestamp)}
        if f.scan_path and base is not None:
            scan = Path(os.path.abspath(f.scan_path))
            if base == scan.parent or base in scan.parents:
                row["scan"] = scan.relative_to(base).as_posix()
        if f.sensor_to_world is not None:
            row["sensor_to_world"] = [_round(r, 9) for r in np.asarray(f.sensor_to_world)]
        row["boxes"] = [_box_entry(f, k) for k in range(len(f.boxes))]
        rows.append(row)
    return {"format": TRACKS_FORMAT, "format_version": TRACKS_FORMAT_VERSION, "frames": rows}


def _quaternion(rotation: np.ndarray) -> list[float]:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    q = np.array([w, x, y, z])
    return _round(q if q[0] >= 0 else -q, 9)


def nuscenes_tracking_document(frames: list[DetectionFrame]) -> dict:
    """The nuScenes tracking result JSON of tracked frames (module docstring)."""
    results: dict[str, list] = {}
    for f in frames:
        pose = None if f.sensor_to_world is None else np.asarray(f.sensor_to_world, dtype=np.float64)
        entries = results.setdefault(f.frame_id, [])
        for k, b in enumerate(f.boxes):
            name = b.label if b.label in NUSCENES_TRACKING_NAMES else NUSCENES_NAME_OF_CLASS.get(b.cls or "")
            if name is None:
                continue
            v = np.zeros(3) if f.velocities is None or len(f.velocities) != len(f.boxes) else f.velocities[k]
            if pose is not None:
                b = b.transformed(pose)
                v = pose[:3, :3] @ v
            entries.append(
                {
                    "sample_token": f.frame_id,
                    "translation": _round(b.center),
                    "size": _round([b.size[1], b.size[0], b.size[2]]),
                    "rotation": _quaternion(b.rotation),
                    "velocity": _round(v[:2]),
                    "tracking_id": b.track_id,
                    "tracking_name": name,
                    "tracking_score": round(1.0 if b.score is None else b.score, 6),
                }
            )
    meta = {"use_camera": False, "use_lidar": True, "use_radar": False, "use_map": False, "use_external": False}
    return {"meta": meta, "results": results}


def write_json(document: dict, path: str | os.PathLike) -> Path:
    """Write ``document`` to ``path`` atomically (nothing half-written on failure); returns the path."""
    path = Path(path)
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(document, indent=1) + "\n", encoding="utf-8")
    return path


def write_tracks(frames: list[DetectionFrame], path: str | os.PathLike) -> Path:
    """Write tracked frames as the generic sequence JSON (:func:`tracks_document`) to ``path``."""
    return write_json(tracks_document(frames, Path(path).parent), path)


def write_nuscenes_tracking(frames: list[DetectionFrame], path: str | os.PathLike) -> Path:
    """Write tracked frames as a nuScenes tracking result JSON (:func:`nuscenes_tracking_document`) to ``path``."""
    return write_json(nuscenes_tracking_document(frames), path)
