"""``spotlights real``: real LiDAR datasets -> partial observations, completed frames, consistency (paper Table 2)."""

from __future__ import annotations

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
from ..options import settings_from_namespace
from ._util import (
    DEVICE_HELP,
    MAX_BATCH,
    SEED_HELP,
    add_command,
    add_crop_arguments,
    add_group,
    add_quiet,
    argparse_type,
    batch_size_number,
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

FORMAT_CHOICES = ("kitti", "kitti360", "av2", "nuscenes", "generic")
SOURCE_HELP = (
    "kitti: a training/ folder (velodyne[_reduced]/, label_2/, calib/); kitti360: the KITTI-360 folder; "
    "av2: a log folder or a folder of logs; nuscenes: the folder with samples/ and the v1.0-* tables; "
    "generic: a scan file (see --boxes), a folder of scans with NAME.json box files, or a sequence .json. "
    "Several SOURCEs of one format are read one after another"
)


_frames_range = argparse_type(parse_frames_range)
_frames_select = argparse_type(parse_frames)


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
    p.add_argument("source", nargs="+", metavar="SOURCE", help=SOURCE_HELP)
    p.add_argument("--format", "-f", required=True, choices=FORMAT_CHOICES, help="dataset format")
    p.add_argument("--out", "-o", required=True, metavar="FILE.h5", help="output HDF5 of observations")
    add_crop_arguments(p)
    p.add_argument(
        "--min-points", type=int, default=10, metavar="K", help="skip boxes with fewer than K points (default 10)"
    )
    p.add_argument(
        "--points",
        type=positive_int,
        default=256,
        metavar="P",
        help=f"points per observation after resampling, 1..{MAX_PARTIAL_POINTS} (default 256)",
    )
    p.add_argument("--seed", type=seed_number, default=0, help=f"resampling seed, {SEED_HELP} (default 0)")
    p.add_argument(
        "--classes",
        default="car,truck,caravan,trailer",
        help="comma-separated classes to keep (default: the paper's four, car,truck,caravan,trailer; also bus, "
        "construction, emergency)",
    )
    _reader_arguments(p)
    p.add_argument(
        "--frames", type=_frames_range, default=None, metavar="START:STOP[:STEP]", help="kitti360: frame range"
    )
    add_quiet(p)

    p = add_command(
        rs,
        "complete",
        "complete every vehicle of every frame of a dataset: one scene PLY, JSON and picture per frame",
        "spotlights real complete ../shared/data/lidar/nuscenes --format nuscenes --out nuscenes_completed",
        _complete,
    )
    p.add_argument("source", nargs="+", metavar="SOURCE", help=SOURCE_HELP)
    p.add_argument("--format", "-f", required=True, choices=FORMAT_CHOICES, help="dataset format")
    p.add_argument(
        "--out",
        "-o",
        required=True,
        metavar="DIR",
        help="output folder: [SEQUENCE/]FRAME.ply (x y z, source, object), FRAME.json, FRAME.png, and summary.json",
    )
    _reader_arguments(p)
    p.add_argument(
        "--frames",
        type=_frames_select,
        default=None,
        metavar="SPEC",
        help="frames to complete: START:STOP[:STEP] positions in the dataset's frame order, or frame ids separated by commas",
    )

    add_completion_arguments(p, single=False)
    p.add_argument(
        "--per-object", action="store_true", help="also write FRAME_objects/object_<id>.ply per completed object"
    )
    p.add_argument(
        "--no-pictures", action="store_true", help="do not draw FRAME.png (a bird's-eye raster, drawn beside the loop)"
    )
    p.add_argument(
        "--closeups",
        action="store_true",
        help="FRAME.png also shows a 3-D close-up of every object with a 1 m ruler (matplotlib: most of a second a "
        "frame, drawn by --picture-workers processes)",
    )
    p.add_argument(
        "--picture-workers",
        type=non_negative_int,
        default=None,
        metavar="N",
        help="processes that draw the frames' PNGs, N frames at once while the next frames are completed "
        "(default: none for the bird's-eye raster, drawn by the writer thread beside the frame loop; with "
        "--closeups one per CPU, at most 8, none on one CPU; 0: drawn in this process, one frame at a time; "
        "the same bytes either way)",
    )
    p.add_argument(
        "--html",
        action="store_true",
        help="also write FRAME.html, an interactive 3-D page per frame (needs plotly); the pages share "
        "OUT/plotly.min.js, so copy the folder as a whole: it opens offline",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="skip the frames an earlier run with the same model and options finished (their FRAME.json exists; "
        "with --fuse, done with the same fusion: the outputs are those of one run)",
    )
    add_track_arguments(p)
    g = p.add_argument_group("a detector's boxes instead of the dataset's (docs/tracking.md)")
    g.add_argument(
        "--detections",
        metavar="FILE",
        help="detector output in the dataset's format (nuscenes: a result JSON; kitti: a folder of result files with "
        "scores; generic: box JSON with scores), used instead of the dataset's boxes; needs --track",
    )
    g.add_argument(
        "--track", action="store_true", help="give --detections track ids (the tracker of 'spotlights track')"
    )
    g.add_argument(
        "--min-score", type=unit_interval, metavar="S", help="drop detections scoring below S (default: none)"
    )
    add_quiet(p)

    p = add_command(
        rs,
        "evaluate",
        "complete the tracked observations with each model and write the consistency table (Markdown + JSON)",
        "spotlights real evaluate av2.h5 --checkpoint default runs/pcn/best.pt --out results/av2_consistency",
        _evaluate,
    )
    p.add_argument("file", metavar="FILE.h5", help="observations from 'spotlights real extract'")
    p.add_argument(
        "--checkpoint",
        "-c",
        nargs="+",
        default=None,
        metavar="CKPT",
        help="one or more models: checkpoint files or short names ('default', 'paper', 'classes'); default: the package's default model",
    )
    p.add_argument(
        "--classes",
        default=None,
        metavar="LIST",
        help="score only these classes, e.g. car,truck,trailer (default: every class in the file)",
    )
    p.add_argument(
        "--equal-points",
        type=int,
        default=512,
        metavar="N",
        help="also score consistency with every completion brought to N points by farthest-point sampling (default 512; 0: not)",
    )
    p.add_argument(
        "--equal-density",
        type=float,
        default=0.1,
        metavar="V",
        help="also score consistency with every completion voxel-downsampled to cells of side V (unit frame; "
        "default 0.1; 0: not): shapes compared at one resolution whatever the models' output densities, the "
        "headline for comparing models",
    )
    p.add_argument(
        "--no-noise-floor",
        action="store_true",
        help="skip the resampling noise floor (each observation completed again from a second 256-point resampling)",
    )
    p.add_argument(
        "--no-heading-check",
        action="store_true",
        help="skip counting heading flips (each observation completed with its box turned)",
    )
    p.add_argument(
        "--heading-margin",
        type=float,
        default=None,
        metavar="M",
        help="margin of the counted heading flips: the turned heading wins when its fidelity is below (1 - M) x "
        f"the given one's (default {HEADING_MARGIN:g}, as 'complete --heading-check')",
    )
    p.add_argument(
        "--names",
        nargs="+",
        default=None,
        metavar="NAME",
        help="report row names, one per --checkpoint (default: the model names, told apart by file or run folder)",
    )
    p.add_argument(
        "--out",
        "-o",
        default=None,
        metavar="PREFIX",
        help="writes PREFIX.md and PREFIX.json (default: FILE without .h5 + '_consistency')",
    )
    p.add_argument(
        "--batch-size", type=batch_size_number, default=64, help=f"completion batch size, 1..{MAX_BATCH} (default 64)"
    )
    p.add_argument(
        "--clip",
        type=unit_interval,
        default=None,
        metavar="T",
        help="depth clip passed to the models (default: each model's own)",
    )
    p.add_argument(
        "--snap", type=non_negative_float, default=0.0, metavar="R", help=SNAP_HELP + "; needs --no-heading-check"
    )
    p.add_argument("--snap-mirror", action="store_true", help=SNAP_MIRROR_HELP)
    p.add_argument("--device", default=None, help=DEVICE_HELP)
    p.add_argument(
        "--reference",
        default=None,
        metavar="DATASET.h5",
        help="completion dataset whose ground-truth cars are the reference set of the minimal matching "
        "distance (MMD) reported beside consistency and fidelity (default: no MMD)",
    )
    p.add_argument(
        "--reference-split",
        default=None,
        choices=["train", "val", "test"],
        help="use only this split of --reference (default: every model)",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="reuse every model already scored in PREFIX.json (or in PREFIX.partial.json, which an interrupted "
        "run leaves) with the same name, the same checkpoint file contents and the same settings; score only "
        "the others (add a model to a table, or continue after Ctrl-C)",
    )
    add_quiet(p)

    p = add_command(
        rs,
        "show",
        "draw one scan: raw points (grey), partial inputs (purple), completions (green), in the sensor frame",
        "spotlights real show kitti.h5 --checkpoint runs/sanet/best.pt --frame 002155 --out kitti_002155.png",
        _show,
    )
    p.add_argument("file", metavar="FILE.h5", help="observations from 'spotlights real extract'")
    p.add_argument(
        "--checkpoint",
        "-c",
        default=None,
        metavar="CKPT",
        help="model: a checkpoint file or a short name ('default', 'paper', 'classes'); default: the package's default model",
    )
    p.add_argument("--no-completion", action="store_true", help="draw the scan and the partial inputs only (no model)")
    p.add_argument(
        "--frame", default=None, metavar="ID", help="frame id (default: the frame with the most observations)"
    )
    p.add_argument("--sequence", default=None, metavar="SEQ", help="sequence / log of the frame, when frame ids repeat")
    p.add_argument(
        "--max-objects",
        type=int,
        default=6,
        metavar="K",
        help="close-ups of the K objects with most points (default 6)",
    )
    p.add_argument(
        "--out",
        "-o",
        default=None,
        metavar="PNG",
        help="output picture (default: FILE_FRAME.png beside FILE; with --html alone, no picture)",
    )
    p.add_argument(
        "--clip",
        type=unit_interval,
        default=None,
        metavar="T",
        help="depth clip passed to the model (default: its own)",
    )
    p.add_argument("--device", default=None, help=DEVICE_HELP)
    add_html_argument(p)


def _reader_arguments(p) -> None:
    p.add_argument(
        "--velodyne",
        default="auto",
        choices=("auto", "velodyne", "velodyne_reduced"),
        help="kitti: which scan folder (default: velodyne/ if present, else velodyne_reduced/)",
    )
    p.add_argument(
        "--sequence",
        action="append",
        default=None,
        metavar="SEQ",
        help="kitti360: a sequence to read (e.g. 2013_05_28_drive_0000_sync); nuscenes: a scene name (e.g. "
        "scene-0523); repeatable; default all",
    )
    p.add_argument(
        "--boxes",
        default=None,
        metavar="JSON",
        help="generic: the box file of a single scan SOURCE (default: the scan's name with .json)",
    )


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
