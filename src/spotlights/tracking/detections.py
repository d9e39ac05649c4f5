"""A detector's boxes as input: per frame, boxes with a class and a score and no identity.

Three formats (:data:`FORMATS`), each read into a list of :class:`DetectionFrame` (boxes in the frame the
dataset reader of the same data uses, with :attr:`~spotlights.geometry.boxes.Box.score` set):

``nuscenes``: a nuScenes detection result JSON (what CenterPoint, BEVFusion and the nuScenes devkit write)::

    {"meta": {...}, "results": {SAMPLE_TOKEN: [{"translation": [x, y, z], "size": [w, l, h],
      "rotation": [qw, qx, qy, qz], "velocity": [vx, vy], "detection_name": "car",
      "detection_score": 0.83, "attribute_name": "..."}, ...], ...}}

read beside the nuScenes folder that holds those samples (:class:`~spotlights.data.real.nuscenes.NuScenesReader`):
boxes are in the global frame with nuScenes' **(width, length, height)** size order; they are moved into each
keyframe's LIDAR_TOP frame with the inverse of that frame's ``sensor_to_world``, as the reader moves annotations,
and their ``velocity`` (global frame, m/s; optional, NaN or null where a detector gives none) is turned with them.
Frames are the folder's keyframes (a keyframe without results has no box); results of sample tokens that are not
keyframes of the folder are left out (logged), and none matching at all is an error.

``kitti``: KITTI-format results with a score column, in the rectified camera frame, moved into the Velodyne frame
through the calibration as :mod:`spotlights.data.real.kitti` does. Either a folder of per-frame files
``000123.txt`` (object layout, 16 fields: ``type truncated occluded alpha x1 y1 x2 y2 h w l x y z rot_y score``),
or one file with a leading frame column (tracking layout, 18 fields:
``frame track_id type truncated occluded alpha x1 y1 x2 y2 h w l x y z rot_y score``; 17 fields: the same without
``track_id``). The calibration (``calib``) is one file (``R0_rect``/``R_rect`` and ``Tr_velo_to_cam``/``Tr_velo_cam``)
or a folder with ``FRAME.txt`` per frame (object layout) or ``SEQUENCE.txt`` (tracking layout: the file's name).
KITTI runs at 10 Hz: a frame's time is its number x 0.1 s. Scores must lie in [0, 1]; detectors that write logits
(PointRCNN) are read with ``logit_scores=True`` (a sigmoid).

``generic``: the project's box JSON (:func:`spotlights.geometry.box_json.box_from_dict`) with an optional ``score``:
a sequence JSON ``{"sequence": ..., "frames": [{"boxes": [...] or "FILE.json", "frame_id", "timestamp",
"frame_index", "sensor_to_world"}, ...]}`` (``scan`` is optional here), a folder of per-frame box files, or one box
file (one frame). Time: ``timestamp`` in seconds, else ``frame_index`` x 0.1 s, else the position x 0.1 s.

Classes: :func:`detector_class` maps nuScenes and KITTI detector class names (and the project's own, and every
label the dataset readers know) to :data:`spotlights.data.real.CLASSES`; other classes (pedestrians, cyclists,
cones) map to None and are left out by :func:`filter_detections` unless asked for.

Caps: at most :data:`MAX_FRAMES` frames and :data:`MAX_BOXES_PER_FRAME` boxes a frame (the nuScenes detection
challenge allows 500); a file beyond them is refused. Every damaged file is an :class:`InputFileError` naming it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..data.real.base import CLASSES
from ..data.real.boxfiles import CLASS_MAP as BOX_FILE_CLASSES
from ..data.real.boxfiles import parse_boxes, parse_frame_keys, read_json_boxes
from ..data.real.generic import frame_name, natural_key
from ..data.real.kitti import box_from_label, read_calib, velo_from_rect
from ..data.real.nuscenes import NuScenesReader
from ..errors import InputFileError, ParameterError
from ..geometry.boxes import MAX_BOX_CENTER_M, Box
from ..geometry.rotations import quaternion_to_matrix
from ..inputs import path_inside, read_json

log = logging.getLogger(__name__)

FORMATS = ("nuscenes", "kitti", "generic")

#: Most frames one detection input may hold (a nuScenes trainval split has 34,149 keyframes).
MAX_FRAMES = 100_000

#: Most boxes one frame may hold (the nuScenes detection challenge keeps at most 500 a sample).
MAX_BOXES_PER_FRAME = 1000

#: The largest speed a detection may report, m/s (about 720 km/h): beyond it a velocity is a damaged value.
MAX_VELOCITY_MPS = 200.0

#: Seconds between frames where the input gives only frame numbers (KITTI's 10 Hz).
FRAME_PERIOD_S = 0.1

#: nuScenes detection and tracking class names -> the project's classes (None: not a vehicle of interest).
NUSCENES_DETECTION_CLASSES: dict[str, str | None] = {
    "car": "car",
    "truck": "truck",
    "bus": "bus",
    "trailer": "trailer",
    "construction_vehicle": "construction",
    "pedestrian": None,
    "bicycle": None,
    "motorcycle": None,
    "traffic_cone": None,
    "barrier": None,
}

#: KITTI detector class names (OpenPCDet, PointRCNN, the KITTI label set) -> the project's classes.
KITTI_DETECTION_CLASSES: dict[str, str | None] = {
    "car": "car",
    "van": "caravan",
    "truck": "truck",
    "pedestrian": None,
    "person_sitting": None,
    "cyclist": None,
    "tram": None,
    "misc": None,
    "dontcare": None,
}

#: Every detector class name this module knows (lower case) -> the project's class.
DETECTOR_CLASSES: dict[str, str | None] = {**BOX_FILE_CLASSES, **NUSCENES_DETECTION_CLASSES, **KITTI_DETECTION_CLASSES}


def detector_class(name: str) -> str | None:
    """The project class (one of :data:`spotlights.data.real.CLASSES`) of a detector's class name, case-insensitive;
    None for a class that is not a vehicle of interest or is unknown."""
    return DETECTOR_CLASSES.get(str(name).strip().lower())


@dataclass
class DetectionFrame:
    """The boxes of one frame (a detector's, a tracker's or ground truth).

    Attributes
    ----------
    sequence : the scene / drive the frame belongs to (tracks are made within one sequence).
    frame_id : the frame's name in its sequence (nuScenes: the sample token; KITTI: ``"000123"``).
    timestamp : seconds (any origin), orders the frames of a sequence.
    boxes : :class:`~spotlights.geometry.boxes.Box` list in the frame's own coordinates (the sensor frame of the
        dataset reader: nuScenes LIDAR_TOP, KITTI Velodyne; a generic file's own), metres.
    sensor_to_world : (4, 4) float64 pose of those coordinates in a fixed world frame, or None (a static sensor,
        or boxes already in one frame for the whole sequence).
    scan_path : the frame's scan file when known (provenance), else ``""``.
    velocities : (len(boxes), 3) float64 m/s in the frame's coordinates (a tracker's estimate, or what a detector
        reported: NaN rows where it gave none), or None (nothing known).
    """

    sequence: str
    frame_id: str
    timestamp: float
    boxes: list[Box]
    sensor_to_world: np.ndarray | None = None
    scan_path: str = ""
    velocities: np.ndarray | None = None


def _cap(n: int, path, what: str = "boxes in one frame") -> None:
    limit = MAX_BOXES_PER_FRAME if what.startswith("boxes") else MAX_FRAMES
    if n > limit:
        raise InputFileError(path, f"{n} {what}, more than the cap of {limit}")


def _finite(value, n: int, path, what: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise InputFileError(path, f"{what} must be {n} finite numbers, got {str(value)[:60]}")
    return a


def _score(value, path, what: str, logit: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputFileError(path, f"{what} must be a finite number, got {str(value)[:40]}")
    x = float(value)
    if logit:
        return 1.0 / (1.0 + math.exp(-x)) if x >= 0 else math.exp(x) / (1.0 + math.exp(x))
    if not 0.0 <= x <= 1.0:
        raise InputFileError(path, f"{what} {x:g} is outside [0, 1] (logits? read them with logit scores)")
    return x


# --- nuScenes -------------------------------------------------------------------------------------------


def nuscenes_box(d: object, path, what: str) -> Box:
    """One nuScenes result box (a dict, see the module docstring) as a :class:`Box` in the **global** frame, with
    ``label`` = ``detection_name`` (or ``tracking_name``), ``cls`` from :func:`detector_class` and the score."""
    if not isinstance(d, dict):
        raise InputFileError(path, f"{what} is not a JSON object")
    name_key = "detection_name" if "detection_name" in d else "tracking_name"
    score_key = "detection_score" if "detection_score" in d else "tracking_score"
    for k in ("translation", "size", "rotation", name_key, score_key):
        if k not in d:
            raise InputFileError(path, f"{what} has no {k!r}")
    t = _finite(d["translation"], 3, path, f"{what} translation")
    wlh = _finite(d["size"], 3, path, f"{what} size (w, l, h)")
    q = _finite(d["rotation"], 4, path, f"{what} rotation (quaternion w, x, y, z)")
    if np.abs(t).max() > MAX_BOX_CENTER_M:
        raise InputFileError(path, f"{what} translation is out of range (±{MAX_BOX_CENTER_M:.0e} m)")
    if np.any(wlh <= 0):
        raise InputFileError(path, f"{what} size (w, l, h) must be positive, got {wlh.tolist()}")
    if np.linalg.norm(q) < 1e-6:
        raise InputFileError(path, f"{what} rotation quaternion is zero")
    if not isinstance(d[name_key], str):
        raise InputFileError(path, f"{what} {name_key} must be a string, got {str(d[name_key])[:40]}")
    score = _score(d[score_key], path, f"{what} {score_key}")
    try:
        return Box(
            t, (wlh[1], wlh[0], wlh[2]), quaternion_to_matrix(*q), d[name_key], detector_class(d[name_key]), "", score
        )
    except ParameterError as exc:
        raise InputFileError(path, f"{what}: {exc}") from None


def nuscenes_velocity(d: dict, path, what: str) -> np.ndarray:
    """(3,) float64 a nuScenes result box's ``velocity`` ``[vx, vy]`` (global frame, m/s) as ``(vx, vy, 0)``; NaN
    where the box has none: no key, ``null`` or NaN values, or exactly ``[0, 0]`` (what exporters of detectors that
    do not estimate velocity write; a parked car's own estimate is never exactly zero, and a tracker loses little
    by not reading it)."""
    v = d.get("velocity")
    if v is None:
        return np.full(3, np.nan)
    if not isinstance(v, list) or len(v) != 2:
        raise InputFileError(path, f"{what} velocity must be [vx, vy], got {str(v)[:40]}")
    out = np.full(3, np.nan)
    for k, x in enumerate(v):
        if x is None:
            continue
        if isinstance(x, bool) or not isinstance(x, (int, float)) or math.isinf(x):
            raise InputFileError(path, f"{what} velocity must be two numbers (m/s), got {str(v)[:40]}")
        out[k] = float(x)
    if np.all(out[:2] == 0.0):
        return np.full(3, np.nan)
    if np.all(np.isfinite(out[:2])):
        if np.abs(out[:2]).max() > MAX_VELOCITY_MPS:
            raise InputFileError(path, f"{what} velocity is out of range (±{MAX_VELOCITY_MPS:g} m/s)")
        out[2] = 0.0
    return out


def read_nuscenes_detections(
    path: str | os.PathLike, data: str | os.PathLike, scenes: list[str] | None = None
) -> list[DetectionFrame]:
    """A nuScenes detection result JSON read beside the nuScenes folder ``data`` (see the module docstring).

    Returns one :class:`DetectionFrame` per LIDAR_TOP keyframe of ``data`` (``scenes``: those scenes only), in scene
    then time order: ``frame_id`` = sample token, ``timestamp`` = seconds, boxes in the LIDAR_TOP frame,
    ``sensor_to_world`` the keyframe's pose, ``velocities`` (K, 3) the boxes' reported velocities in that frame
    (m/s; NaN rows where a box reports none: :func:`nuscenes_velocity`). :class:`InputFileError` for a damaged file or folder.
    """
    path = Path(path)
    reader = NuScenesReader(data, scenes)
    doc = read_json(path, "nuScenes detection result file")
    if not isinstance(doc, dict) or not isinstance(doc.get("results"), dict):
        raise InputFileError(
            path, 'not a nuScenes result file: expected {"meta": ..., "results": {SAMPLE_TOKEN: [...]}}'
        )
    results = doc["results"]
    keys = reader.frame_keys()
    _cap(len(keys), path, "frames")
    tokens = {k[1] for k in keys}
    unknown = [t for t in results if t not in tokens]
    if results and len(unknown) == len(results):
        raise InputFileError(path, f"no sample token of the results is a keyframe of {data} (e.g. {unknown[0]!r})")
    if unknown:
        log.info("%s: %d sample token(s) of the results are not keyframes of %s: left out", path, len(unknown), data)
    frames = []
    for key in keys:
        rows = results.get(key[1], [])
        if not isinstance(rows, list):
            raise InputFileError(path, f"results[{key[1]!r}] is not a list of boxes")
        _cap(len(rows), path)
        world = reader.sensor_to_world(key)
        to_sensor = np.linalg.inv(world)
        boxes = [nuscenes_box(r, path, f"results[{key[1]!r}][{i}]").transformed(to_sensor) for i, r in enumerate(rows)]
        velocities = (
            np.array(
                [nuscenes_velocity(r, path, f"results[{key[1]!r}][{i}]") for i, r in enumerate(rows)], dtype=np.float64
            ).reshape(-1, 3)
            @ to_sensor[:3, :3].T
        )
        us, scan = reader.keyframe(key)
        frames.append(DetectionFrame(key[0], key[1], us * 1e-6, boxes, world, scan, velocities))
    return frames


# --- KITTI ----------------------------------------------------------------------------------------------


def _kitti_row(fields: list[str], path, lineno: int, t_velo_rect, logit: bool, track_id: str = "") -> Box:
    """``type`` + 14 numbers + score (16 fields) -> a Velodyne-frame :class:`Box` with its score."""
    if len(fields) != 16:
        raise InputFileError(path, f"line {lineno}: expected a type, 14 numbers and a score, got {len(fields)} fields")
    try:
        nums = np.array([float(v) for v in fields[1:16]], dtype=np.float64)
    except ValueError:
        raise InputFileError(path, f"line {lineno}: non-numeric field in {' '.join(fields)[:80]!r}") from None
    if not np.all(np.isfinite(nums)):
        raise InputFileError(path, f"line {lineno}: every number must be finite")
    if np.any(nums[7:10] <= 0):
        raise InputFileError(path, f"line {lineno}: h, w, l must be positive, got {nums[7:10].tolist()}")
    score = _score(float(nums[14]), path, f"line {lineno}: score", logit)
    try:
        box = box_from_label(fields[0], nums[:14], t_velo_rect, track_id)
    except ParameterError as exc:
        raise InputFileError(path, f"line {lineno}: {exc}") from None
    return box.replace(cls=detector_class(fields[0]), score=score)


def _calib_file(calib: Path, name: str) -> Path:
    return calib / f"{name}.txt" if calib.is_dir() else calib


def read_kitti_detections(
    path: str | os.PathLike, calib: str | os.PathLike, logit_scores: bool = False
) -> list[DetectionFrame]:
    """KITTI-format results with a score column (see the module docstring): a folder of per-frame files, or one
    tracking-layout file with a leading frame column. ``calib``: one calibration file, or a folder of them
    (``FRAME.txt`` per frame, ``SEQUENCE.txt`` for one tracking file). Boxes come in the Velodyne frame; a tracking
    file's frames run from 0 to its last frame (frames without a row have no box), ``sequence`` = its name."""
    path, calib = Path(path), Path(calib)
    if not path.exists():
        raise InputFileError(path, "detection file or folder not found")
    if not calib.exists():
        raise InputFileError(calib, "calibration file or folder not found")
    frames = []
    if path.is_dir():
        files = sorted(path.glob("*.txt"), key=lambda p: natural_key(p.stem))
        if not files:
            raise InputFileError(path, "no per-frame result files (*.txt)")
        _cap(len(files), path, "frames")
        cached: dict[Path, np.ndarray] = {}
        for pos, f in enumerate(files):
            cf = _calib_file(calib, f.stem)
            if cf not in cached:
                cached[cf] = velo_from_rect(read_calib(cf))
            boxes = []
            with open(f, encoding="utf-8", errors="replace") as fh:
                for lineno, line in enumerate(fh, 1):
                    if line.strip():
                        boxes.append(_kitti_row(line.split(), f, lineno, cached[cf], logit_scores))
            _cap(len(boxes), f)
            frames.append(DetectionFrame("", f.stem, pos * FRAME_PERIOD_S, boxes))
        if all(f.frame_id.isdigit() for f in frames):  # KITTI names: the frame number is its time
            frames = [dataclasses.replace(f, timestamp=int(f.frame_id) * FRAME_PERIOD_S) for f in frames]
        return frames
    t = velo_from_rect(read_calib(_calib_file(calib, path.stem)))
    by_frame: dict[int, list[Box]] = {}
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            fields = line.split()
            if not fields:
                continue
            if len(fields) not in (17, 18):
                raise InputFileError(
                    path,
                    f"line {lineno}: expected 18 fields (frame track_id type ... rot_y score) or 17, got {len(fields)}",
                )
            try:
                frame = int(fields[0])
            except ValueError:
                raise InputFileError(path, f"line {lineno}: frame must be a whole number, got {fields[0]!r}") from None
            if not 0 <= frame < MAX_FRAMES:
                raise InputFileError(path, f"line {lineno}: frame {frame} is outside 0..{MAX_FRAMES - 1}")
            rest = fields[2:] if len(fields) == 18 else fields[1:]
            boxes = by_frame.setdefault(frame, [])
            boxes.append(_kitti_row(rest, path, lineno, t, logit_scores))
            _cap(len(boxes), path)
    if not by_frame:
        raise InputFileError(path, "no detection rows")
    for k in range(max(by_frame) + 1):
        frames.append(DetectionFrame(path.stem, f"{k:06d}", k * FRAME_PERIOD_S, by_frame.get(k, [])))
    return frames


# --- generic --------------------------------------------------------------------------------------------


def _generic_frame(keys: dict, boxes: list[Box], name: str, sequence: str, path) -> dict:
    _cap(len(boxes), path)
    return dict(
        sequence=keys.get("sequence", sequence),
        frame_id=keys.get("frame_id", name),
        timestamp=keys.get("timestamp"),
        frame_index=keys.get("frame_index"),
        sensor_to_world=keys.get("sensor_to_world"),
        boxes=boxes,
    )


def _folder_frames(path: Path) -> list[dict]:
    """The raw frames of a folder of per-frame box files (natural order of their names)."""
    files = sorted(path.glob("*.json"), key=lambda p: natural_key(p.stem))
    if not files:
        raise InputFileError(path, "no box files (*.json)")
    _cap(len(files), path, "frames")
    raw = []
    for file in files:
        bf = read_json_boxes(file)
        keys = {
            k: v
            for k, v in vars(bf).items()
            if k in ("timestamp", "frame_index", "frame_id", "sequence", "sensor_to_world") and v is not None
        }
        raw.append(_generic_frame(keys, bf.boxes, file.stem, path.name, file))
    return raw


def _listed_frame(path: Path, fr: object, i: int, default_seq: str) -> dict:
    """The raw frame of entry ``i`` of a sequence JSON's ``frames``: its boxes inline or in a box file (whose
    frame keys fill those the entry does not give)."""
    what = f"frames[{i}]"
    if not isinstance(fr, dict) or not isinstance(fr.get("boxes"), (list, str)):
        raise InputFileError(path, f"{what} needs 'boxes' (a list of boxes, or a box file path)")
    keys = parse_frame_keys(fr, path, what)
    if isinstance(fr["boxes"], str):
        bp = path_inside(path.parent, fr["boxes"], path, f"{what} boxes")
        bf = read_json_boxes(bp)
        boxes = bf.boxes
        for k in ("timestamp", "frame_index", "frame_id", "sequence", "sensor_to_world"):
            if k not in keys and getattr(bf, k) is not None:
                keys[k] = getattr(bf, k)
    else:
        _cap(len(fr["boxes"]), path)
        boxes = parse_boxes(fr["boxes"], path, what=f"{what} box")
    name = frame_name(Path(fr["scan"])) if isinstance(fr.get("scan"), str) else f"{i:06d}"
    return _generic_frame(keys, boxes, name, default_seq, path)


def _file_frames(path: Path) -> list[dict]:
    """The raw frames of one JSON file: a sequence JSON (a ``frames`` list), else one box file."""
    doc = read_json(path)
    if isinstance(doc, dict) and isinstance(doc.get("frames"), list):
        _cap(len(doc["frames"]), path, "frames")
        default_seq = str(doc["sequence"]) if doc.get("sequence") is not None else ""
        return [_listed_frame(path, fr, i, default_seq) for i, fr in enumerate(doc["frames"])]
    bf = read_json_boxes(path)
    keys = {k: getattr(bf, k) for k in ("timestamp", "frame_index", "frame_id", "sequence", "sensor_to_world")}
    return [_generic_frame({k: v for k, v in keys.items() if v is not None}, bf.boxes, path.stem, "", path)]


def _check_unique_frames(path: Path, raw: list[dict]) -> None:
    """Refuse two raw frames with the same (sequence, frame_id)."""
    seen = set()
    for f in raw:
        key = (f["sequence"], f["frame_id"])
        if key in seen:
            raise InputFileError(path, f"two frames share the sequence {key[0]!r} and frame_id {key[1]!r}")
        seen.add(key)


def _timed_frames(path: Path, raw: list[dict]) -> list[DetectionFrame]:
    """The raw frames as :class:`DetectionFrame` s with times in seconds, sequence by sequence (sorted): their
    timestamps when every frame has one, else their frame indices, else their positions, times the frame period."""
    by_seq: dict[str, list[dict]] = {}
    for f in raw:
        by_seq.setdefault(f["sequence"], []).append(f)
    frames = []
    for seq in sorted(by_seq):
        fs = by_seq[seq]
        has_t = [f["timestamp"] is not None for f in fs]
        has_i = [f["frame_index"] is not None for f in fs]
        if any(has_t) and not all(has_t):
            raise InputFileError(
                path, f"sequence {seq!r} mixes frames with and without a timestamp: give every frame one"
            )
        for pos, f in enumerate(fs):
            if all(has_t):
                t = float(f["timestamp"])
            elif all(has_i):
                t = f["frame_index"] * FRAME_PERIOD_S
            else:
                t = pos * FRAME_PERIOD_S
            frames.append(DetectionFrame(seq, f["frame_id"], t, f["boxes"], f["sensor_to_world"]))
    return frames


def read_generic_detections(path: str | os.PathLike) -> list[DetectionFrame]:
    """The project's box JSON with optional scores (see the module docstring): a sequence JSON, a folder of
    per-frame box files, or one box file. Frames are ordered by sequence then time."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(path, "detection file or folder not found")
    raw = _folder_frames(path) if path.is_dir() else _file_frames(path)
    _check_unique_frames(path, raw)
    frames = _timed_frames(path, raw)
    frames.sort(key=lambda f: (f.sequence, f.timestamp))
    for a, b in zip(frames, frames[1:]):
        if a.sequence == b.sequence and not b.timestamp > a.timestamp:
            raise InputFileError(
                path,
                f"sequence {a.sequence!r}: frames {a.frame_id!r} and {b.frame_id!r} share the time {a.timestamp:g} s "
                "(a sequence's frames need distinct times)",
            )
    return frames


# --- one entry --------------------------------------------------------------------------------------------


def read_detections(
    path: str | os.PathLike,
    format: str,
    data: str | os.PathLike | None = None,
    calib: str | os.PathLike | None = None,
    logit_scores: bool = False,
) -> list[DetectionFrame]:
    """Read detections of ``format`` (one of :data:`FORMATS`): ``data`` is the nuScenes folder (required for
    ``nuscenes``; for ``kitti`` a KITTI folder whose ``calib/`` is used when ``calib`` is not given), ``calib`` the
    KITTI calibration file or folder, ``logit_scores`` KITTI scores given as logits. :class:`ParameterError` for a
    missing or misplaced parameter, :class:`InputFileError` for a damaged file."""
    if format not in FORMATS:
        raise ParameterError(f"format: unknown detection format {format!r}; choose one of {', '.join(FORMATS)}")
    if format == "nuscenes":
        if data is None:
            raise ParameterError("data: nuScenes detections are read beside their nuScenes folder; name it")
        if calib is not None:
            raise ParameterError("calib: applies to KITTI detections only")
        return read_nuscenes_detections(path, data)
    if format == "kitti":
        if calib is None and data is not None:
            calib = Path(data) / "calib"
            if not calib.exists() and (Path(data) / "training" / "calib").exists():
                calib = Path(data) / "training" / "calib"
        if calib is None:
            raise ParameterError(
                "calib: KITTI detections are in the camera frame; name their calibration file or folder"
            )
        return read_kitti_detections(path, calib, logit_scores)
    if data is not None or calib is not None:
        raise ParameterError("data and calib apply to nuScenes and KITTI detections, not generic ones")
    return read_generic_detections(path)


def filter_detections(
    frames: list[DetectionFrame], min_score: float = 0.0, classes: tuple[str, ...] | None = CLASSES
) -> tuple[list[DetectionFrame], dict[str, int]]:
    """The frames with only the boxes whose score is at least ``min_score`` (a box without a score counts as 1)
    and, unless ``classes`` is None, whose class is one of ``classes`` (with their reported velocities, if any).
    Returns the frames and the counts
    ``{"kept", "low_score", "other_class"}``."""
    if not 0.0 <= min_score <= 1.0:
        raise ParameterError(f"min_score: a score in [0, 1], got {min_score}")
    counts = {"kept": 0, "low_score": 0, "other_class": 0}
    out = []
    for f in frames:
        kept = []
        for i, b in enumerate(f.boxes):
            if classes is not None and b.cls not in classes:
                counts["other_class"] += 1
            elif (1.0 if b.score is None else b.score) < min_score:
                counts["low_score"] += 1
            else:
                kept.append(i)
        counts["kept"] += len(kept)
        v = f.velocities
        v = None if v is None or len(v) != len(f.boxes) else np.asarray(v, dtype=np.float64).reshape(-1, 3)[kept]
        out.append(replace(f, boxes=[f.boxes[i] for i in kept], velocities=v))
    return out, counts


__all__ = [
    "DETECTOR_CLASSES",
    "DetectionFrame",
    "FORMATS",
    "KITTI_DETECTION_CLASSES",
    "MAX_BOXES_PER_FRAME",
    "MAX_FRAMES",
    "MAX_VELOCITY_MPS",
    "NUSCENES_DETECTION_CLASSES",
    "detector_class",
    "filter_detections",
    "read_detections",
    "read_generic_detections",
    "read_kitti_detections",
    "nuscenes_velocity",
    "read_nuscenes_detections",
]
