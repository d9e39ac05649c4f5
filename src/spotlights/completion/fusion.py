"""Track-level completion of a dataset: each vehicle's frames fused in its box frame, boxes refined, completed.

The plan behind ``spotlights real complete ... --fuse POLICY [--refine-boxes]``:

1. :meth:`TrackPlan.build` reads every selected frame once and collects, per track (sequence, track id),
   each frame's box, its points (the box's crop, grown by the bound of a box correction when refining),
   the sensor origin and the time (seconds: :data:`spotlights.data.tracks.TIME_UNIT_S`). A vehicle box
   without a track id, a track with a gap or two boxes at one instant, or a selection of fewer than two
   frames is refused with one line before anything is written.
2. With ``refine``: a :class:`spotlights.data.tracks.TrackRefiner` per track (the numbers of
   :func:`spotlights.data.tracks.refine_track`, with the same window policy: ``past:K`` stays causal), run as the
   frames are reached: with ``past:K`` frame ``t``'s box is refined when frame ``t`` is asked for, other windows
   refine the whole track at its first frame.
3. Per frame, :meth:`TrackPlan.frame_inputs` gives the boxes (refined where refined) and, per vehicle box,
   the other frames of its window fused in its box frame (:func:`spotlights.data.tracks.fuse_track`, the
   completion's crop) and put in this frame's scan frame: :func:`spotlights.completion.frame.complete_scene`
   adds them to the box's own crop for the model input. The completion is the existing one, on more points.
   With ``worker=True`` (and two usable CPUs) a :class:`TrackWorker` process crops the tracked boxes while the
   frames are read, then refines and fuses the frames ahead of the frame loop, which completes them meanwhile:
   a two-stage pipeline with the same outputs, byte for byte.
4. :meth:`TrackPlan.record` keeps each track's latest completion; :meth:`TrackPlan.write` writes per track
   ``tracks/<track>.ply`` (box frame of the track's last frame: the whole track's fused input, ``source`` 1
   with ``frame`` = the frame's position in the track, then the completion of the last frame's window,
   ``source`` 2, ``frame`` -1) and ``tracks.json`` (per track and frame: given and refined boxes, status,
   correction, points in the frame and in its fused input).

Frames: scan points and boxes in each frame's scan frame; fusion in the box frame (x forward, y left, z up,
box centre, metres). The sensor origin is the scan frame's origin unless the frame carries
``sensor_origin`` ((3,) metres, scan frame).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import pickle
import sys
import time
import traceback
import weakref
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from queue import Empty
from typing import TYPE_CHECKING

import numpy as np

from ..data.real.base import Frame
from ..data.real.extract import points_in_box
from ..data.tracks import (
    FLAGGED,
    MAX_GAP_S,
    MAX_TRANSLATION_M,
    MAX_YAW_RAD,
    TIME_UNIT_S,
    FusedTrack,
    TrackFrame,
    TrackRefiner,
    WindowPolicy,
    check_track,
    fuse_track,
)
from ..errors import ParameterError, ProcessFailure
from ..geometry.boxes import Box
from ..geometry.io import save_ply
from ..options import check_threads
from ..outputs import atomic_output
from ..processes import _quiet_worker, process_pool_context, sigint_held
from ..timing import StageTimer
from .frame import SOURCE_COMPLETION, SOURCE_PARTIAL, SceneConfig, SceneResult, _selected, scene_crops
from .names import file_stem, sequence_folders, unique_names
from .shapes import SIZE_TOLERANCE, TrackShapes, split_by_size

if TYPE_CHECKING:
    from multiprocessing.process import BaseProcess
    from multiprocessing.queues import Queue

#: The most scan points :meth:`TrackPlan.build` keeps of the frames it read, for the frame loop to take
#: (:meth:`TrackPlan.take`) instead of reading them again (2^24: ~200 MB; 480 nuScenes keyframes). Frames
#: beyond it are read again.
KEEP_POINTS = 1 << 24


@dataclass
class _Track:
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


class TrackPlan:
    """Tracks of the selected frames, their (refined) boxes and fused inputs (see the module docstring)."""

    def __init__(
        self,
        policy: WindowPolicy,
        config: SceneConfig,
        refine: bool = False,
        max_gap_s: float | None = MAX_GAP_S,
        max_translation: float = MAX_TRANSLATION_M,
        max_yaw: float = MAX_YAW_RAD,
        worker: bool | TrackWorker = False,
        track_shape: bool = False,
    ):
        if not policy.fuses:
            raise ParameterError("a track plan needs a window that fuses frames (all, past:K or centered:K)")
        self.policy, self.config, self.refine = policy, config, refine
        self.max_gap_s, self.max_translation, self.max_yaw = max_gap_s, max_translation, max_yaw
        self.tracks: dict[tuple[str, str], _Track] = {}
        self.where: dict[tuple[str, str], dict[int, tuple[_Track, int]]] = {}  # frame key -> box -> (track, pos)
        self.timer = StageTimer()  # read_s (build), refine_s and fuse_s (frame_inputs), wait_s (for the worker)
        self.folders: dict[str, str] | None = None  # sequence -> its folder, for the frames' keys (build)
        self.kept: dict = {}  # frame key -> the Frame build read, until the frame loop takes it (KEEP_POINTS)
        # refine and fuse in a worker process (TrackWorker) while this one completes: True starts one in build, a
        # TrackWorker started earlier (its interpreter ready by then) is used as it is
        self.worker = bool(worker)
        self._worker: TrackWorker | None = worker if isinstance(worker, TrackWorker) else None
        self.scene_crops: dict = {}  # frame key -> the worker's crops of its scene (frame_crops), the latest only
        self.asked: set = set()  # frame keys frame_inputs was called for (the frames whose points are counted)
        # called as the refinement and fusion go (each frame registered, each box fused): the track worker's sign of
        # life (worker_main); None: nothing
        self.progress: Callable[[], None] | None = None
        self._tracks_digest: str | None = None  # settings(): the digest of the tracks' frame keys
        # a shape per track (spotlights.completion.shapes): tracks split by box size in build, shapes placed by
        # place_shapes; None: every frame shows its own completion
        self.shapes = TrackShapes(policy) if track_shape else None
        self.n_size_splits = 0
        self.recrop: set = set()  # frames with a box frame_inputs resized to make a shape: complete_scene crops them

    @property
    def timings(self) -> dict[str, float]:
        """Wall seconds spent reading the frames, refining the boxes, fusing the windows (in the worker process
        when there is one) and, with a worker, waiting for it and the CPU seconds of its work (``worker_cpu_s``)."""
        names = ("read_s", "refine_s", "fuse_s", "wait_s", "worker_cpu_s")
        return {k: self.timer.seconds.get(k, 0.0) for k in names}

    # --- building ---------------------------------------------------------------------------

    def build(self, reader, keys) -> TrackPlan:
        """Read the frames ``keys`` of ``reader`` and collect their tracks (refined when asked). One-line
        :class:`ParameterError` for what cannot be fused (see the module docstring)."""
        unit = TIME_UNIT_S.get(reader.format)
        if unit is None:
            raise ParameterError(
                f"`format` {reader.format} has no tracks over time: `fuse` needs a sequence format", "format", "fuse"
            )
        if len(keys) < 2:
            raise ParameterError(
                f"`fuse` needs a sequence of at least 2 frames; the selection holds {len(keys)}", "fuse"
            )
        laps = StageTimer()
        self.folders = sequence_folders(keys)  # the frames' sequence folders (frame_selection.frame_stems) are theirs
        grow = self.config.margin + (self.max_translation if self.refine else 0.0)
        budget = KEEP_POINTS
        if self.worker and self._worker is None:
            self._worker = TrackWorker.start()  # its interpreter starts while the frames are read (None: cannot)
        for key in keys:
            frame = reader.load(key)
            if len(frame.points) <= budget:
                self.kept[key] = frame
                budget -= len(frame.points)
            so = getattr(frame, "sensor_origin", None)
            origin = np.zeros(3) if so is None else np.asarray(so, dtype=np.float64).reshape(3)
            todo = [
                i
                for i, b in enumerate(frame.boxes)
                if _selected(b, self.config) and b.is_valid() and b.track_id.strip()
            ]
            untracked = sum(
                1 for b in frame.boxes if _selected(b, self.config) and b.is_valid() and not b.track_id.strip()
            )
            todo_boxes = [frame.boxes[i] for i in todo]
            if self._worker is not None:  # the worker crops (its frames' points are None here)
                keep = key in self.kept  # the frame loop takes this frame: the worker also makes its scene's crops
                if todo or keep:
                    self._worker.crop(key, frame.points, todo, frame.boxes, grow, self.config.ground_clearance, keep)
                crops: list = [None] * len(todo)
            else:
                crops = _crops(frame.points, todo_boxes, grow, self.config.ground_clearance)
            for i, b, crop in zip(todo, todo_boxes, crops):
                tr = self.tracks.setdefault((frame.sequence, b.track_id), _Track(frame.sequence, b.track_id))
                tr.keys.append(key)
                tr.box_index.append(i)
                tr.frames.append(TrackFrame(crop, b, origin, float(frame.timestamp) * unit))
                self.where.setdefault(key, {})[i] = (tr, len(tr.frames) - 1)
            if untracked:
                where = f"{frame.sequence}/{frame.frame_id}" if frame.sequence else frame.frame_id
                raise ParameterError(
                    f"frame {where} ({frame.label_path or frame.scan_path}): {untracked} vehicle box(es) without a "
                    "track id; `fuse` needs a track id on every box it completes (track_id in the box files)",
                    "fuse",
                )
        for tr in self.tracks.values():
            check_track(
                [f.timestamp for f in tr.frames],
                self.max_gap_s,
                name=f"track {tr.track_id}" + (f" of {tr.sequence}" if tr.sequence else ""),
            )
        if self.shapes is not None:  # one shape is one size: a track of boxes of several sizes is split
            self.tracks, self.where, self.n_size_splits = split_by_size(self.tracks, self.where)
        self.timer.add("read_s", laps.lap("read"))
        for tr in self.tracks.values():
            tr.boxes = [f.box for f in tr.frames]
            tr.status = ["given"] * len(tr.frames)
            if self.refine and len(tr.frames) >= 2:  # refined as the frames are reached (frame_inputs)
                tr.refiner = TrackRefiner(
                    tr.frames,
                    self.policy,
                    max_translation=self.max_translation,
                    max_yaw=self.max_yaw,
                    min_points=self.config.min_points,
                    margin=grow,
                    ground_clearance=self.config.ground_clearance,
                )
            elif self.refine:
                tr.status = ["single_frame"]
            tr.n_points = [0] * len(tr.frames)
            tr.n_fused = [0] * len(tr.frames)
        if self._worker is not None:
            self.start_worker(keys, self._worker)
        return self

    def start_worker(self, keys: Sequence[Hashable], worker: TrackWorker | None = None) -> bool:
        """Hand the built plan to a worker process (``worker``, else a new :class:`TrackWorker`) that refines and
        fuses the frames ``keys`` in that order, ahead of :meth:`frame_inputs`; False where no process can be
        started (the plan then works alone). A plan built with a worker (``worker=True``) was cropped there."""
        worker = TrackWorker.start() if worker is None else worker
        if worker is None:
            return False
        self._worker = worker
        worker.send(self, list(keys))
        return True

    @property
    def worker_process(self) -> BaseProcess | None:
        """The worker's ``multiprocessing`` process while one works for this plan, else None."""
        return None if self._worker is None else self._worker.proc

    # --- per frame ----------------------------------------------------------------------------

    def take(self, key: tuple) -> Frame | None:
        """The frame ``key`` as :meth:`build` read it (its reader's ``Frame``), handed out once: the frame loop
        reads each frame once, not twice. None when it was not kept (beyond :data:`KEEP_POINTS`) or was taken."""
        return self.kept.pop(key, None)

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

    def frame_inputs(self, key, boxes: list[Box]) -> tuple[list[Box], dict[int, np.ndarray]]:
        """For one frame: its boxes with the refined ones in place, and {box index: (k, 3) scan-frame points of
        the other frames of the box's window, fused in its box frame and put in this frame}. With a worker
        process, what it computed for the frame (the frames are asked for in the order given to :meth:`build`,
        some may be passed over)."""
        self.asked.add(key)
        repl, extra = self._inputs(key) if self._worker is None else self._worker.inputs(self, key)
        out = list(boxes)
        for i, box in repl.items():
            out[i] = box
        if self.shapes is not None:  # a box that makes its track's shape is completed in the track's median size
            for i, (tr, pos) in self.where.get(key, {}).items():
                made = self.shapes.maker_box(tr, pos)
                if made is not None and not np.array_equal(made.size, out[i].size):
                    out[i] = made
                    self.recrop.add(key)  # the worker's crops were of the other box
        return out, extra

    def frame_crops(self, key: Hashable) -> dict | None:
        """The crops of frame ``key``'s scene that the worker made with its (refined) boxes ({box index: (k,) int64},
        :func:`spotlights.completion.frame.scene_crops`), for ``complete_scene(..., crops=...)``; None without (no
        worker, or a frame it was not sent the scan of). Asked for after :meth:`frame_inputs`, handed out once."""
        crops = self.scene_crops.pop(key, None)
        return None if key in self.recrop else crops

    def finish(self) -> None:
        """Refine what no frame reached (the boxes of frames left out of the frame loop) and, with a worker
        process, take its final boxes, statuses, point counts and timings and end it. Idempotent."""
        if self._worker is not None:
            self._worker.finish(self)
            self._worker = None
        for tr in self.tracks.values():
            self._refine_upto(tr, len(tr.frames) - 1)

    def close(self) -> None:
        """End the worker process, if any, without waiting for its results (after an error)."""
        if self._worker is not None:
            self._worker.stop()
            self._worker = None

    def place_shapes(self, key, result: SceneResult) -> None:
        """With ``track_shape``: in frame ``key``'s ``result`` (after :meth:`frame_inputs` and ``complete_scene``),
        each tracked box that does not make its track's shape shows the shape in use instead of its own completion
        (:class:`~spotlights.completion.shapes.TrackShapes`, in place; frames asked for in order). Else nothing."""
        if self.shapes is not None:
            self.shapes.apply(self.where.get(key, {}), result)

    def record(self, key, result: SceneResult) -> None:
        """Keep each track's completion of this frame (scan frame; :meth:`write` puts it in its box frame), the
        latest frame's winning."""
        for o in result.completed:
            hit = self.where.get(key, {}).get(o.index)
            if hit is None:
                continue
            tr, pos = hit
            if pos >= tr.completion_frame:  # moved into its box frame once, by write()
                tr.completion = o.completion
                tr.completion_frame = pos

    # --- outputs ------------------------------------------------------------------------------

    def settings(self) -> dict:
        """JSON-ready: what decides each frame's inputs (window, refinement and its bounds, longest gap, and the
        tracks' frames: ``tracks``, a digest of every track's frame keys, which another ``--frames`` selection
        changes); each frame's JSON records it and ``real complete --resume`` reuses only frames done with the same."""
        if self._tracks_digest is None:  # the tracks are fixed once built: computed once
            keys = [[list(k), [list(x) for x in tr.keys]] for k, tr in self.tracks.items()]  # in the frames' order
            text = json.dumps(keys, default=str, separators=(",", ":"))
            self._tracks_digest = hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]
        shape = {} if self.shapes is None else {"track_shape": self.shapes.mode, "size_tolerance": SIZE_TOLERANCE}
        return (
            dict(
                fuse=str(self.policy),
                refine_boxes=self.refine,
                max_gap_s=self.max_gap_s,
                max_translation_m=self.max_translation,
                max_yaw_deg=math.degrees(self.max_yaw),
                tracks=self._tracks_digest,
            )
            | shape
        )

    def summary(self) -> dict:
        """JSON-ready: policy, refinement settings, per track and frame the boxes, statuses and point counts,
        and the totals (frames refined, flagged, moved by more than 0.3 m)."""
        self.finish()
        tracks = []
        moved = flagged = refined = n = 0
        for tr in self.tracks.values():
            rows = []
            for pos, (key, f, b, st) in enumerate(zip(tr.keys, tr.frames, tr.boxes, tr.status)):
                d = float(np.hypot(*(b.center - f.box.center)[:2]))
                dyaw = math.remainder(b.yaw - f.box.yaw, 2 * math.pi)
                rows.append(
                    dict(
                        frame_id=key[1],
                        timestamp_s=f.timestamp,
                        box_index=tr.box_index[pos],
                        status=st,
                        flagged=st in FLAGGED,
                        moved_m=d,
                        turned_deg=math.degrees(dyaw),
                        n_points=tr.n_points[pos],
                        n_fused=tr.n_fused[pos],
                        box=f.box.to_dict(),
                        refined_box=b.to_dict(),
                    )
                )
                n += 1
                moved += d > 0.3
                flagged += st in FLAGGED
                refined += st == "refined"
            entry = dict(sequence=tr.sequence, track_id=tr.track_id, n_frames=len(tr.frames), frames=rows)
            if self.shapes is not None:
                made = self.shapes.made_at((tr.sequence, tr.track_id))
                entry |= dict(size_group=tr.size_group, split_from=tr.split_from, shape_made_at=made)
            tracks.append(entry)
        fixed = {k: v for k, v in self.settings().items() if k != "tracks"}  # the tracks themselves follow, in full
        if self.shapes is not None:
            fixed["n_size_splits"] = self.n_size_splits
        return dict(
            **fixed,
            n_tracks=len(tracks),
            n_track_frames=n,
            n_refined=refined,
            n_flagged=flagged,
            n_moved_over_0_3_m=moved,
            timings=self.timings,
            tracks=tracks,
        )

    def write(self, out: str | Path, model: str = "", summary: dict | None = None) -> list[Path]:
        """Write ``OUT/[SEQUENCE/]tracks/<track>.ply`` per track and ``OUT/tracks.json`` (``summary``: the
        :meth:`summary` the caller already made, else made here); returns the paths."""
        self.finish()
        out = Path(out)
        written = []
        folders = self.folders
        if folders is None:  # a plan not built from frame keys
            folders = sequence_folders((tr.sequence, "") for tr in self.tracks.values())
        # one file per track in each folder: ids that sanitise alike ("a/b", "a_b") or differ in case take a digest
        ids: dict[str, list] = {}
        for tr in self.tracks.values():
            ids.setdefault(tr.sequence or "", []).append(tr.track_id)
        names = {s: unique_names(v, empty="track") for s, v in ids.items()}
        for tr in self.tracks.values():
            last = len(tr.frames) - 1
            pts = (
                tr.fused
                if tr.fused is not None
                else fuse_track(
                    tr.frames,
                    self._kept(tr),
                    boxes=tr.boxes,
                    margin=self.config.margin,
                    ground_clearance=self.config.ground_clearance,
                )
            )
            comp = np.zeros((0, 3)) if tr.completion is None else tr.boxes[tr.completion_frame].to_object(tr.completion)
            # the completion is in the box frame of its frame's box; the fused points in each frame's own box
            # frame: both are the object frame, the one all the track's boxes share
            xyz = np.concatenate([pts.points, comp])
            src = np.r_[
                np.full(len(pts.points), SOURCE_PARTIAL, np.uint8), np.full(len(comp), SOURCE_COMPLETION, np.uint8)
            ]
            frm = np.r_[pts.frame_index.astype(np.int32), np.full(len(comp), -1, np.int32)]
            folder = out / folders[tr.sequence] / "tracks" if tr.sequence else out / "tracks"
            com = [
                f"spotlights track {tr.track_id}"
                + (f" of {tr.sequence}" if tr.sequence else "")
                + ": box frame (x forward, y left, z up, box centre), metres",
                (
                    f"source: 1 fused input, 2 completion of frame {tr.completion_frame} ({last + 1} frames); "
                    if self.shapes is None
                    else f"source: 1 fused input, 2 the track's {self.shapes.mode} shape, made at frame(s) "
                    f"{' '.join(map(str, self.shapes.made_at((tr.sequence, tr.track_id)))) or 'none'} "
                    f"({last + 1} frames); "
                )
                + "frame: position in the track (-1: completion)",
                f"fuse {self.policy}"
                + (", boxes refined" if self.refine else "")
                + (f", model {model}" if model else ""),
            ]
            written.append(
                save_ply(
                    folder / f"{names[tr.sequence or ''][tr.track_id]}.ply",
                    xyz,
                    {"source": src, "frame": frm},
                    comments=com,
                )
            )
        with atomic_output(out / "tracks.json") as tmp:
            text = json.dumps(self.summary() if summary is None else summary, indent=2, default=float)
            tmp.write_text(text + "\n", encoding="utf-8")
        written.append(out / "tracks.json")
        return written


# --- the worker process ---------------------------------------------------------------------------

#: Seconds :class:`TrackWorker` waits between checks that its process is still alive.
POLL_S = 0.5

#: Seconds the worker process may go without a message before it is taken for hung: the run then stops it and fails
#: with one line (:class:`TrackWorkerStalled`). The worker sends a sign of life at least every :data:`BEAT_S` while it
#: works (after each frame it registers and each box it fuses), so this bounds one such step, not a whole frame:
#: scene-0523 (nuScenes, 40 keyframes, 91 tracks, 2-core machine under load) took at most 0.07 s a frame with
#: ``past:5 --refine-boxes`` and 0.6 s for its longest track's whole refinement with ``all`` (one step: ~5 ms); the
#: worker's start to its first frame (fork server and worker: fresh interpreters importing numpy and scipy) 0.45 s.
#: A pause of the whole run (Ctrl-Z, then ``fg``) is not counted. 120 s is over 100 times the longest of these:
#: a slow or busy machine gets no false alarm, a hung worker costs two minutes instead of a run that never ends.
STALL_S = 120.0

#: Seconds between the worker's signs of life (``("beat",)`` messages) while it works without another message.
BEAT_S = 1.0


def _flipped(tr, pos: int) -> bool:
    """Whether frame ``pos`` of the track ``tr`` was found with its box turned around (refinement status
    ``yaw_flip``: :func:`~spotlights.data.tracks.yaw_flips`)."""
    return pos < len(tr.status) and tr.status[pos] == "yaw_flip"


class TrackWorkerStalled(ProcessFailure):
    """The track worker process sent nothing for :data:`STALL_S` seconds while alive: it was stopped (exit code 1)."""


class TrackWorkerDied(ProcessFailure):
    """The track worker process ended without sending its results (killed, say for memory): exit code 1."""


#: Linux cgroup v2 file of this process's CPU quota ("QUOTA PERIOD" in microseconds, or "max PERIOD").
CGROUP_CPU_MAX = "/sys/fs/cgroup/cpu.max"


def cgroup_cpu_limit(path: str | Path = CGROUP_CPU_MAX) -> int | None:
    """The whole CPUs a cgroup v2 quota allows (``ceil(quota / period)``, at least 1; ``docker --cpus=1`` writes
    ``100000 100000``), or None without a quota (``max``) or without a readable file (other systems)."""
    try:
        quota, period = Path(path).read_text().split()[:2]
        return None if quota == "max" else max(1, math.ceil(int(quota) / int(period)))
    except (OSError, ValueError, ZeroDivisionError):
        return None


def usable_cpus() -> int:
    """The CPUs this process may run on: its affinity where the platform tells it (else ``os.cpu_count()``), no
    more than its container's CPU quota (:func:`cgroup_cpu_limit`)."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        n = os.cpu_count() or 1
    limit = cgroup_cpu_limit()
    return n if limit is None else min(n, limit)


@contextlib.contextmanager
def threads_beside_worker(plan: TrackPlan | None, threads: int | None = None):
    """While ``plan`` has a worker process, run torch on at most the usable CPUs less one (restored on exit); with
    ``threads`` (``--threads``), on that many, worker or not (the user's count wins; restored on exit too).

    The worker takes one core for the whole run; torch's OpenMP threads spin for every core it was given, so on
    two cores a second torch thread only competes with the worker (scene-0523, ``past:5 --refine-boxes``, bf16, a
    quiet 2-core machine: 14.4 frames/s with one torch thread against 11.0 with two; docs/real-data.md). A lower
    thread count set by the caller is kept; without a worker (and ``threads``) nothing changes."""
    torch = sys.modules.get("torch")  # not imported: onnxruntime runs the model (its threads are its session's)
    if torch is None or (not threads and (plan is None or plan.worker_process is None)):
        yield
        return

    before = torch.get_num_threads()
    torch.set_num_threads(check_threads(threads) if threads else max(1, min(before, usable_cpus() - 1)))
    try:
        yield
    finally:
        torch.set_num_threads(before)


def worker_main(jobs: Queue, results: Queue) -> None:
    """What the :class:`TrackWorker` process runs: receive a plan (:meth:`TrackWorker.send`), then for each frame key
    in order put ``("frame", key, repl, extra, scene)`` (:meth:`TrackPlan._inputs`), then ``("done", state, timer
    seconds)``; ``("error", exception)`` instead when something fails; ``("beat",)`` at most every :data:`BEAT_S`
    seconds while it works without another message (read by :data:`STALL_S`)."""
    _quiet_worker(None, ())  # as a pool worker: Ctrl-C is the parent's (which stops this one); dies with it
    import scipy.spatial  # noqa: F401 - imported now, while the parent opens and reads (0.25 s), not at the first crop

    last = [time.monotonic()]

    def put(msg) -> None:
        results.put(msg)
        last[0] = time.monotonic()

    def beat() -> None:
        if time.monotonic() - last[0] >= BEAT_S:
            put(("beat",))

    try:
        crops: dict = {}  # frame key -> {box index: its crop}
        scans: dict = {}  # frame key -> (its scan, its boxes): for the scene's crops of the frames the loop takes
        cpu0 = time.process_time()
        while True:
            msg = jobs.get()
            if msg is None:  # stopped before a plan came
                return
            if msg[0] == "plan":
                job = msg[1]
                break
            _, key, points, todo, boxes, grow, clearance, keep = msg
            crops[key] = dict(zip(todo, _crops(points, [boxes[i] for i in todo], grow, clearance)))
            if keep:
                scans[key] = (points, boxes)
            beat()
        plan = TrackPlan(job["policy"], job["config"], job["refine"], None, job["max_translation"], job["max_yaw"])
        plan.progress = beat
        plan.tracks, plan.where = job["tracks"], job["where"]
        for tr in plan.tracks.values():  # the crops made here go where the plan left None
            for pos, (key, i, f) in enumerate(zip(tr.keys, tr.box_index, tr.frames)):
                if f.points is None:
                    tr.frames[pos] = TrackFrame(crops[key][i], f.box, f.origin, f.timestamp)
            if tr.refiner is not None:
                tr.refiner.frames = tr.frames
        del crops
        for key in job["keys"]:
            repl, extra = plan._inputs(key)
            scene = None
            if key in scans and plan.config.crop:  # complete_scene's crops, of the boxes the loop will use
                points, boxes = scans.pop(key)
                scene = scene_crops(points, [repl.get(i, b) for i, b in enumerate(boxes)], plan.config)
            put(("frame", key, repl, extra, scene))
        plan.finish()
        cfg = plan.config
        state = {}
        for k, tr in plan.tracks.items():
            fused = fuse_track(
                tr.frames, plan._kept(tr), boxes=tr.boxes, margin=cfg.margin, ground_clearance=cfg.ground_clearance
            )
            state[k] = (tr.boxes, tr.status, tr.n_points, tr.n_fused, fused)
            beat()
        put(("done", state, dict(plan.timer.seconds) | {"worker_cpu_s": time.process_time() - cpu0}))
    except BaseException as exc:  # noqa: BLE001 - handed to the parent, which raises it
        exc.add_note("in the track worker process:\n" + traceback.format_exc().rstrip())  # its frames are lost else
        try:
            pickle.dumps(exc)  # the queue pickles in a thread of its own, where a failure would be lost
        except Exception:  # an exception that does not pickle
            exc = RuntimeError(f"the track worker failed: {exc!r}")
        results.put(("error", exc))


class TrackWorker:
    """One worker process that refines the boxes and fuses the windows of a :class:`TrackPlan` frame by frame,
    ahead of the process that completes the frames (a two-stage pipeline on two cores: the frame loop completes
    frame ``t`` while the worker prepares frame ``t + 1``). It computes what :meth:`TrackPlan.frame_inputs` would
    (the same functions on the same inputs: the same numbers); the plan's frames (the crops of its tracked
    boxes) are sent to it once, after :meth:`TrackPlan.build` has read them. Started from the fork server of
    :func:`spotlights.processes.process_pool_context` (never a fork of a process holding a model), it ends with its
    parent."""

    def __init__(self, proc: BaseProcess, jobs: Queue, results: Queue):
        self.proc, self.jobs, self.results = proc, jobs, results
        self.pending: dict = {}  # frame key -> (repl, extra) received before it was asked for
        self.done = False
        # a plan used from Python and dropped without finish()/close(): its worker (and the scans it holds) ends
        # when this object is collected, not only with the parent process
        self._finalizer = weakref.finalize(self, _end_worker, proc, jobs, results)

    @classmethod
    def start(cls) -> TrackWorker | None:
        """A started worker process, or None where none can be started or this process may use one CPU only
        (:func:`usable_cpus`: a second process would only take turns with it; the caller then works alone)."""
        if usable_cpus() < 2:
            return None
        try:
            ctx = process_pool_context()
            # the queues first: they start the resource tracker, whose start unblocks SIGINT
            jobs, results = ctx.Queue(), ctx.Queue()
            # Ctrl-C held back while the processes start: the fork server (a fresh interpreter, started with the first
            # worker) and the worker inherit the blocked signal (they ignore it), so a Ctrl-C in their first
            # milliseconds prints no traceback of theirs, and none lands half-way through the start; this process gets
            # it when unblocked (CPython's resource tracker starts the same way)
            with sigint_held():
                proc = ctx.Process(target=worker_main, args=(jobs, results), daemon=True, name="spotlights-tracks")
                proc.start()
                worker = cls(proc, jobs, results)
        except Exception:  # no processes here (an unguarded script, a sandbox): the plan works in this process
            return None
        return worker

    def crop(
        self,
        key,
        points: np.ndarray,
        todo: list[int],
        boxes: list[Box],
        grow: float,
        ground_clearance: float,
        keep: bool = False,
    ) -> None:
        """Have the worker crop the tracked boxes ``todo`` (indices into the frame's ``boxes``) of frame ``key`` from
        its scan ``points`` (N, 3): the plan's crops (:meth:`TrackPlan.build` leaves their points None), made while
        the frames are still being read. ``keep``: the worker keeps the scan and, when it prepares the frame,
        makes its scene's crops too (:func:`spotlights.completion.frame.scene_crops`, :meth:`TrackPlan.frame_crops`)."""
        self.jobs.put(("scan", key, points, todo, boxes, grow, ground_clearance, keep))

    def send(self, plan: TrackPlan, keys: list) -> None:
        """Hand the worker the built ``plan`` (its tracks, their frames and refiners) and the frame order."""
        self.jobs.put(
            (
                "plan",
                dict(
                    policy=plan.policy,
                    config=plan.config,
                    refine=plan.refine,
                    max_translation=plan.max_translation,
                    max_yaw=plan.max_yaw,
                    tracks=plan.tracks,
                    where=plan.where,
                    keys=keys,
                ),
            )
        )

    def _next(self, plan: TrackPlan):
        """The worker's next message (waiting for it: ``wait_s``); raises what the worker raised,
        :class:`TrackWorkerDied` (one line) when its process ended without a word, or :class:`TrackWorkerStalled` (one line; the process stopped) when it
        sent nothing, not even a sign of life, for :data:`STALL_S` seconds."""
        with plan.timer("wait_s"):
            # seconds of silence, each poll counted for at most 2 POLL_S: a pause of this process (Ctrl-Z then fg, a
            # debugger; its worker paused with it) is not the worker's silence
            silent, before = 0.0, time.monotonic()
            while True:
                try:
                    msg = self.results.get(timeout=POLL_S)
                except Empty:
                    if not self.proc.is_alive():
                        raise TrackWorkerDied(
                            f"the track worker process ended (exit code {self.proc.exitcode}) before its results; "
                            "--no-track-worker refines and fuses the tracks in this process instead"
                        ) from None
                    now = time.monotonic()
                    silent, before = silent + min(now - before, 2 * POLL_S), now
                    if silent > STALL_S:
                        self.stop()
                        raise TrackWorkerStalled(
                            f"the track worker process made no progress for {STALL_S:g} s and was stopped; "
                            "--no-track-worker refines and fuses the tracks in this process instead"
                        ) from None
                    continue
                if msg[0] != "beat":
                    break
                silent, before = 0.0, time.monotonic()
        if msg[0] == "error":
            self.stop()
            raise msg[1]
        return msg

    def _apply(self, plan: TrackPlan, key, repl: dict) -> None:
        for i, box in repl.items():  # the frame's refined boxes (record() maps its completions with them)
            tr, pos = plan.where[key][i]
            tr.boxes[pos] = box

    def inputs(self, plan: TrackPlan, key: Hashable) -> tuple[dict[int, Box], dict[int, np.ndarray]]:
        """``(repl, extra)`` of frame ``key`` as :meth:`TrackPlan._inputs` gives them (the frames come in the order
        sent; those the frame loop skips are passed over). RuntimeError for a frame the worker was not sent."""
        while key not in self.pending and not self.done:
            msg = self._next(plan)
            if msg[0] == "done":
                self._final(plan, msg)
                break
            _, k, repl, extra, scene = msg
            self._apply(plan, k, repl)
            self.pending = {k: (repl, extra)}  # only the latest: the loop asks in order
            plan.scene_crops = {k: scene} if scene is not None else {}
        if key not in self.pending:
            raise RuntimeError(f"frame {key} was not planned, or asked for out of the order given to build()")
        return self.pending.pop(key)

    def _final(self, plan: TrackPlan, msg) -> None:
        _, state, seconds = msg
        for k, (boxes, status, n_points, n_fused, fused) in state.items():
            tr = plan.tracks[k]
            tr.boxes, tr.status, tr.fused = boxes, status, fused
            # the worker prepared every frame; the counts are those of the frames the loop asked for, as in one process
            asked = [key in plan.asked for key in tr.keys]
            tr.n_points = [c if a else 0 for c, a in zip(n_points, asked)]
            tr.n_fused = [c if a else 0 for c, a in zip(n_fused, asked)]
            tr.refiner = None  # the worker refined every frame
        for name, sec in seconds.items():
            plan.timer.add(name, sec)
        self.done = True
        self.pending.clear()
        self.stop()

    def finish(self, plan: TrackPlan) -> None:
        """Take the worker's remaining messages and its final state into ``plan``; end the process."""
        while not self.done:
            msg = self._next(plan)
            if msg[0] == "done":
                self._final(plan, msg)
            else:
                self._apply(plan, msg[1], msg[2])

    def stop(self) -> None:
        """End the process (now, when it has not finished). Idempotent."""
        self._finalizer()


def _end_worker(proc, jobs, results) -> None:
    """End a :class:`TrackWorker`'s process ``proc`` and close its queues (its ``stop``, and its finalizer)."""
    try:
        jobs.put(None)  # a worker still waiting for its plan returns
    except Exception:  # noqa: S110 - a closed queue: the process is ending anyway
        pass
    proc.join(timeout=POLL_S)
    if proc.is_alive():
        proc.terminate()
        proc.join(timeout=5)
    if proc.is_alive():  # stuck where SIGTERM does not reach it
        proc.kill()
        proc.join(timeout=5)
    for q in (jobs, results):
        q.cancel_join_thread()
        q.close()


__all__ = [
    "BEAT_S",
    "STALL_S",
    "TrackPlan",
    "TrackWorker",
    "TrackWorkerDied",
    "TrackWorkerStalled",
    "file_stem",
    "threads_beside_worker",
    "usable_cpus",
    "worker_main",
]
