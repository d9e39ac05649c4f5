"""``spotlights real``: real LiDAR datasets -> partial observations, completed frames, consistency (paper Table 2)."""

from __future__ import annotations

from dataclasses import dataclass

from ..completion.frame import HEADING_MARGIN
from ..completion.frame_selection import FramesSettings, parse_frames, parse_frames_range
from ..completion.frames import complete_frames
from ..data.store import MAX_PARTIAL_POINTS
from ..experiments.real_runs import (
    EvaluateSettings,
    ExtractSettings,
    ShowSettings,
    evaluate_file,
    extract_file,
    show_file,
)
from ..learning.fit import FIT_DOC, FIT_STEPS_DOC, parse_fit_steps
from ..options import option, settings_from_namespace
from ._util import (
    CROP_GROUND_HELP,
    CROP_MARGIN_HELP,
    DEVICE_HELP,
    MAX_BATCH,
    SEED_HELP,
    add_command,
    add_group,
    add_options,
    add_quiet,
    argparse_type,
    batch_size_number,
    crop_metres,
    non_negative_float,
    non_negative_int,
    positive_int,
    seed_number,
    unit_interval,
)
from .complete import (
    SNAP_HELP,
    SNAP_MIRROR_HELP,
    add_completion_arguments,
    add_track_arguments,
    check_track_arguments,
    warn,
)
from .view import add_html_argument

DETECTIONS_GROUP = "a detector's boxes instead of the dataset's (docs/tracking.md)"
FORMAT_CHOICES = ("kitti", "kitti360", "av2", "nuscenes", "generic")
SOURCE_HELP = (
    "kitti: a training/ folder (velodyne[_reduced]/, label_2/, calib/); kitti360: the KITTI-360 folder; "
    "av2: a log folder or a folder of logs; nuscenes: the folder with samples/ and the v1.0-* tables; "
    "generic: a scan file (see --boxes), a folder of scans with NAME.json box files, or a sequence .json. "
    "Several SOURCEs of one format are read one after another"
)


_frames_range = argparse_type(parse_frames_range)
_frames_select = argparse_type(parse_frames)


def _source():
    """The ``SOURCE`` positional of ``real extract`` and ``real complete``."""
    return option("source", nargs="+", metavar="SOURCE", help=SOURCE_HELP)


def _format():
    """``--format/-f`` of ``real extract`` and ``real complete``."""
    return option("--format", "-f", choices=FORMAT_CHOICES, help="dataset format")


@dataclass(kw_only=True)
class ReaderArguments:
    """How ``real extract`` and ``real complete`` read their SOURCEs (per format)."""

    velodyne: str = option(
        default="auto",
        choices=("auto", "velodyne", "velodyne_reduced"),
        help="kitti: which scan folder (default: velodyne/ if present, else velodyne_reduced/)",
    )
    sequence: list[str] | None = option(
        default=None,
        action="append",
        metavar="SEQ",
        help="kitti360: a sequence to read (e.g. 2013_05_28_drive_0000_sync); nuscenes: a scene name (e.g. "
        "scene-0523); repeatable; default all",
    )
    boxes: str | None = option(
        default=None,
        metavar="JSON",
        help="generic: the box file of a single scan SOURCE (default: the scan's name with .json)",
    )


@dataclass(kw_only=True)
class RealExtractOptions:
    """The own options of ``spotlights real extract``, added around :class:`ReaderArguments` (``--frames`` after
    them, then ``-q``); read as :class:`~spotlights.experiments.real_runs.ExtractSettings`."""

    source: list[str] = _source()
    format: str = _format()
    out: str = option("--out", "-o", metavar="FILE.h5", help="output HDF5 of observations")
    margin: float = option(default=0.15, type=crop_metres, metavar="M", help=CROP_MARGIN_HELP)
    ground_clearance: float = option(default=0.10, type=crop_metres, metavar="M", help=CROP_GROUND_HELP)
    min_points: int = option(default=10, type=int, metavar="K", help="skip boxes with fewer than K points (default 10)")
    points: int = option(
        default=256,
        type=positive_int,
        metavar="P",
        help=f"points per observation after resampling, 1..{MAX_PARTIAL_POINTS} (default 256)",
    )
    seed: int = option(default=0, type=seed_number, help=f"resampling seed, {SEED_HELP} (default 0)")
    classes: str = option(
        default="car,truck,caravan,trailer",
        help="comma-separated classes to keep (default: the paper's four, car,truck,caravan,trailer; also bus, "
        "construction, emergency)",
    )
    frames: tuple | None = option(
        default=None, type=_frames_range, metavar="START:STOP[:STEP]", help="kitti360: frame range"
    )


@dataclass(kw_only=True)
class RealCompleteOptions:
    """The own options of ``spotlights real complete``, added around :class:`ReaderArguments`,
    :class:`~spotlights.cli.complete.CompletionArguments` and :class:`~spotlights.cli.complete.TrackArguments`
    (:data:`REAL_COMPLETE_OUTPUTS`); read as :class:`~spotlights.completion.frame_selection.FramesSettings`."""

    source: list[str] = _source()
    format: str = _format()
    out: str = option(
        "--out",
        "-o",
        metavar="DIR",
        help="output folder: [SEQUENCE/]FRAME.ply (x y z, source, object), FRAME.json, FRAME.png, and summary.json",
    )
    frames: tuple | None = option(
        default=None,
        type=_frames_select,
        metavar="SPEC",
        help="frames to complete: START:STOP[:STEP] positions in the dataset's frame order, or frame ids separated by commas",
    )
    per_object: bool = option(
        default=False, action="store_true", help="also write FRAME_objects/object_<id>.ply per completed object"
    )
    no_pictures: bool = option(
        default=False,
        action="store_true",
        help="do not draw FRAME.png (a bird's-eye raster, drawn beside the loop)",
    )
    closeups: bool = option(
        default=False,
        action="store_true",
        help="FRAME.png also shows a 3-D close-up of every object with a 1 m ruler (matplotlib: most of a second a "
        "frame, drawn by --picture-workers processes)",
    )
    picture_workers: int | None = option(
        default=None,
        type=non_negative_int,
        metavar="N",
        help="processes that draw the frames' PNGs, N frames at once while the next frames are completed "
        "(default: none for the bird's-eye raster, drawn by the writer thread beside the frame loop; with "
        "--closeups one per CPU, at most 8, none on one CPU; 0: drawn in this process, one frame at a time; "
        "the same bytes either way)",
    )
    html: bool = option(
        default=False,
        action="store_true",
        help="also write FRAME.html, an interactive 3-D page per frame (needs plotly); the pages share "
        "OUT/plotly.min.js, so copy the folder as a whole: it opens offline",
    )
    resume: bool = option(
        default=False,
        action="store_true",
        help="skip the frames an earlier run with the same model and options finished (their FRAME.json exists; "
        "with --fuse, done with the same fusion: the outputs are those of one run)",
    )
    detections: str | None = option(
        default=None,
        metavar="FILE",
        group=DETECTIONS_GROUP,
        help="detector output in the dataset's format (nuscenes: a result JSON; kitti: a folder of result files with "
        "scores; generic: box JSON with scores), used instead of the dataset's boxes; needs --track",
    )
    track: bool = option(
        default=False,
        action="store_true",
        group=DETECTIONS_GROUP,
        help="give --detections track ids (the tracker of 'spotlights track')",
    )
    min_score: float | None = option(
        default=None,
        type=unit_interval,
        metavar="S",
        group=DETECTIONS_GROUP,
        help="drop detections scoring below S (default: none)",
    )


REAL_COMPLETE_OUTPUTS = ("per_object", "no_pictures", "closeups", "picture_workers", "html", "resume")
"""The options of ``real complete`` added after :class:`~spotlights.cli.complete.CompletionArguments`."""


@dataclass(kw_only=True)
class RealEvaluateOptions:
    """The options of ``spotlights real evaluate`` (then ``-q``); read as
    :class:`~spotlights.experiments.real_runs.EvaluateSettings`."""

    file: str = option("file", metavar="FILE.h5", help="observations from 'spotlights real extract'")
    checkpoint: list[str] | None = option(
        "--checkpoint",
        "-c",
        default=None,
        nargs="+",
        metavar="CKPT",
        help="one or more models: checkpoint files or short names ('default', 'paper', 'classes'); default: the package's default model",
    )
    classes: str | None = option(
        default=None,
        metavar="LIST",
        help="score only these classes, e.g. car,truck,trailer (default: every class in the file)",
    )
    equal_points: int = option(
        default=512,
        type=int,
        metavar="N",
        help="also score consistency with every completion brought to N points by farthest-point sampling (default 512; 0: not)",
    )
    equal_density: float = option(
        default=0.1,
        type=float,
        metavar="V",
        help="also score consistency with every completion voxel-downsampled to cells of side V (unit frame; "
        "default 0.1; 0: not): shapes compared at one resolution whatever the models' output densities, the "
        "headline for comparing models",
    )
    no_noise_floor: bool = option(
        default=False,
        action="store_true",
        help="skip the resampling noise floor (each observation completed again from a second 256-point resampling)",
    )
    no_heading_check: bool = option(
        default=False,
        action="store_true",
        help="skip counting heading flips (each observation completed with its box turned)",
    )
    heading_margin: float | None = option(
        default=None,
        type=float,
        metavar="M",
        help="margin of the counted heading flips: the turned heading wins when its fidelity is below (1 - M) x "
        f"the given one's (default {HEADING_MARGIN:g}, as 'complete --heading-check')",
    )
    names: list[str] | None = option(
        default=None,
        nargs="+",
        metavar="NAME",
        help="report row names, one per --checkpoint (default: the model names, told apart by file or run folder)",
    )
    out: str | None = option(
        "--out",
        "-o",
        default=None,
        metavar="PREFIX",
        help="writes PREFIX.md and PREFIX.json (default: FILE without .h5 + '_consistency')",
    )
    batch_size: int = option(
        default=64, type=batch_size_number, help=f"completion batch size, 1..{MAX_BATCH} (default 64)"
    )
    clip: float | None = option(
        default=None,
        type=unit_interval,
        metavar="T",
        help="depth clip passed to the models (default: each model's own)",
    )
    snap: float = option(
        default=0.0, type=non_negative_float, metavar="R", help=SNAP_HELP + "; needs --no-heading-check"
    )
    snap_mirror: bool = option(default=False, action="store_true", help=SNAP_MIRROR_HELP)
    fit: bool = option(default=False, action="store_true", help=FIT_DOC)
    fit_steps: int | None = option(default=None, type=argparse_type(parse_fit_steps), metavar="N", help=FIT_STEPS_DOC)
    device: str | None = option(default=None, help=DEVICE_HELP)
    reference: str | None = option(
        default=None,
        metavar="DATASET.h5",
        help="completion dataset whose ground-truth cars are the reference set of the minimal matching "
        "distance (MMD) reported beside consistency and fidelity (default: no MMD)",
    )
    reference_split: str | None = option(
        default=None,
        choices=["train", "val", "test"],
        help="use only this split of --reference (default: every model)",
    )
    resume: bool = option(
        default=False,
        action="store_true",
        help="reuse every model already scored in PREFIX.json (or in PREFIX.partial.json, which an interrupted "
        "run leaves) with the same name, the same checkpoint file contents and the same settings; score only "
        "the others (add a model to a table, or continue after Ctrl-C)",
    )


@dataclass(kw_only=True)
class RealShowOptions:
    """The own options of ``spotlights real show`` (then ``--html``); read as
    :class:`~spotlights.experiments.real_runs.ShowSettings`."""

    file: str = option("file", metavar="FILE.h5", help="observations from 'spotlights real extract'")
    checkpoint: str | None = option(
        "--checkpoint",
        "-c",
        default=None,
        metavar="CKPT",
        help="model: a checkpoint file or a short name ('default', 'paper', 'classes'); default: the package's default model",
    )
    no_completion: bool = option(
        default=False, action="store_true", help="draw the scan and the partial inputs only (no model)"
    )
    frame: str | None = option(
        default=None, metavar="ID", help="frame id (default: the frame with the most observations)"
    )
    sequence: str | None = option(
        default=None, metavar="SEQ", help="sequence / log of the frame, when frame ids repeat"
    )
    max_objects: int = option(
        default=6,
        type=int,
        metavar="K",
        help="close-ups of the K objects with most points (default 6)",
    )
    out: str | None = option(
        "--out",
        "-o",
        default=None,
        metavar="PNG",
        help="output picture (default: FILE_FRAME.png beside FILE; with --html alone, no picture)",
    )
    clip: float | None = option(
        default=None,
        type=unit_interval,
        metavar="T",
        help="depth clip passed to the model (default: its own)",
    )
    device: str | None = option(default=None, help=DEVICE_HELP)


def register(sub) -> None:
    rs = add_group(
        sub,
        "real",
        "real LiDAR data: extract vehicles, complete whole frames, score consistency, draw them",
        "spotlights real extract ../shared/data/lidar/nuscenes --format nuscenes --out nuscenes.h5",
    )

    p = add_command(
        rs,
        "extract",
        "cut the points of every vehicle box out of real scans into unit-frame partial observations (HDF5)",
        "spotlights real extract ../shared/data/lidar/kitti-object/training --format kitti --out kitti.h5",
        _extract,
    )
    add_options(p, RealExtractOptions, exclude=("frames",))
    add_options(p, ReaderArguments)
    add_options(p, RealExtractOptions, only=("frames",))
    add_quiet(p)

    p = add_command(
        rs,
        "complete",
        "complete every vehicle of every frame of a dataset: one scene PLY, JSON and picture per frame",
        "spotlights real complete ../shared/data/lidar/nuscenes --format nuscenes --out nuscenes_completed",
        _complete,
    )
    add_options(p, RealCompleteOptions, only=("source", "format", "out"))
    add_options(p, ReaderArguments)
    add_options(p, RealCompleteOptions, only=("frames",))
    add_completion_arguments(p, single=False)
    add_options(p, RealCompleteOptions, only=REAL_COMPLETE_OUTPUTS)
    add_track_arguments(p)
    add_options(p, RealCompleteOptions, only=("detections", "track", "min_score"))
    add_quiet(p)

    p = add_command(
        rs,
        "evaluate",
        "complete the tracked observations with each model and write the consistency table (Markdown + JSON)",
        "spotlights real evaluate av2.h5 --checkpoint default runs/pcn/best.pt --out results/av2_consistency",
        _evaluate,
    )
    add_options(p, RealEvaluateOptions)
    add_quiet(p)

    p = add_command(
        rs,
        "show",
        "draw one scan: raw points (grey), partial inputs (purple), completions (green), in the sensor frame",
        "spotlights real show kitti.h5 --checkpoint runs/sanet/best.pt --frame 002155 --out kitti_002155.png",
        _show,
    )
    add_options(p, RealShowOptions)
    add_html_argument(p)


def _extract(args) -> int:
    extract_file(settings_from_namespace(ExtractSettings, args), say=print)
    return 0


def _evaluate(args) -> int:
    evaluate_file(settings_from_namespace(EvaluateSettings, args), say=print, warn=warn)
    return 0


def _show(args) -> int:
    show_file(settings_from_namespace(ShowSettings, args), say=print)
    return 0


def _complete(args) -> int:
    check_track_arguments(args)  # --max-gap goes with --fuse
    complete_frames(settings_from_namespace(FramesSettings, args), say=print, warn=warn)
    return 0
