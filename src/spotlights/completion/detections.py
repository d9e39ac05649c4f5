"""A detector's boxes, tracked, in place of a dataset's annotations (``real complete --detections FILE --track``).

:func:`tracked_reader` reads the detections beside the dataset (:func:`spotlights.tracking.detections.
read_detections`: nuScenes results beside ``--format nuscenes``, KITTI results with scores beside ``kitti``, the
generic box JSON with scores beside ``generic``), keeps the vehicle boxes scoring at least ``min_score``, tracks them
(:func:`spotlights.tracking.track_boxes`, default settings) and returns a reader whose frames are the dataset's
scans with the tracked boxes (track ids, scores) instead of its own boxes: ``--fuse`` then fuses each track. A
track the tracker kept alive across a gap longer than the fusion's ``max_gap`` (it ends a track only after several
misses) is split there into tracks of their own (:func:`split_at_gaps`): the fusion never bridges such a gap.
A frame of the dataset with no detection has no box; detections of frames the dataset lacks are left out.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

from ..data.real.base import CLASSES, Frame, SceneReader
from ..errors import InputFileError, ParameterError
from ..geometry.boxes import Box
from ..tracking.detections import DetectionFrame, filter_detections, read_detections, read_nuscenes_detections
from ..tracking.outputs import tracks_document
from ..tracking.tracker import TrackerConfig, track_boxes

#: Dataset formats whose detections can be read (the detection format is the dataset's).
DETECTION_FORMATS = ("nuscenes", "kitti", "generic")


class TrackedReader(SceneReader):
    """The frames of ``reader`` with the boxes of ``tracked`` (keyed by (sequence, frame_id)) instead of its own."""

    def __init__(
        self,
        reader: SceneReader,
        tracked: dict[tuple[str, str], list[Box]],
        label_path: str,
        detection_settings: dict | None = None,
    ) -> None:
        self.reader = reader
        self.format = reader.format
        self.root = reader.root
        self.tracked = tracked
        self.label_path = label_path
        #: what the boxes were made from (the detection file's digest, the score cut, the tracker's settings, the
        #: longest gap): a frame's summary records it and ``--resume`` completes again the frames of another
        self.detection_settings = detection_settings

    def frame_keys(self) -> list[tuple[str, str]]:
        return self.reader.frame_keys()

    def load(self, key: tuple[str, str]) -> Frame:
        frame = self.reader.load(key)
        return dataclasses.replace(frame, boxes=list(self.tracked.get(key, [])), label_path=self.label_path)


def check_detection_options(
    detections: str | None, track: bool, fmt: str, sources: int, min_score: float | None = None
) -> None:
    """One-line :class:`ParameterError` for ``--detections`` without ``--track`` (or ``--track`` or ``--min-score``
    without ``--detections``), for a format whose detections cannot be read, or for several sources."""
    if detections is None:
        if track or min_score is not None:
            raise ParameterError(
                "`track` and `min_score` go with `detections` FILE (the detector's boxes to track)",
                "track",
                "min_score",
                "detections",
            )
        return
    if not track:
        raise ParameterError(
            "`detections` needs `track`: a detector's boxes have no track ids (`track` gives them ids before `fuse`)",
            "detections",
            "track",
            "fuse",
        )
    if fmt not in DETECTION_FORMATS:
        raise ParameterError(
            f"`detections` is read beside `format` {', '.join(DETECTION_FORMATS)}, not {fmt}", "detections", "format"
        )
    if sources != 1:
        raise ParameterError("`detections` goes with one SOURCE (the dataset its frames belong to)", "detections")


def tracked_reader(
    reader: SceneReader,
    detections: str,
    source: str,
    min_score: float | None = None,
    scenes: list | None = None,
    config: TrackerConfig | None = None,
    max_gap: float | None = None,
) -> TrackedReader:
    """``reader`` (the dataset at ``source``) with the tracked boxes of the detection file ``detections`` (module
    docstring); ``min_score``: None keeps every score; ``scenes``: the nuScenes scenes read; ``max_gap``: seconds, the
    longest gap a track keeps its id over (None: no split). :class:`InputFileError` when no detection frame is a frame
    of the dataset."""
    fmt = reader.format
    if fmt == "nuscenes":
        frames: list[DetectionFrame] = read_nuscenes_detections(detections, source, scenes)
    elif fmt == "kitti":
        frames = read_detections(detections, "kitti", data=Path(reader.root))
    else:
        frames = read_detections(detections, "generic")
    keys = set(reader.frame_keys())
    frames = [f for f in frames if (f.sequence, f.frame_id) in keys]
    if not frames:
        raise InputFileError(detections, f"no frame of the detections is a frame of {source} (sequence, frame id)")
    frames, _ = filter_detections(frames, min_score or 0.0, CLASSES)
    tracked = track_boxes(frames, config)
    if max_gap is not None:
        tracked = split_at_gaps(tracked, max_gap)
    settings = {
        "sha256": detections_digest(frames),
        "min_score": min_score or 0.0,
        "max_gap": max_gap,
        "tracker": dataclasses.asdict(config if config is not None else TrackerConfig()),
    }
    return TrackedReader(reader, {(f.sequence, f.frame_id): f.boxes for f in tracked}, str(detections), settings)


def detections_digest(frames: list[DetectionFrame]) -> str:
    """The SHA-256 (hex) of detection frames as read, in the tracks file's form
    (:func:`~spotlights.tracking.outputs.tracks_document`: every frame's sequence, id, time and pose, its boxes with
    their scores and reported velocities), so that any file the detections were read from (a sequence JSON's box
    files too) counts."""
    return hashlib.sha256(json.dumps(tracks_document(frames), sort_keys=True).encode()).hexdigest()


def split_at_gaps(frames: list[DetectionFrame], max_gap: float) -> list[DetectionFrame]:
    """The tracked ``frames`` with every track split where it goes unseen for more than ``max_gap`` seconds between
    two of its boxes: the part after a gap gets a new integer id (one above the largest id of the call, in order of
    sequence, then time, then id: deterministic). Frames and boxes are otherwise unchanged (new objects)."""
    if not (max_gap > 0):
        raise ParameterError(f"`max_gap` must be > 0 seconds, got {max_gap}", "max_gap")
    order = sorted(range(len(frames)), key=lambda i: (frames[i].sequence, frames[i].timestamp))
    ids = [int(b.track_id) for f in frames for b in f.boxes if str(b.track_id).isdigit()]
    next_id = max(ids, default=0) + 1
    last_seen: dict[tuple[str, str], float] = {}
    renamed: dict[tuple[str, str], str] = {}
    out: list[DetectionFrame | None] = [None] * len(frames)
    for i in order:
        f = frames[i]
        boxes = []
        for b in f.boxes:  # the tracker's order (deterministic)
            key = (f.sequence, str(b.track_id))
            if key in last_seen and f.timestamp - last_seen[key] > max_gap:
                renamed[key] = str(next_id)
                next_id += 1
            last_seen[key] = f.timestamp
            boxes.append(b.replace(track_id=renamed.get(key, str(b.track_id))))
        out[i] = dataclasses.replace(f, boxes=boxes)
    return [f for f in out if f is not None]
