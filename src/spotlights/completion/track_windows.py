"""The tracks of a track plan and each frame's inputs: boxes refined as the frames are reached, windows fused.

:class:`TrackWindows` holds what both :class:`spotlights.completion.fusion.TrackPlan` (the frame loop's process)
and the track worker process (:mod:`spotlights.completion.track_worker`) compute with: per track (sequence, track
id) its frames, (refined) boxes and statuses, and per frame key where its tracked boxes are in those tracks. Its
:meth:`TrackWindows._inputs` gives one frame's refined boxes and the other frames of each box's window, fused in the
box frame and put in the frame's scan frame; the plan adds reading, the worker and the outputs.

Frames: scan points and boxes in each frame's scan frame; fusion in the box frame (x forward, y left, z up, box
centre, metres).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..data.real.extract import points_in_box
from ..data.tracks import MAX_TRANSLATION_M, MAX_YAW_RAD, FusedTrack, TrackRefiner, WindowPolicy, fuse_track
from ..geometry.boxes import Box
from ..timing import StageTimer
from .frame import SceneConfig


@dataclass
class _Track:
    """One track of a plan: its frames (in time order), their boxes, statuses, point counts and completion."""

    sequence: str
    track_id: str
    keys: list = field(default_factory=list)  # (sequence, frame_id) per frame
    box_index: list = field(default_factory=list)  # the box's index in its frame's box list
    frames: list = field(default_factory=list)  # TrackFrame (points: the generous crop, scan frame)
    boxes: list = field(default_factory=list)  # refined (or given) boxes
    status: list = field(default_factory=list)
    n_points: list = field(default_factory=list)  # the frame's own points in the completion's crop
    n_fused: list = field(default_factory=list)
    completion: np.ndarray | None = None  # latest completion (scan frame of ``completion_frame``: box frame in write)
    completion_frame: int = -1
    refiner: TrackRefiner | None = None  # the box refinement, made as the frames are reached (None: none)
    fused: FusedTrack | None = None  # the whole track fused under its final boxes (from the worker), for write()
    size_group: int = 1  # with track shapes: its size group (1-based) of the track it was split from (shapes.py)
    split_from: str | None = None  # with track shapes: the track id it was split from (boxes of several sizes)


def _near_boxes(points: np.ndarray, boxes: list[Box], margin: float, ground_clearance: float) -> list[np.ndarray]:
    """Per box, the sorted indices (int64) of the scan points (N, 3) within the reach of
    :func:`spotlights.geometry.boxes.crop_boxes`' pre-cut (box radius + margin + clearance): one KD-tree
    for the scan instead of a distance to every point per box (a nuScenes keyframe: 35k points, 40 boxes)."""
    if not boxes or len(points) == 0:
        return [np.zeros(0, np.int64) for _ in boxes]
    from scipy.spatial import cKDTree

    reach = np.array([b.radius + max(margin, 0.0) + abs(ground_clearance) for b in boxes])
    # one query per box: a tree built without balancing is ~2x cheaper to build and finds the same points
    tree = cKDTree(points, balanced_tree=False, compact_nodes=False)
    hits = tree.query_ball_point(np.array([b.center for b in boxes]), reach)
    return [np.sort(np.asarray(h, dtype=np.int64)) for h in hits]


def _crops(points: np.ndarray, boxes: list[Box], grow: float, ground_clearance: float) -> list[np.ndarray]:
    """Per box, its points (k, 3) float64 of the scan ``points`` (N, 3), the scan's frame: those inside the box grown
    by ``grow`` with its bottom raised by ``ground_clearance`` (the plan's crop of a tracked box)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    near = _near_boxes(pts, boxes, grow, ground_clearance)
    return [pts[cand[points_in_box(pts[cand], b, grow, ground_clearance)]] for b, cand in zip(boxes, near)]


def _flipped(tr, pos: int) -> bool:
    """Whether frame ``pos`` of the track ``tr`` was found with its box turned around (refinement status
    ``yaw_flip``: :func:`~spotlights.data.tracks.yaw_flips`)."""
    return pos < len(tr.status) and tr.status[pos] == "yaw_flip"


class TrackWindows:
    """The tracks of a plan (``tracks``: {(sequence, track id): track}; ``where``: {frame key: {box index: (track,
    position)}}) and what each frame's inputs are: its boxes refined as far as its windows need (``refine``: a
    :class:`~spotlights.data.tracks.TrackRefiner` per track, bounded by ``max_translation`` metres and ``max_yaw``
    radians) and, per box, the other frames of its window (``policy``) fused in its box frame. ``config``: the
    completion's crop (margin, ground clearance)."""

    def __init__(
        self,
        policy: WindowPolicy,
        config: SceneConfig,
        refine: bool = False,
        max_translation: float = MAX_TRANSLATION_M,
        max_yaw: float = MAX_YAW_RAD,
    ):
        self.policy, self.config, self.refine = policy, config, refine
        self.max_translation, self.max_yaw = max_translation, max_yaw
        self.tracks: dict[tuple[str, str], _Track] = {}
        self.where: dict[tuple[str, str], dict[int, tuple[_Track, int]]] = {}  # frame key -> box -> (track, pos)
        self.timer = StageTimer()  # read_s (build), refine_s and fuse_s (frame_inputs), wait_s (for the worker)
        # called as the refinement and fusion go (each frame registered, each box fused): the track worker's sign of
        # life (worker_main); None: nothing
        self.progress: Callable[[], None] | None = None

    def _kept(self, tr: _Track) -> list[int] | None:
        """The positions of ``tr``'s frames that its whole-track fusion takes (None: every one): not a yaw flip."""
        kept = [j for j in range(len(tr.frames)) if not _flipped(tr, j)]
        return None if len(kept) == len(tr.frames) else kept or [0]

    def _own(self, tr: _Track, pos: int) -> np.ndarray:
        """The frame's points in the completion's crop of its (refined) box, box frame."""
        return fuse_track(
            tr.frames, [pos], boxes=tr.boxes, margin=self.config.margin, ground_clearance=self.config.ground_clearance
        ).points

    def _refine_upto(self, tr: _Track, pos: int) -> None:
        """Make the refined boxes that frame ``pos`` of ``tr`` and its window use final (causal windows: the
        frames up to ``pos``; others: the whole track), copied into ``tr.boxes`` / ``tr.status``."""
        ref = tr.refiner
        if ref is None or pos <= ref.done:
            return
        before = ref.done
        with self.timer("refine_s"):
            ref.upto(pos, self.progress)
        for j in range(before + 1, ref.done + 1):
            tr.boxes[j], tr.status[j] = ref.box(j), ref.status[j]

    def _inputs(self, key) -> tuple[dict[int, Box], dict[int, np.ndarray]]:
        """For one frame: {box index: its (refined) box} and {box index: (k, 3) scan-frame points of the other
        frames of its window, fused in its box frame and put in this frame} (refining what they need)."""
        repl: dict[int, Box] = {}
        extra: dict[int, np.ndarray] = {}
        for i, (tr, pos) in self.where.get(key, {}).items():
            window = self.policy.select(len(tr.frames), pos)
            self._refine_upto(tr, int(window[-1]))
            laps = StageTimer()
            box = tr.boxes[pos]
            # a frame whose box is turned around (yaw_flip) is left out of the fusion: its points are mirrored
            others = [] if _flipped(tr, pos) else [j for j in window if j != pos and not _flipped(tr, j)]
            own = len(self._own(tr, pos))
            fused = (
                fuse_track(
                    tr.frames,
                    others,
                    boxes=tr.boxes,
                    margin=self.config.margin,
                    ground_clearance=self.config.ground_clearance,
                ).points
                if others
                else np.zeros((0, 3))
            )
            repl[i] = box
            extra[i] = box.from_object(fused)
            tr.n_points[pos] = own
            tr.n_fused[pos] = own + len(fused)
            self.timer.add("fuse_s", laps.lap("fuse"))
            if self.progress is not None:
                self.progress()
        return repl, extra

    def finish(self) -> None:
        """Refine what no frame reached (the boxes of frames left out of the frame loop). Idempotent."""
        for tr in self.tracks.values():
            self._refine_upto(tr, len(tr.frames) - 1)


__all__ = ["TrackWindows"]
