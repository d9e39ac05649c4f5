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

import hashlib
import json
import math
from collections.abc import Hashable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..data.real.base import Frame
from ..data.tracks import (
    FLAGGED,
    MAX_GAP_S,
    MAX_TRANSLATION_M,
    MAX_YAW_RAD,
    TIME_UNIT_S,
    TrackFrame,
    TrackRefiner,
    WindowPolicy,
    check_track,
    fuse_track,
)
from ..errors import ParameterError
from ..geometry.boxes import Box
from ..geometry.io import save_ply
from ..outputs import atomic_output
from ..timing import StageTimer
from .frame import SOURCE_COMPLETION, SOURCE_PARTIAL, SceneConfig, SceneResult, _selected
from .names import file_stem, sequence_folders, unique_names
from .shapes import SIZE_TOLERANCE, TrackShapes, split_by_size
from .track_windows import TrackWindows, _crops, _Track
from .track_worker import (
    BEAT_S,
    CGROUP_CPU_MAX,
    POLL_S,
    STALL_S,
    TrackWorker,
    TrackWorkerDied,
    TrackWorkerStalled,
    cgroup_cpu_limit,
    threads_beside_worker,
    usable_cpus,
    worker_main,
)

if TYPE_CHECKING:
    from multiprocessing.process import BaseProcess

#: The most scan points :meth:`TrackPlan.build` keeps of the frames it read, for the frame loop to take
#: (:meth:`TrackPlan.take`) instead of reading them again (2^24: ~200 MB; 480 nuScenes keyframes). Frames
#: beyond it are read again.
KEEP_POINTS = 1 << 24


def _time_unit(fmt: str, n_frames: int) -> float:
    """Seconds per timestamp unit of the reader format ``fmt``; one-line :class:`ParameterError` for a format
    without tracks over time or a selection of fewer than 2 frames (``n_frames``)."""
    unit = TIME_UNIT_S.get(fmt)
    if unit is None:
        raise ParameterError(
            f"`format` {fmt} has no tracks over time: `fuse` needs a sequence format", "format", "fuse"
        )
    if n_frames < 2:
        raise ParameterError(f"`fuse` needs a sequence of at least 2 frames; the selection holds {n_frames}", "fuse")
    return unit


def _untracked_error(frame: Frame, untracked: int) -> ParameterError:
    """The one-line refusal of a frame with ``untracked`` completed boxes without a track id."""
    where = f"{frame.sequence}/{frame.frame_id}" if frame.sequence else frame.frame_id
    return ParameterError(
        f"frame {where} ({frame.label_path or frame.scan_path}): {untracked} vehicle box(es) without a "
        "track id; `fuse` needs a track id on every box it completes (track_id in the box files)",
        "fuse",
    )


class TrackPlan(TrackWindows):
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
        super().__init__(policy, config, refine, max_translation, max_yaw)
        self.max_gap_s = max_gap_s
        self.folders: dict[str, str] | None = None  # sequence -> its folder, for the frames' keys (build)
        self.kept: dict = {}  # frame key -> the Frame build read, until the frame loop takes it (KEEP_POINTS)
        # refine and fuse in a worker process (TrackWorker) while this one completes: True starts one in build, a
        # TrackWorker started earlier (its interpreter ready by then) is used as it is
        self.worker = bool(worker)
        self._worker: TrackWorker | None = worker if isinstance(worker, TrackWorker) else None
        self.scene_crops: dict = {}  # frame key -> the worker's crops of its scene (frame_crops), the latest only
        self.asked: set = set()  # frame keys frame_inputs was called for (the frames whose points are counted)
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
        unit = _time_unit(reader.format, len(keys))
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
            self._collect(key, frame, unit, grow)
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
            self._start_track(tr, grow)
        if self._worker is not None:
            self.start_worker(keys, self._worker)
        return self

    def _completes(self, box: Box) -> bool:
        """Whether the frame loop completes ``box`` (selected by the config, and valid)."""
        return _selected(box, self.config) and box.is_valid()

    def _collect(self, key, frame: Frame, unit: float, grow: float) -> None:
        """Add frame ``key``'s tracked boxes to their tracks (their crops grown by ``grow`` metres, timestamps times
        ``unit`` seconds); one-line :class:`ParameterError` when a completed box has no track id."""
        # the LiDAR's place; the scan frame's origin where it is unknown (as the frame loop completes that frame)
        origin = frame.lidar_origin() if frame.lidar_known() else np.zeros(3)
        todo = [i for i, b in enumerate(frame.boxes) if self._completes(b) and b.track_id.strip()]
        untracked = sum(1 for b in frame.boxes if self._completes(b) and not b.track_id.strip())
        todo_boxes = [frame.boxes[i] for i in todo]
        for i, b, crop in zip(todo, todo_boxes, self._track_crops(key, frame, todo, grow)):
            tr = self.tracks.setdefault((frame.sequence, b.track_id), _Track(frame.sequence, b.track_id))
            tr.keys.append(key)
            tr.box_index.append(i)
            tr.frames.append(TrackFrame(crop, b, origin, float(frame.timestamp) * unit))
            self.where.setdefault(key, {})[i] = (tr, len(tr.frames) - 1)
        if untracked:
            raise _untracked_error(frame, untracked)

    def _track_crops(self, key, frame: Frame, todo: list[int], grow: float) -> list:
        """The crops (k, 3) of frame ``key``'s tracked boxes ``todo`` (scan frame), or None each where the worker
        crops them (it is sent the scan here)."""
        if self._worker is None:
            return _crops(frame.points, [frame.boxes[i] for i in todo], grow, self.config.ground_clearance)
        keep = key in self.kept  # the frame loop takes this frame: the worker also makes its scene's crops
        if todo or keep:
            self._worker.crop(key, frame.points, todo, frame.boxes, grow, self.config.ground_clearance, keep)
        return [None] * len(todo)

    def _start_track(self, tr: _Track, grow: float) -> None:
        """Give a collected track its given boxes, statuses, zero point counts and (``refine``) its refiner."""
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
        super().finish()

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


# the worker process's names, importable from here too (spotlights.completion.track_worker holds them)
__all__ = [
    "BEAT_S",
    "CGROUP_CPU_MAX",
    "KEEP_POINTS",
    "POLL_S",
    "STALL_S",
    "TrackPlan",
    "TrackWorker",
    "TrackWorkerDied",
    "TrackWorkerStalled",
    "cgroup_cpu_limit",
    "file_stem",
    "threads_beside_worker",
    "usable_cpus",
    "worker_main",
]
