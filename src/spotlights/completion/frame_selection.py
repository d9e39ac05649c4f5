"""Which frames of a dataset ``real complete`` completes and where their files go: the reader's options
(:class:`ReaderOptions`), the run's settings (:class:`FramesSettings`), the frame selection (``--frames``), the
frames' file names (:func:`frame_stems`) and what marks a frame done (:func:`done_frame`)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from ..data.real import open_reader
from ..data.real.base import SceneReader
from ..data.tracks import MAX_GAP_S, WindowPolicy, parse_window
from ..errors import ParameterError
from ..geometry.io import POINT_SUFFIXES, ply_is_whole
from .frame import (
    SceneConfig,
)
from .fusion import TrackPlan, TrackWorker
from .names import FRAME_SUFFIXES, RESERVED_FRAMES, sequence_folders, unique_names
from .scan import CompletionOptions, ScanSettings


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


def stem_file(stem: Path, suffix: str) -> Path:
    """``stem`` + ``suffix`` (not ``with_suffix``: a frame id ``x.1`` keeps its ``.1``)."""
    return stem.parent / (stem.name + suffix)


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
    path: Path,
    config: SceneConfig,
    model: str,
    checkpoint: str,
    fuse: dict | None = None,
    precision: str = "fp32",
    detections: dict | None = None,
) -> dict | None:
    """The summary of a frame finished by an earlier run with the same model and options (``fuse``: the track
    fusion's, :meth:`~spotlights.completion.fusion.TrackPlan.settings`; None: none; ``precision``: the model's,
    ``fp32`` or ``bf16``; ``detections``: what tracked boxes were made from, ``TrackedReader.detection_settings``;
    None: the dataset's own boxes), else None."""
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
        and json.loads(json.dumps(summ.get("detections"))) == json.loads(json.dumps(detections))
    )
    return summ if same else None


#: The keys of a frame's summary that ``summary.json`` lists per frame.
FRAME_KEYS = ("sequence", "frame_id", "timestamp", "scan", "ply", "n_boxes", "n_completed", "n_flipped", "skipped")
