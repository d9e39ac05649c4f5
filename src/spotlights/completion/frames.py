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

import json
import os
from collections import Counter, deque
from collections.abc import Sequence
from concurrent.futures import Future
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from tqdm import tqdm

from .. import logs
from ..data.real import open_reader
from ..data.real.base import SceneReader
from ..data.tracks import MAX_GAP_S, TIME_UNIT_S, WindowPolicy, parse_window
from ..errors import ParameterError, ProcessFailure
from ..geometry.io import POINT_SUFFIXES, ply_is_whole
from ..learning.inference import BaseCompleter
from ..learning.runtime import runs_with
from ..options import check_threads
from ..outputs import output_folder, sweep_folder_temporaries
from ..processes import shared_thread_pool, sigint_held, start_process_pool, stop_process_pool
from ..timing import StageTimer
from ..viz import write_png
from ..viz.html import write_plotlyjs
from ..viz.rerun_log import check_rerun_path, open_recording
from .detections import check_detection_options, tracked_reader
from .frame import (
    SceneConfig,
    SceneResult,
    complete_scene,
    fallback_counts,
    fallback_hint,
    render_result,
    render_result_html,
    result_png,
    write_scene,
)
from .fusion import TrackPlan, TrackWorker, threads_beside_worker, usable_cpus
from .names import FRAME_SUFFIXES, RESERVED_FRAMES, file_stem, safe_name, sequence_folders, unique_names
from .scan import CompletionOptions, Say, ScanSettings, complete_scan, write_json


def frame_stems(keys) -> dict[tuple, Path]:
    """The output stem of each frame key ``(sequence, frame_id)``, relative to the output folder:
    ``SEQUENCE/FRAME`` (``FRAME`` without a sequence; :mod:`spotlights.completion.names`). Distinct frames never
    share a file, none is a file of the run (``summary.json``, ``tracks.json``); a frame's name depends on the other
    frames only when two names differ in letter case alone (``A`` and ``a`` both take the digest)."""
    seqs = sequence_folders(keys)
    # a frame beside the sequence folders must not take a folder's name with one of its suffixes
    beside = [d[: -len(x)] for d in seqs.values() for x in FRAME_SUFFIXES if d.endswith(x)]
    by_seq: dict[str, list[str]] = {}
    for s, f in keys:
        by_seq.setdefault(str(s) if s else "", []).append(str(f))
    stems = {}
    for s, fids in by_seq.items():
        names = unique_names(fids, reserved=() if s else [*RESERVED_FRAMES, *beside])
        stems.update({(s, f): Path(seqs[s]) / names[f] if s else Path(names[f]) for f in fids})
    return {(s, f): stems[(str(s) if s else "", str(f))] for s, f in keys}


def _with(stem: Path, suffix: str) -> Path:
    """``stem`` + ``suffix`` (not ``with_suffix``: a frame id ``x.1`` keeps its ``.1``)."""
    return stem.parent / (stem.name + suffix)


# ---------------------------------------------------------------------------- frame selection


def parse_frames_range(text: str) -> tuple[int, int | None, int]:
    """``"START:STOP[:STEP]"`` (each part may be empty: ``":10"``, ``"5:"``) -> ``(start, stop, step)``, as a
    Python slice (stop None: to the end; step >= 1). Raises :class:`ParameterError` for anything else."""
    parts = text.split(":")
    try:
        if len(parts) not in (2, 3):
            raise ValueError
        start = int(parts[0]) if parts[0] else 0
        stop = int(parts[1]) if parts[1] else None
        step = int(parts[2]) if len(parts) == 3 and parts[2] else 1
        if step < 1:
            raise ValueError
    except ValueError:
        raise ParameterError(f"expected START:STOP[:STEP] with integers, got {text!r}") from None
    return (start, stop, step)


def parse_frames(text: str) -> tuple[str, object]:
    """``--frames`` of ``real complete``: ``("range", (start, stop, step))`` for ``START:STOP[:STEP]``
    (positions in the dataset's frame order), ``("ids", [frame ids])`` for ids separated by commas."""
    if ":" in text:
        return ("range", parse_frames_range(text))
    ids = [t.strip() for t in text.split(",") if t.strip()]
    if not ids:
        raise ParameterError(f"expected START:STOP[:STEP] or frame ids separated by commas, got {text!r}")
    return ("ids", ids)


def select_frames(keys: list[tuple], spec: tuple | None) -> list[tuple]:
    """The frame keys ``(sequence, frame_id)`` a :func:`parse_frames` ``spec`` selects (None: all), in order.
    Raises :class:`ParameterError` naming frame ids that are not in ``keys``."""
    if spec is None:
        return keys
    kind, val = spec
    if kind == "range":
        start, stop, step = val
        return keys[start:stop:step]
    wanted = list(val)
    known = {k[1] for k in keys}
    missing = [f for f in wanted if f not in known]
    if missing:
        ex = ", ".join(sorted(known)[:5])
        raise ParameterError(
            f"frame(s) {', '.join(missing)} not in the dataset (frames: {ex}{', ...' if len(known) > 5 else ''})"
        )
    return [k for k in keys if k[1] in set(wanted)]


@dataclass(kw_only=True)
class ReaderOptions:
    """A dataset and its format's options (``real extract``, ``real complete``).

    source : one or more dataset folders or files of one format; format : kitti, kitti360, av2, nuscenes or
    generic; velodyne : kitti's scan folder (``auto``, ``velodyne``, ``velodyne_reduced``); sequence : kitti360
    sequences or nuScenes scene names (None: all); boxes : generic, the box file of a single scan.
    """

    source: Sequence[str]
    format: str
    velodyne: str = "auto"
    sequence: list | None = None
    boxes: str | None = None

    def open(self, frames: tuple | None = None) -> SceneReader:
        """The dataset's reader (``frames``: kitti360's ``(start, stop, step)`` range). Raises a one-line
        :class:`ParameterError` for an option of another format."""
        options: dict = {}
        if self.format == "kitti":
            options["velodyne"] = self.velodyne
        elif self.format in ("kitti360", "nuscenes"):
            options["sequences"] = self.sequence
            if self.format == "kitti360" and frames is not None:
                options["frames"] = frames
        elif self.format == "generic":
            options["boxes"] = self.boxes
        for name, val, fmts in (
            ("velodyne", self.velodyne != "auto", ("kitti",)),
            ("sequence", self.sequence, ("kitti360", "nuscenes")),
            ("frames", frames is not None, ("kitti360",)),
            ("boxes", self.boxes, ("generic",)),
        ):
            if val and self.format not in fmts:
                raise ParameterError(f"`{name}` applies to `format` {' or '.join(fmts)} only", name, "format")
        return open_reader(self.source, self.format, **options)


# ---------------------------------------------------------------------------- the frame loop


@dataclass(kw_only=True)
class FramesSettings(ReaderOptions, CompletionOptions):
    """What ``spotlights real complete`` does: a dataset (:class:`ReaderOptions`), the model and its options
    (:class:`~spotlights.completion.scan.CompletionOptions`), and

    out : the output folder; frames : a :func:`parse_frames` selection (None: every frame);
    per_object, no_pictures, html : per-object PLYs, no PNGs, an HTML page per frame; closeups : the PNGs show a
    matplotlib close-up of every object beside the bird's-eye raster; picture_workers : processes that draw the
    PNGs, several frames at once (None: none for the raster, drawn by the writer thread beside the frame loop;
    :func:`picture_workers`' default with closeups; 0: the writer thread draws them, one frame at a time);
    resume : skip frames an earlier run with the same model and options finished;
    fuse : the frames of a track fused into its input (``"none"``, ``"all"``, ``"past:K"``, ``"centered:K"`` or a
    :class:`~spotlights.data.tracks.WindowPolicy`); refine_boxes : register and correct the boxes (with fuse);
    max_gap : the longest time between two frames of one track, seconds; rerun : a ``.rrd`` file that also
    receives every frame on a time line (:mod:`spotlights.viz.rerun_log`; None: none); quiet : no progress bar;
    track_worker : with fuse, refine the boxes and fuse the windows in a second process, a frame ahead of the
    completion (:class:`~spotlights.completion.fusion.TrackWorker`: the same outputs, two cores);
    detections, track, min_score : a detector's boxes (a file of the dataset's format) tracked and used instead of
    the dataset's boxes, those scoring below ``min_score`` dropped (:mod:`spotlights.completion.detections`);
    track_shape : with fuse all or past:K, one shape per track shown in every frame through its box
    (:mod:`spotlights.completion.shapes`).
    """

    out: str
    frames: tuple | None = None
    per_object: bool = False
    no_pictures: bool = False
    closeups: bool = False
    picture_workers: int | None = None
    html: bool = False
    resume: bool = False
    fuse: WindowPolicy | str = field(default_factory=lambda: parse_window("none"))
    refine_boxes: bool = False
    max_gap: float = MAX_GAP_S
    rerun: str | None = None
    quiet: bool = False
    track_worker: bool = True
    detections: str | None = None
    track: bool = False
    min_score: float | None = None
    track_shape: bool = False

    @classmethod
    def of_scene(cls, s: ScanSettings) -> FramesSettings:
        """What ``spotlights complete SCENE`` does with a multi-frame generic scene (``s.multi_frame``): the
        settings of ``real complete SCENE --format generic --no-pictures`` with ``s``'s model options, track
        options and output folder ``s.out``. Raises a one-line :class:`ParameterError` for an ``--out`` that names
        a point-cloud file and for the options of one scan (its boxes, axes, crop, per-file outputs)."""
        if Path(s.out).suffix.lower() in POINT_SUFFIXES:
            raise ParameterError(
                f"`out` {s.out}: {s.input} is a multi-frame scene, written to a folder: give `out` DIR "
                "(DIR/[SEQUENCE/]FRAME.ply per frame, summary.json; with `fuse` tracks/ and tracks.json)",
                "out",
                "fuse",
            )
        for name, given in (
            ("--boxes/--calib/--box/--center/--size/--yaw", (s.boxes, s.calib, s.box, s.center, s.size, s.yaw)),
            ("--crop/--no-crop", (s.crop, s.no_crop or None)),
            ("--up/--forward", (None if s.up == "z" else s.up, None if s.forward == "x" else s.forward)),
            ("--per-object/--summary/--show/--html", (s.per_object, s.summary, s.show, s.html)),
            ("--closeups", (s.closeups or None,)),
        ):
            if any(v is not None for v in given):
                raise ParameterError(
                    f"{name} apply to one scan; {s.input} is a multi-frame scene (its box files name the boxes, z "
                    "up; DIR gets FRAME.json per frame and summary.json; 'real complete `format` generic' draws "
                    "pictures, per-object files and pages)",
                    "format",
                )
        return cls(
            **{f.name: getattr(s, f.name) for f in fields(CompletionOptions)},
            source=[s.input],
            format="generic",
            out=s.out,
            no_pictures=True,
            fuse=s.fuse,
            refine_boxes=s.refine_boxes,
            max_gap=s.max_gap,
            rerun=s.rerun,
            track_worker=s.track_worker,
            quiet=s.quiet,
            track_shape=s.track_shape,
        )

    @property
    def window(self) -> WindowPolicy:
        """:attr:`fuse` as a :class:`~spotlights.data.tracks.WindowPolicy`."""
        return parse_window(self.fuse) if isinstance(self.fuse, str) else self.fuse

    def track_plan(
        self, reader: SceneReader, keys: list, config: SceneConfig, worker: TrackWorker | None = None
    ) -> TrackPlan | None:
        """The built :class:`~spotlights.completion.fusion.TrackPlan` of ``fuse`` (None without fusion); ``worker``:
        its :class:`~spotlights.completion.fusion.TrackWorker`, started earlier (default: one started here with
        ``track_worker``)."""
        if self.window.fuses:
            use = worker if worker is not None else self.track_worker
            # a window without a shape per track (track_shape) is refused here, before any frame is read
            plan = TrackPlan(
                self.window, config, self.refine_boxes, self.max_gap, worker=use, track_shape=self.track_shape
            )
            try:
                return plan.build(reader, keys)
            except BaseException:
                plan.close()
                raise
        if self.refine_boxes:
            raise ParameterError(
                "`refine_boxes` needs `fuse` all, past:K or centered:K (the frames to register to)",
                "refine_boxes",
                "fuse",
            )
        if self.track_shape:
            raise ParameterError(
                "`track_shape` needs `fuse` all (one shape per track) or past:K (made again every K frames)",
                "track_shape",
                "fuse",
            )
        return None


def done_frame(
    path: Path, config: SceneConfig, model: str, checkpoint: str, fuse: dict | None = None, precision: str = "fp32"
) -> dict | None:
    """The summary of a frame finished by an earlier run with the same model and options (``fuse``: the track
    fusion's, :meth:`~spotlights.completion.fusion.TrackPlan.settings`; None: none; ``precision``: the model's,
    ``fp32`` or ``bf16``), else None."""
    try:
        summ = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(summ, dict):
        return None  # not a frame's summary: the frame is completed again
    ply = summ.get("ply")
    if isinstance(ply, str):  # the frame's scene PLY beside its JSON: gone, empty or cut short, completed again
        if not ply_is_whole(path.parent / Path(ply).name):
            return None
    cfg = asdict(config)
    cfg["clip"] = str(cfg["clip"]) if cfg["clip"] is not None and not isinstance(cfg["clip"], float) else cfg["clip"]
    earlier = summ.get("config")
    if isinstance(earlier, dict):
        earlier = {"snap": 0.0, "snap_mirror": False} | earlier  # runs before --snap existed did not snap
    same = (
        summ.get("model") == model
        and summ.get("checkpoint") == checkpoint
        and json.loads(json.dumps(cfg)) == earlier
        and summ.get("fuse") == fuse
        and summ.get("precision", "fp32") == precision
    )
    return summ if same else None


#: The keys of a frame's summary that ``summary.json`` lists per frame.
FRAME_KEYS = ("sequence", "frame_id", "timestamp", "scan", "ply", "n_boxes", "n_completed", "n_flipped", "skipped")


#: The most processes that draw PNGs by default (:func:`picture_workers`); each holds ~140 MB (matplotlib).
PICTURE_WORKERS_MAX = 8

#: Seconds a frame's PNG may take in a picture process before the run stops with one line (a hung process; a
#: frame of scene-0523 takes about 0.5 s, a slow machine a few): the run never waits for ever on a picture.
PICTURE_STALL_S = 120.0

#: Seconds the picture processes get to finish the picture they draw when the run ends (then they are ended).
PICTURE_CLOSE_S = 10.0


def picture_workers(asked: int | None, n_frames: int) -> int:
    """How many processes draw a run's PNGs (:class:`PictureProcesses`): ``asked`` (``--picture-workers``), by
    default one per usable CPU (:func:`~spotlights.completion.fusion.usable_cpus`: drawing a frame costs several
    times its completion, so the frame loop's own CPU is mostly free), at most :data:`PICTURE_WORKERS_MAX`, none on
    one CPU; never more than ``n_frames`` and none for a single frame (0: the writer thread draws them, one frame
    at a time, as before)."""
    if asked is None:
        cpus = min(usable_cpus(), PICTURE_WORKERS_MAX)
        n = cpus if cpus >= 2 else 0
    else:
        n = int(asked)
    if n < 0:
        raise ParameterError(f"`picture_workers` must be >= 0, got {n}", "picture_workers")
    return 0 if n_frames < 2 else min(n, n_frames)


#: How much lower a picture process runs than the frame loop (``os.nice``): a picture waits for a free core, the
#: frame loop does not wait for the picture.
PICTURE_NICE = 5


def _lower_priority() -> None:
    """A picture process's start: :data:`PICTURE_NICE` below its parent (where the system allows it)."""
    try:
        os.nice(PICTURE_NICE)
    except (AttributeError, OSError):  # pragma: no cover - not POSIX, or refused
        pass


def _ready_to_draw(closeups: bool = True) -> None:
    """In a picture process (which imported this module, so the drawing code, to run this): import what draws
    (matplotlib's Agg and 3-D axes for the close-ups; PIL for the raster) while the frame loop's model loads."""
    if closeups:
        import matplotlib.backends.backend_agg  # noqa: F401
        import mpl_toolkits.mplot3d  # noqa: F401
    else:
        import PIL.PngImagePlugin  # noqa: F401


class PictureProcesses:
    """Worker processes (:func:`~spotlights.processes.start_process_pool`: the fork server, Ctrl-C left to this
    process) that draw frames' PNGs (:func:`~spotlights.completion.frame.result_png`), ``workers`` frames at once,
    while the frame loop completes the next ones. The bytes are those of drawing in this process (the same
    function; matplotlib's defaults in both: rcParams changed in this process do not reach the workers); the
    writer thread writes them in frame order."""

    def __init__(self, workers: int, closeups: bool = False) -> None:
        self.workers = int(workers)
        self.closeups = bool(closeups)  # matplotlib's close-ups too (result_png)
        pool = None
        try:
            # Ctrl-C held back while they start (as the track worker's start): the fork server and the workers
            # inherit the blocked signal (they ignore it), and none lands half-way through the start; one that came
            # meanwhile is raised as the block ends, and stops the processes here
            # the resource tracker started (which unblocks SIGINT) first
            pool = start_process_pool(self.workers, _lower_priority)
            with sigint_held():
                for _ in range(self.workers):  # each task starts a process: their imports overlap the model's load
                    pool.submit(_ready_to_draw, self.closeups)
        except BaseException:
            if pool is not None:
                stop_process_pool(pool)
            raise
        self.pool = pool

    @classmethod
    def start(cls, s: FramesSettings, n_frames: int) -> PictureProcesses | None:
        """The processes of a run of ``s`` over ``n_frames`` frames, started; None when no picture is drawn,
        :func:`picture_workers` says 0, or no process can be started here (an unguarded script, a sandbox: the
        writer thread draws the pictures, as with 0)."""
        # the bird's-eye raster costs a few hundredths of a second: one process draws it (none on one CPU), beside the
        # frame loop and below its priority; the close-ups (matplotlib) get one process per CPU by default
        raster = 1 if usable_cpus() >= 2 else 0
        asked = s.picture_workers if s.closeups or s.picture_workers is not None else raster
        n = 0 if s.no_pictures else picture_workers(asked, n_frames)
        if n == 0:
            return None
        try:
            return cls(n, s.closeups)
        except Exception:
            return None

    def draw(self, result: SceneResult, title: str) -> Future:
        """Start drawing ``result``'s PNG; a future of its bytes (:meth:`png`). When a picture process has died
        already (the pool is broken), the future holds that error: it is reported in frame order, by :meth:`png`."""
        from concurrent.futures.process import BrokenProcessPool

        try:
            return self.pool.submit(result_png, result, title, self.closeups)
        except BrokenProcessPool as exc:
            failed: Future = Future()
            failed.set_exception(exc)
            return failed

    @staticmethod
    def png(drawn: Future, path: Path) -> bytes:
        """The bytes of ``drawn`` (waiting for them, :data:`PICTURE_STALL_S` at most); a one-line
        :class:`~spotlights.errors.ProcessFailure` naming ``path`` when the process drawing it ended first (killed,
        say for memory) or took longer than that (hung)."""
        from concurrent.futures import TimeoutError as FutureTimeout
        from concurrent.futures.process import BrokenProcessPool

        hint = "--picture-workers 0 draws the pictures in this process"
        try:
            return drawn.result(timeout=PICTURE_STALL_S)
        except BrokenProcessPool:
            raise ProcessFailure(
                f"{path}: the process drawing it ended before it was done (killed, or out of memory?); {hint}"
            ) from None
        except FutureTimeout:
            raise ProcessFailure(
                f"{path}: the process drawing it made no progress for {PICTURE_STALL_S:g} s and was stopped; {hint}"
            ) from None

    def close(self) -> None:
        """Stop the processes: what is not being drawn yet is dropped, a picture being drawn gets
        :data:`PICTURE_CLOSE_S` to finish (the run has waited for its frames in flight first anyway), then the
        processes still alive are ended (:func:`~spotlights.processes.stop_process_pool`: workers ended mid-task can
        leave the resource tracker warning of a leaked semaphore at exit, seen after a Ctrl-C during the frames)."""
        stop_process_pool(self.pool, grace=PICTURE_CLOSE_S)


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
        # in flight, or one more than there are picture processes (each drawing one frame's PNG, below the loop's
        # priority: a picture may finish a frame later)
        self.pictures = pictures
        self.in_flight = pictures.workers + 1 if pictures is not None else 1
        self._written: deque[Future] = deque()
        self._stopped = False  # a write failed, or the run ends early: the frames not yet written write nothing

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
        # at most in_flight - 1 frames before this one are not on disk yet (one: the frame before is, its PNG too); a
        # failed write stops the run at the next wait, and no later frame writes a file
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
        summ = {**info, "ply": str(_with(stem, ".ply")), **result.summary()}
        if self.precision != "fp32":
            summ["precision"] = self.precision  # compared by resume (absent: fp32, as frames of older runs)
        if tracks is not None:
            summ["fuse"] = tracks.settings()  # compared by resume
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
        per_object = _with(stem, "_objects") if s.per_object else None
        png = _with(stem, ".png")
        picture = not s.no_pictures and bool(result.completed)
        drawn = self.pictures.draw(result, title) if picture and self.pictures is not None else None

        def files() -> None:
            if self._stopped:  # an earlier frame's write failed, or the run stopped: this frame writes nothing
                return
            try:
                write_scene(result, _with(stem, ".ply"), per_object=per_object, scan_name=scan_name)
                if drawn is not None:
                    write_png(PictureProcesses.png(drawn, png), png)
                elif picture:
                    render_result(result, png, title, s.closeups)
                if s.html:
                    js = os.path.relpath(write_plotlyjs(out), stem.parent).replace(os.sep, "/")
                    render_result_html(result, _with(stem, ".html"), title, js)
                write_json(_with(stem, ".json"), summ)
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
            sensor=frame.lidar_origin(),
            extra_points=extra,
            fallback=self.fallback,
            fallback_name=s.fallback_model,
            crops=crops,
        )

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
                done_frame(_with(stem, ".json"), self.config, model, self.s.checkpoint_name, fuse, self.precision)
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
        completer = s.load_completer(beside) if completer is None else completer
        s.check_snap(completer)
        fallback = s.load_fallback(beside)  # loaded beside the main model, before any output exists
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
    run = _FrameRun(s, reader, config, completer, out, tracks, recorder, fallback, pictures)
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


__all__ = [
    "FramesSettings",
    "PictureProcesses",
    "ReaderOptions",
    "complete_frames",
    "complete_input",
    "done_frame",
    "file_stem",
    "frame_stems",
    "parse_frames",
    "parse_frames_range",
    "picture_workers",
    "safe_name",
    "select_frames",
]
