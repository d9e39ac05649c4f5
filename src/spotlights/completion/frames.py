"""Completing every frame of a LiDAR dataset into a folder: what ``spotlights real complete`` runs.

:class:`ReaderOptions` opens a dataset of any supported format with its format's options checked;
:class:`FramesSettings` adds the frame selection, the outputs, the track fusion (``fuse``) and the
:class:`~spotlights.completion.scan.CompletionOptions`; :func:`complete_frames` runs the
resumable per-frame loop and writes, per frame, ``[SEQUENCE/]FRAME.ply`` (x y z, ``source``, ``object``;
scan frame, metres), ``FRAME.png``, ``FRAME.html``, ``FRAME_objects/`` and, last, ``FRAME.json`` (a frame
with its JSON is done: ``resume`` skips it), then ``summary.json``.

File names: :func:`frame_stems` gives every frame a name no other frame (or file of the run) maps to.
"""

from __future__ import annotations

import os
from collections import Counter, deque
from concurrent.futures import Future
from pathlib import Path

import numpy as np
from tqdm import tqdm

from .. import logs
from ..data.tracks import TIME_UNIT_S
from ..errors import ParameterError
from ..learning.inference import BaseCompleter
from ..learning.runtime import runs_with
from ..options import check_threads
from ..outputs import output_folder, sweep_folder_temporaries
from ..processes import shared_thread_pool
from ..timing import StageTimer
from ..viz import write_png
from ..viz.html import write_plotlyjs
from ..viz.rerun_log import check_rerun_path, open_recording
from .detections import check_detection_options, tracked_reader
from .frame import complete_scene, fallback_hint
from .frame_selection import (
    FRAME_KEYS,
    FramesSettings,
    done_frame,
    frame_stems,
    select_frames,
    stem_file,
)
from .fusion import TrackPlan, TrackWorker, threads_beside_worker, usable_cpus
from .picture_processes import PICTURE_BACKLOG, PictureProcesses
from .pictures import render_result, render_result_html
from .results import SceneResult
from .scan import Say, ScanSettings, complete_scan
from .scene_config import SceneConfig
from .writing import fallback_counts, write_json, write_scene

# ---------------------------------------------------------------------------- frame selection


# ---------------------------------------------------------------------------- the frame loop


class _FrameRun:
    """The state of one ``real complete`` run: settings, reader, model, output folder, totals."""

    def __init__(
        self,
        s: FramesSettings,
        reader,
        config: SceneConfig,
        completer,
        out: Path,
        tracks,
        recorder=None,
        fallback=None,
        pictures: PictureProcesses | None = None,
        warn: Say = logs.warning,
    ) -> None:
        self.s, self.reader, self.config = s, reader, config
        self.completer, self.out, self.tracks, self.recorder = completer, out, tracks, recorder
        self.fallback = fallback  # the model of --fallback, or None
        self.precision = str(getattr(completer, "precision", "fp32"))  # the model's, resolved ("auto": bf16 or fp32)
        self.frames: list[dict] = []
        self.warnings: list[str] = []
        self.totals: dict = {"boxes": 0, "completed": 0, "flipped": 0, "completion_points": 0, "skipped": {}}
        self.totals["resumed"] = 0
        self.t_model = 0.0
        # with fuse, frames skipped by resume whose completions a track may still need (its latest completion, for
        # tracks/<track>.ply): key -> (boxes, fused inputs, crops, the tracks it is the latest completed frame of)
        self.resumed: dict = {}
        self.latest: dict = {}  # track key -> the resumed frame holding its latest completion so far
        # a frame's files are written by one thread, in frame order, while the next frames are completed: one frame
        # in flight, or PICTURE_BACKLOG more than there are picture processes (each drawing one frame's PNG, below the
        # loop's priority: the pictures catch up in the loop's idle moments, and at the end)
        self.pictures = pictures
        self.in_flight = pictures.workers + PICTURE_BACKLOG if pictures is not None else 1
        self._written: deque[Future] = deque()
        self._stopped = False  # a write failed, or the run ends early: the frames not yet written write nothing
        self._no_lidar: set[str] = set()  # sequences whose LiDAR place is unknown (said once each)
        self.warn = warn

    def complete(self, key: tuple, stem: Path) -> dict | None:
        """Complete frame ``key`` and write its files; its summary, or None for a scan with too few points."""
        if self._stopped:  # a frame in flight failed to write: stop now (its error is raised), not N frames later
            self.wait_writes()
        config = self.config
        frame = None if self.tracks is None else self.tracks.take(key)  # read once: the track plan kept it
        frame = self.reader.load(key) if frame is None else frame
        info = dict(
            sequence=frame.sequence,
            frame_id=frame.frame_id,
            timestamp=frame.timestamp,
            scan=frame.scan_path,
            labels=frame.label_path,
        )
        if len(frame.points) < config.min_points:
            self.frames.append(
                {**info, "status": f"scan holds {len(frame.points)} points (< {config.min_points}): not completed"}
            )
            return None
        tracks = self.tracks
        boxes, extra = (frame.boxes, None) if tracks is None else tracks.frame_inputs(key, frame.boxes)
        crops = None if tracks is None else tracks.frame_crops(key)  # made by the track worker, if any
        result = self._scene(frame, boxes, extra, crops)
        if tracks is not None:
            tracks.place_shapes(key, result)  # with track_shape: the track's shape where this frame does not make it
        # at most in_flight - 1 frames before this one are not on disk yet (without picture processes none: the frame
        # before is, its PNG too); a failed write stops the run at the next wait, and no later frame writes a file
        self.wait_writes(keep=self.in_flight - 1)
        if tracks is not None:
            tracks.record(key, result)
            for o in result.completed:  # a resumed frame before this one no longer holds these tracks' latest
                hit = tracks.where.get(key, {}).get(o.index)
                if hit is not None:
                    self._not_latest(hit[0], key)
        if self.recorder is not None:  # rerun (spotlights.viz.rerun_log)
            self.recorder.log_frame(result, frame.boxes, frame.timestamp, frame.sequence, extra)
        prefix = f"{frame.sequence}/" if frame.sequence else ""
        title = f"{self.reader.format} {prefix}{frame.frame_id}: {result.model}"
        summ = {**info, "ply": str(stem_file(stem, ".ply")), **result.summary()}
        if self.precision != "fp32":
            summ["precision"] = self.precision  # compared by resume (absent: fp32, as frames of older runs)
        if tracks is not None:
            summ["fuse"] = tracks.settings()  # compared by resume
        detections = getattr(self.reader, "detection_settings", None)
        if detections is not None:
            summ["detections"] = detections  # compared by resume: boxes from other detections are other boxes
        if frame.sensor_to_world is not None:
            summ["sensor_to_world"] = [[float(v) for v in row] for row in frame.sensor_to_world]
        self._write(result, stem, Path(frame.scan_path).name, title, summ)
        return summ

    def _write(self, result: SceneResult, stem: Path, scan_name: str, title: str, summ: dict) -> None:
        """Write a frame's files in the order of one process - its PLY (+ per-object files), PNG, HTML, then its
        JSON (last: a frame with its JSON is done, for resume) - on the writer thread (one: the frames are written
        in their order) while the next frames are completed (:meth:`complete` lets at most :attr:`in_flight`
        frames wait to be written; a failed write stops the run, and no later frame writes a file). The PNG is
        drawn by a picture process (:class:`PictureProcesses`) as soon as the frame is complete, else by the
        writer thread; the pictures are matplotlib ``Figure`` objects drawn by Agg, without pyplot's global state
        (:mod:`spotlights.viz`)."""
        s, out = self.s, self.out
        per_object = stem_file(stem, "_objects") if s.per_object else None
        png = stem_file(stem, ".png")
        picture = not s.no_pictures and bool(result.completed)
        drawn = self.pictures.draw(result, title) if picture and self.pictures is not None else None

        def files() -> None:
            if self._stopped:  # an earlier frame's write failed, or the run stopped: this frame writes nothing
                return
            try:
                write_scene(result, stem_file(stem, ".ply"), per_object=per_object, scan_name=scan_name)
                if drawn is not None:
                    write_png(PictureProcesses.png(drawn, png), png)
                elif picture:
                    render_result(result, png, title, s.closeups)
                if s.html:
                    js = os.path.relpath(write_plotlyjs(out), stem.parent).replace(os.sep, "/")
                    render_result_html(result, stem_file(stem, ".html"), title, js)
                write_json(stem_file(stem, ".json"), summ)
            except BaseException:
                self._stopped = True
                raise

        self._written.append(shared_thread_pool("write", 1).submit(files))

    def wait_writes(self, keep: int = 0) -> None:
        """Wait until at most ``keep`` frames are not on disk yet, oldest first (a write's error raised here). A
        write leaves the queue once done: a Ctrl-C while waiting leaves it there for :meth:`close` to wait for."""
        while len(self._written) > keep:
            self._written[0].result()
            self._written.popleft()

    def close(self) -> None:
        """Stop: the frames not yet written write nothing, the one being written is finished (also after an error
        or Ctrl-C: nothing half-written is left)."""
        self._stopped = True
        while self._written:
            # finished either way; reached after the run raised (an error of its own, Ctrl-C), so a write error
            # too is dropped here: the run's own error is the one reported
            self._written.popleft().exception()

    def _scene(self, frame, boxes, extra, crops) -> SceneResult:
        """The completion of one frame (its boxes, fused inputs and crops as the track plan gives them)."""
        s = self.s
        return complete_scene(
            frame.points,
            boxes,
            self.completer,
            self.config,
            checkpoint=s.checkpoint_name,
            sensor=self._sensor(frame),
            extra_points=extra,
            fallback=self.fallback,
            fallback_name=s.fallback_model,
            crops=crops,
        )

    def _sensor(self, frame) -> np.ndarray | None:
        """The LiDAR's place in ``frame``'s scan frame for :func:`complete_scene`; None (the scan frame's origin) where
        the dataset does not know it (an Argoverse 2 log without calibration), said once per sequence."""
        if frame.lidar_known():
            return frame.lidar_origin()
        if frame.sequence not in self._no_lidar:
            self._no_lidar.add(frame.sequence)
            self.warn(
                f"{frame.sequence or frame.frame_id}: the LiDAR's place is unknown (no calibration in the dataset): "
                "its frames are completed as seen from the scan frame's origin"
            )
        return None

    def _not_latest(self, tr, key) -> None:
        """A frame after the resumed one that held ``tr``'s latest completion completed it: that one is not needed."""
        old = self.latest.pop(id(tr), None)
        if old is not None and old != key:
            held = self.resumed[old][3]
            held.discard(id(tr))
            if not held:
                del self.resumed[old]

    def skip_fused(self, key: tuple, summ: dict) -> None:
        """A frame done by an earlier run, with fuse: its track inputs are asked for all the same (counted in
        tracks.json as in one run; the worker's order kept) and kept while it holds a track's latest completion
        (:meth:`finish_tracks` completes it again, in memory, for that track's file)."""
        tracks = self.tracks
        frame = tracks.take(key)
        frame = self.reader.load(key) if frame is None else frame
        boxes, extra = tracks.frame_inputs(key, frame.boxes)
        crops = tracks.frame_crops(key)
        completed = {o["index"] for o in summ["objects"] if o["status"] == "completed"}
        if tracks.shapes is not None and tracks.shapes.needed(tracks.where.get(key, {}), completed):
            # it makes a track's shape, which the frames after it show: completed again (in memory, not rewritten)
            tracks.place_shapes(key, self._scene(frame, boxes, extra, crops))
        held = set()
        for i, (tr, _) in tracks.where.get(key, {}).items():
            if i in completed:
                self._not_latest(tr, key)
                self.latest[id(tr)] = key
                held.add(id(tr))
        if held:
            self.resumed[key] = (boxes, extra, crops, held)

    def finish_tracks(self) -> None:
        """Complete again the resumed frames that hold a track's latest completion (the same inputs: the same
        completion as the run that wrote them) and record it, so that tracks/<track>.ply is that of one run."""
        for key, (boxes, extra, crops, _) in self.resumed.items():
            result = self._scene(self.reader.load(key), boxes, extra, crops)
            self.tracks.place_shapes(key, result)
            self.tracks.record(key, result)
        self.resumed.clear()

    def count(self, key: tuple, summ: dict) -> None:
        """Add a frame's summary to the run's totals, warnings and frame list."""
        seq, fid = key
        totals = self.totals
        done = [o for o in summ["objects"] if o["status"] == "completed"]
        totals["boxes"] += summ["n_boxes"]
        totals["completed"] += summ["n_completed"]
        totals["flipped"] += summ["n_flipped"]
        totals["completion_points"] += sum(o["n_completion"] for o in done)
        by = Counter(o["completed_by"] for o in done if o.get("completed_by"))  # boxes a fallback completed
        if by:
            totals["completed_by"] = dict(Counter(totals.get("completed_by", {})) + by)
        for k, v in summ["skipped"].items():
            totals["skipped"][k] = totals["skipped"].get(k, 0) + v
        for k, v in summ.get("not_completed", {}).items():  # boxes the model did not learn, per class
            totals.setdefault("not_completed", {})[k] = totals.get("not_completed", {}).get(k, 0) + v
        self.t_model += summ["timings"].get("total_s", 0.0)
        self.warnings += [f"{seq + '/' if seq else ''}{fid} {w}" for w in summ["warnings"]]
        self.frames.append({k: summ.get(k) for k in FRAME_KEYS} | {"n_warnings": len(summ["warnings"])})

    def run(self, keys: list[tuple]) -> None:
        """Every frame of ``keys``: skipped when done (``resume``), else completed; then counted."""
        stems = frame_stems(keys)
        model = self.completer.model_name
        fuse = None if self.tracks is None else self.tracks.settings()
        try:
            self._run(keys, stems, model, fuse)
            self.wait_writes()  # the last frame's files: part of the run (and of its wall time)
        finally:
            self.close()

    def _run(self, keys: list[tuple], stems: dict, model: str, fuse: dict | None) -> None:
        for key in tqdm(keys, desc="complete", unit="frame", disable=self.s.quiet):
            stem = self.out / stems[key]
            summ = (
                done_frame(
                    stem_file(stem, ".json"),
                    self.config,
                    model,
                    self.s.checkpoint_name,
                    fuse,
                    self.precision,
                    getattr(self.reader, "detection_settings", None),
                )  # fmt: skip
                if self.s.resume
                else None
            )
            if summ is not None:
                self.totals["resumed"] += 1
                if self.tracks is not None:
                    self.skip_fused(key, summ)
            else:
                summ = self.complete(key, stem)
            if summ is not None:
                self.count(key, summ)
        if self.tracks is not None:
            self.finish_tracks()

    def _fallback_hint(self) -> bool:
        """True when, without a fallback model, some box was left as observed points for a vehicle class that the
        main model did not learn and the packaged class model did (:func:`spotlights.completion.frame.fallback_hint`)."""
        domain = getattr(self.completer, "domain", None)
        if self.fallback is not None or domain is None:
            return False
        return any(fallback_hint(c, domain) for c in self.totals.get("not_completed", {}))

    def line(self, n_frames: int) -> str:
        """The run's one summary line."""
        totals = self.totals
        flips = f", {totals['flipped']} heading flip(s)" if self.config.heading_check else ""
        sk = ", ".join(f"{k} {v}" for k, v in sorted(totals["skipped"].items()))
        resumed = f"; {totals['resumed']} frame(s) already done" if totals["resumed"] else ""
        by = fallback_counts(totals.get("completed_by", {}))
        return (
            f"{n_frames} frame(s), {totals['boxes']} boxes: {totals['completed']} completed"
            + (f" ({by})" if by else "")
            + flips
            + (f", skipped {sk}" if sk else "")
            + (
                " (not_learned: left as observed points; "
                + ("--fallback classes completes trucks, buses, vans and trailers; " if self._fallback_hint() else "")
                + "--complete-unknown completes them)"
                if "not_learned" in sk
                else ""
            )
            + f" ({self.completer.model_name}, {runs_with(self.completer)}, {self.t_model:.1f} s of completion{resumed})"
            + f" -> {self.out}/"
        )


def complete_frames(
    s: FramesSettings, say: Say = logs.info, warn: Say = logs.warning, completer: BaseCompleter | None = None
) -> dict:
    """Complete the selected frames of a dataset into the folder ``s.out`` as ``spotlights real complete`` does.

    Opens the dataset (:meth:`ReaderOptions.open`), selects ``s.frames``, builds the track plan (``s.fuse``),
    loads the model (:meth:`CompletionOptions.load_completer`), then per frame writes its PLY (scan frame,
    metres), PNG, HTML, per-object files and, last, its JSON (``s.resume`` skips frames whose JSON says the same
    model and options); then ``summary.json`` (+ per-track files with ``fuse``). The output folder is removed
    again when nothing could be written. ``warn`` receives the out-of-domain warnings (ten at most: the rest
    are counted), ``say`` the summary line; ``completer``: a model already loaded (default: the one ``s``
    names). Returns the run's summary (the content of ``summary.json``).
    """
    check_threads(s.threads)  # also when a model is given (loading one checks it)
    check_detection_options(s.detections, s.track, s.format, len(s.source), s.min_score)
    # the track worker's interpreter starts while the dataset is opened and read (refusals stop it)
    early = TrackWorker.start() if s.track_worker and s.window.fuses else None
    try:
        reader = s.open()
        if s.detections is not None:
            reader = tracked_reader(reader, s.detections, s.source[0], s.min_score, s.sequence, max_gap=s.max_gap)
        keys = select_frames(reader.frame_keys(), s.frames)
        if not keys:
            raise ParameterError("`frames` selects no frame", "frames")
        config = s.scene_config()
        if s.rerun is not None:
            check_rerun_path(s.rerun)
        tracks = s.track_plan(reader, keys, config, early)
    except BaseException:
        if early is not None:
            early.stop()
        raise
    pictures = None
    try:
        pictures = PictureProcesses.start(s, len(keys))  # their start and imports overlap the model's load
        # onnxruntime's threads leave a core to the track worker, as threads_beside_worker does torch's
        beside = max(1, usable_cpus() - 1) if tracks is not None and tracks.worker_process is not None else None
        completer = s.load_completer(beside, len(keys)) if completer is None else completer
        s.check_snap(completer)
        fallback = s.load_fallback(beside, len(keys))  # loaded beside the main model, before any output exists
        # the folder is removed again if nothing could be written; the recording is written only when the run ends
        with (
            output_folder(s.out) as out,
            open_recording(s.rerun, TIME_UNIT_S.get(reader.format)) as rec,
            threads_beside_worker(tracks, s.threads),  # a core left to the track worker, if any (or --threads)
        ):
            return _run_frames(s, reader, keys, config, completer, out, tracks, say, warn, rec, fallback, pictures)
    finally:
        if pictures is not None:
            pictures.close()  # idle by now unless something failed
        if tracks is not None:
            tracks.close()  # the worker process, if any (done by now unless something failed)


def complete_input(
    s: ScanSettings, say: Say = logs.info, warn: Say = logs.warning, completer: BaseCompleter | None = None
) -> SceneResult | dict:
    """What ``spotlights complete INPUT`` runs: one scan file (:func:`~spotlights.completion.scan.
    complete_scan`: ``s.out`` is its scene file; returns its :class:`SceneResult`), or a multi-frame generic scene
    (a folder of frames or a sequence ``.json``: :func:`complete_frames` of :meth:`FramesSettings.of_scene`,
    ``s.out`` a folder, with ``s.fuse``, ``s.refine_boxes``, ``s.max_gap``, ``s.rerun`` and ``s.track_worker``; returns the run's
    summary). ``say``, ``warn`` and ``completer`` as those functions take them."""
    if s.multi_frame:
        if s.sensor is not None:
            raise ParameterError(
                f"{s.input}: `sensor` is for one scan; a multi-frame scene's frames give their own", "sensor"
            )
        return complete_frames(FramesSettings.of_scene(s), say=say, warn=warn, completer=completer)
    return complete_scan(s, say=say, warn=warn, completer=completer)


def _run_frames(
    s: FramesSettings,
    reader,
    keys: list,
    config: SceneConfig,
    completer: BaseCompleter,
    out: Path,
    tracks: TrackPlan | None,
    say: Say,
    warn: Say,
    recorder=None,
    fallback=None,
    pictures: PictureProcesses | None = None,
) -> dict:
    """The loop of :func:`complete_frames` in the folder ``out`` that exists, and its summary."""
    sweep_folder_temporaries(out)  # what a killed run was writing (a 0-byte .FRAME.png.PID-X.part.png)
    run = _FrameRun(s, reader, config, completer, out, tracks, recorder, fallback, pictures, warn)
    timer = StageTimer()
    with timer("frames"):
        run.run(keys)
    summary = dict(
        source=[str(x) for x in s.source],
        format=reader.format,
        model=completer.model_name,
        checkpoint=s.checkpoint_name,
        runtime=str(getattr(completer, "runtime", "torch")),  # what ran the model, and at what precision
        precision=str(getattr(completer, "precision", "fp32")),
        n_frames=len(keys),
        totals=run.totals,
        heading_check=config.heading_check,
        snap=config.snap,  # the snap radius (0: off) and its mirror, as every frame's JSON says
        snap_mirror=config.snap_mirror,
        completion_seconds=run.t_model,
        wall_seconds=timer.total,
        warnings=run.warnings,
        frames=run.frames,
    )
    if tracks is not None:
        per_track = tracks.summary()  # made once: tracks.json and summary.json's totals
        tracks.write(out, completer.model_name, summary=per_track)
        summary["tracks"] = {k: v for k, v in per_track.items() if k != "tracks"}
    write_json(out / "summary.json", summary)
    shown = run.warnings
    if len(shown) > 10:
        shown = shown[:5] + [f"... and {len(shown) - 5} more out-of-domain boxes (see {out / 'summary.json'})"]
    for w in shown:
        warn(w)
    say(run.line(len(keys)))
    return summary


__all__ = ["complete_frames", "complete_input"]
