"""``spotlights complete``: complete the vehicles of a LiDAR scan (a whole frame with its boxes, or one object)."""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

from ..completion.frames import complete_input
from ..completion.scan import ScanSettings
from ..completion.shapes import SIZE_TOLERANCE
from ..data.tracks import MAX_GAP_S, MAX_TRANSLATION_M, MAX_YAW_RAD, WINDOW_HELP, WindowPolicy, parse_window
from ..errors import ParameterError
from ..learning.fit import FIT_DOC, FIT_STEPS_DOC, parse_fit_steps
from ..options import option, settings_from_namespace
from ._util import (
    CROP_GROUND_HELP,
    CROP_MARGIN_HELP,
    DEVICE_HELP,
    SEED_HELP,
    add_command,
    add_options,
    argparse_type,
    crop_metres,
    non_negative_float,
    positive_float,
    positive_int,
    seed_number,
    thread_count,
    unit_interval,
)
from .view import add_html_argument

CROP_DOC = (
    "each box's points: the box grown by --margin on its sides and top, its bottom raised by --ground-clearance "
    "(ground returns)"
)


SNAP_HELP = (
    "SA-Nets: a predicted ray that passes within R (unit frame: the box's half diagonal; 0.05 is ~13 cm on a car) of "
    "an observed point takes its depth from the scan, so the completion keeps what the LiDAR saw instead of the "
    "shape the model remembers; not onto a point hidden behind the predicted surface unless the LiDAR saw through "
    "it; a point-set model (a --fallback baseline) completes unsnapped (default 0: off; docs/learning.md, 'Snapping "
    "to the observed points': more complete on vehicles of an unseen source, less consistent from frame to frame "
    "on real scans)"
)


SNAP_MIRROR_HELP = (
    "with --snap R: also snap to the observed points' mirror image across the box's length-height plane (vehicles "
    "are left-right symmetric), so the side the LiDAR did not see follows the side it saw (docs/learning.md)"
)


CROP_GROUP = "crop (" + CROP_DOC + ")"
MODEL_INPUT_GROUP = "model input (the same observation always gives the same completion)"
TRACKS_GROUP = "tracks of a multi-frame input (fuse each vehicle's frames in its box frame; docs/real-data.md)"


@dataclass(kw_only=True)
class CompletionArguments:
    """Options shared by ``complete`` and ``real complete``: model, selection, crop, input, heading check
    (``--crop`` and ``--no-crop``: ``complete`` alone, a single object)."""

    checkpoint: str | None = option(
        "--checkpoint",
        "-c",
        default=None,
        metavar="CKPT",
        help="model: a checkpoint file or a short name, 'default' (the package's default model, cars, used when "
        "this is not given), 'paper' (the paper-faithful SA-Net) or 'classes' (cars, vans, trucks, buses, "
        "trailers; the default model's --fallback)",
    )
    classes: str | None = option(
        default=None,
        metavar="LIST",
        help="comma-separated classes to complete (default: every vehicle class: car, truck, caravan, trailer, "
        "bus, construction, emergency; the default model learned cars, its --fallback the others but construction "
        "and emergency vehicles, which are left as observed points)",
    )
    fallback: str = option(
        default="auto",
        metavar="CKPT",
        help="a second model for the boxes --checkpoint's model did not learn but it did (a checkpoint file or short "
        "name); 'auto' (default): 'classes', the packaged class model (vans, trucks, buses, trailers), beside the "
        "car-only default model, none beside a model you chose; 'none': such boxes are left as observed points",
    )
    complete_unknown: bool = option(
        default=False,
        action="store_true",
        help="also complete boxes whose class (or size, far outside its class's range) the model did not learn "
        "(default: left as their observed points and counted as not_learned)",
    )
    keep_observed: bool = option(
        default=True,
        action=argparse.BooleanOptionalAction,
        help="return each object's observed points (the model's input) beside its predicted ones (default on; "
        "fidelity and the heading check score the predicted points alone)",
    )
    snap: float = option(
        default=0.0, type=non_negative_float, metavar="R", help=SNAP_HELP + "; not with --heading-check"
    )
    snap_mirror: bool = option(default=False, action="store_true", help=SNAP_MIRROR_HELP)
    fit: bool = option(default=False, action="store_true", help=FIT_DOC)
    fit_steps: int | None = option(default=None, type=argparse_type(parse_fit_steps), metavar="N", help=FIT_STEPS_DOC)
    heading_check: bool = option(
        default=False,
        action="store_true",
        help="complete each box also turned by 180 degrees and keep the heading whose completion is clearly "
        "closer to the observed points (for detector boxes that may point backwards)",
    )
    heading_margin: float | None = option(
        default=None,
        type=float,
        metavar="M",
        help="the turned heading wins when its fidelity is below (1 - M) x the given one's (default 0.5: the "
        "default model turned 0-3.1%% of correct real boxes at 0.5, 5.5-15.6%% at 0.3; with --checkpoint paper "
        "0.3 turned none of the real cars; docs/real-data.md)",
    )
    margin: float | None = option(default=None, type=crop_metres, metavar="M", group=CROP_GROUP, help=CROP_MARGIN_HELP)
    ground_clearance: float = option(
        default=0.10, type=crop_metres, metavar="M", group=CROP_GROUP, help=CROP_GROUND_HELP
    )
    crop: float | None = option(
        default=None,
        type=crop_metres,
        metavar="MARGIN",
        group=CROP_GROUP,
        help="same as --margin (kept for older scripts)",
    )
    no_crop: bool = option(
        default=False,
        action="store_true",
        group=CROP_GROUP,
        help="single object: use every point of the scan (a scan that is already cropped to the object)",
    )
    min_points: int = option(
        default=10,
        type=positive_int,
        metavar="K",
        group=CROP_GROUP,
        help="boxes holding fewer than K points are not completed; a scan needs at least K points (default 10)",
    )
    resample: str = option(
        default="random",
        choices=("random", "fps"),
        group=MODEL_INPUT_GROUP,
        help="how an object's points are brought to the 256 the model takes: a random subset seeded with --seed "
        "(default, as in the training data) or farthest-point sampling from a seeded start; either way the "
        "points are first sorted, so the same points give the same input",
    )
    seed: int = option(
        default=0, type=seed_number, group=MODEL_INPUT_GROUP, help=f"seed of the resampling, {SEED_HELP} (default 0)"
    )
    clip: float | None = option(
        default=None,
        type=unit_interval,
        metavar="T",
        group=MODEL_INPUT_GROUP,
        mutex="clip",
        help="SA-Net: drop rays with depth < T (default: the checkpoint's: 0.2 for the paper SA-Net, none for the hit-aware default)",
    )
    no_clip: bool = option(
        default=False,
        action="store_true",
        group=MODEL_INPUT_GROUP,
        mutex="clip",
        help="SA-Net: keep every ray with depth > 0",
    )
    device: str | None = option(default=None, help=DEVICE_HELP)
    precision: str = option(
        default="auto",
        choices=("auto", "fp32", "bf16"),
        help="torch runtime: bf16 autocast or fp32; auto (default): bf16 where the CPU multiplies bfloat16 natively "
        "(avx512_bf16 or AMX flags), else fp32; onnxruntime runs fp32. bf16 took 2.0-2.6x less CPU per scan than fp32 "
        "(one thread, batch 1-32) on an AMD EPYC with avx512_bf16 and no AMX; depths move by up to 0.02 "
        "(docs/studies/speed.md)",
    )
    threads: int | None = option(
        default=None,
        type=thread_count,
        metavar="N",
        help="CPU threads of the model: torch's (default: one per core; with the track worker of --fuse, one less, "
        "leaving a core to it) or, run by onnxruntime, its intra-op threads; N is used as it is, up to 4 "
        "per CPU (at least 64)",
    )
    runtime: str = option(
        default="auto",
        choices=("auto", "torch", "onnx"),
        help="auto (default): onnxruntime on the CPU for the packaged default and class models (their ONNX exports "
        "ship with them; no torch start-up), torch for other checkpoints, on CUDA or with --precision bf16; torch; "
        "or onnx (a 'spotlights export' .onnx --checkpoint, or a packaged model's export; a .onnx checkpoint "
        "selects it; pip install 'spotlights[onnx]')",
    )


def add_completion_arguments(p, single: bool) -> None:
    """Add :class:`CompletionArguments` (``single``: with ``--crop`` and ``--no-crop``, a single object's)."""
    add_options(p, CompletionArguments, exclude=() if single else ("crop", "no_crop"))


@dataclass(kw_only=True)
class TrackArguments:
    """Options of multi-frame input shared by ``complete`` and ``real complete``: track fusion, box refinement,
    the longest gap in a track, the track worker process, the rerun recording."""

    fuse: WindowPolicy = option(
        default=parse_window("none"),
        type=argparse_type(parse_window),
        metavar="WINDOW",
        group=TRACKS_GROUP,
        help="which frames of a vehicle's track are fused into its input: " + WINDOW_HELP + "; default none. "
        "Also writes [SEQUENCE/]tracks/TRACK.ply (fused input and completion, box frame) and tracks.json",
    )
    refine_boxes: bool = option(
        default=False,
        action="store_true",
        group=TRACKS_GROUP,
        help="with --fuse: register each frame's points to the other frames of its window and correct its box "
        f"(x, y, yaw; at most {MAX_TRANSLATION_M:g} m and {math.degrees(MAX_YAW_RAD):g} degrees, else kept and "
        "flagged); the refined boxes are used and written to tracks.json",
    )
    track_shape: bool = option(
        default=False,
        action="store_true",
        group=TRACKS_GROUP,
        help="with --fuse all: one completion per track (its whole track fused, completed once) shown in every frame "
        "through that frame's box (refined with --refine-boxes); with --fuse past:K: a shape made again every K "
        "frames from the past K, never from later frames. A track whose boxes differ in size by more than "
        f"{100 * SIZE_TOLERANCE:g}%% a side is split (tracks.json: split_from); docs/fusion.md",
    )
    max_gap: float = option(
        default=argparse.SUPPRESS,  # not given: the settings' default, MAX_GAP_S (check_track_arguments)
        type=positive_float,
        metavar="S",
        group=TRACKS_GROUP,
        help=f"with --fuse: the longest time between two frames of one track, seconds (default {MAX_GAP_S:g})",
    )
    track_worker: bool = option(
        "--no-track-worker",
        default=True,
        action="store_false",
        group=TRACKS_GROUP,
        help="with --fuse: crop, refine and fuse the tracks in this process (default: in a second process a frame "
        "ahead of the completion, where two CPUs are usable; the same outputs; a worker silent for 120 s ends the "
        "run)",
    )
    rerun: str | None = option(
        default=None,
        metavar="FILE.rrd",
        group=TRACKS_GROUP,
        help="also log every frame (scan, given and used boxes, fused inputs, completions) on a time line into a "
        "rerun recording (needs the rerun extra; docs/viewer.md)",
    )


def add_track_arguments(p) -> None:
    """Add :class:`TrackArguments`, the options of a multi-frame input."""
    add_options(p, TrackArguments)


def check_track_arguments(args) -> None:
    """Refuse in one line, before any work, a track option given without ``--fuse`` (as ``--heading-margin``
    without ``--heading-check``): ``--max-gap``, which would be ignored. Not given, ``--max-gap`` is absent from
    ``args`` and the settings keep their default (:data:`~spotlights.data.tracks.MAX_GAP_S`)."""
    if hasattr(args, "max_gap") and not args.fuse.fuses:
        raise ParameterError("--max-gap goes with --fuse (the longest time between two fused frames of a track)")


BOXES_GROUP = "boxes (one of)"


@dataclass(kw_only=True)
class CompleteOptions:
    """The first options of ``spotlights complete``: the scan, the output and the boxes (then
    :class:`CompletionArguments`, :class:`CompleteSceneOptions`, ``--html``, :class:`TrackArguments`, ``-q``;
    all read as :class:`~spotlights.completion.scan.ScanSettings`)."""

    input: str = option(
        "input",
        metavar="SCAN",
        help="the scan: KITTI .bin (N x 4), nuScenes .pcd.bin (N x 5), AV2 .feather, .ply .pcd .npy .npz .xyz .txt, "
        ".las .laz (pip install 'spotlights[las]'); or a multi-frame generic scene: a folder of scans with NAME.json "
        "box files, or a sequence .json ('dataset sequences' writes DIR/seqNNNN/sequence.json; docs/real-data.md)",
    )
    out: str = option(
        "--out",
        "-o",
        metavar="OUT",
        help="the scene: .ply with x y z, 'source' (0 raw point, 1 partial input of an object, 2 completion) and "
        "'object' (box index, or integer track id; -1 outside every box); other suffixes (.pcd .npy .xyz .txt) "
        "hold the completion points only. A multi-frame scene: a folder, as 'real complete' writes it: "
        "[SEQUENCE/]FRAME.ply (these fields) and FRAME.json per frame, summary.json; with --fuse "
        "[SEQUENCE/]tracks/TRACK.ply and tracks.json",
    )
    boxes: str | None = option(
        default=None,
        metavar="BOXES",
        group=BOXES_GROUP,
        help='every box of the frame: a JSON list [{"center": [x,y,z], "size": [l,w,h], "yaw": rad (or "rotation": '
        '3x3 or quaternion w,x,y,z), "label": "car", "track_id": 7}, ...] or {"boxes": [...]}; or a KITTI '
        "label_2 .txt with --calib; at most 2000 boxes a frame",
    )
    calib: str | None = option(
        default=None, metavar="CALIB.txt", group=BOXES_GROUP, help="the KITTI calib file of a label_2 --boxes file"
    )
    box: str | None = option(
        default=None,
        metavar="BOX.json",
        group=BOXES_GROUP,
        help='one object\'s box: {"center": [x,y,z], "size": [l,w,h], "yaw": radians}',
    )
    center: list[float] | None = option(
        default=None,
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        group=BOXES_GROUP,
        help="one object's box centre (instead of --box)",
    )
    size: list[float] | None = option(
        default=None,
        type=float,
        nargs=3,
        metavar=("L", "W", "H"),
        group=BOXES_GROUP,
        help="its length, width, height (metres)",
    )
    yaw: float | None = option(
        default=None,
        type=float,
        metavar="RAD",
        group=BOXES_GROUP,
        help="its heading in radians about the up axis (default 0)",
    )


@dataclass(kw_only=True)
class CompleteSceneOptions:
    """The scan's sensor and axes, and what ``spotlights complete`` writes beside the scene."""

    sensor: list[float] | None = option(
        default=None,
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="the LiDAR's position in the scan's frame, metres (default: the scan's origin, as in a sensor-frame "
        "scan): the free space that the ray-local model and --snap's occlusion rule read; one scan only",
    )
    up: str = option(default="z", help="the scan's up axis (x, y, z, -x, ...); PCN-style scans are y (default z)")
    forward: str = option(default="x", help="the scan's forward axis (x, -y, ...): yaw 0 points along it (default x)")
    per_object: str | None = option(
        default=None, metavar="DIR", help="also write DIR/object_<id>.ply per completed object"
    )
    summary: str | None = option(
        default=None, metavar="JSON", help="also write a JSON summary (objects, warnings, timings)"
    )
    show: str | None = option(
        default=None,
        metavar="PNG",
        help="also draw the scene: a bird's-eye view with box outlines and ids and the objects' captions (a raster, "
        "a few hundredths of a second)",
    )
    closeups: bool = option(
        default=False,
        action="store_true",
        help="with --show: also a 3-D close-up of every object with a 1 m ruler (matplotlib; most of a second)",
    )


@dataclass(kw_only=True)
class CompleteQuietOption:
    """``-q/--quiet`` of ``spotlights complete`` (it has no progress bar, so no ``--no-progress`` alias)."""

    quiet: bool = option(
        "--quiet", "-q", default=False, action="store_true", help="print nothing but warnings and errors"
    )


def register(sub) -> None:
    p = add_command(
        sub,
        "complete",
        "complete the vehicles of a LiDAR scan given their 3-D boxes (a whole frame, or one object), or of every "
        "frame of a multi-frame generic scene (with --fuse: each vehicle's track fused); output in the scan's frame",
        "spotlights complete 002155.bin --boxes label_2/002155.txt --calib calib/002155.txt --out 002155.ply --show 002155.png\n"
        "  spotlights complete car.pcd --center 12.1 -3.4 0.9 --size 4.3 1.8 1.5 --yaw 0.52 --out car_completed.ply\n"
        "  spotlights complete seqs/seq0000/sequence.json --fuse past:5 --refine-boxes --out seq0000_completed",
        _complete,
    )
    add_options(p, CompleteOptions)
    add_completion_arguments(p, single=True)
    add_options(p, CompleteSceneOptions)
    add_html_argument(p)
    add_track_arguments(p)
    add_options(p, CompleteQuietOption)


def warn(line: str) -> None:
    """Print ``line`` as a warning on stderr."""
    print(f"spotlights: warning: {line}", file=sys.stderr)


def _complete(args) -> int:
    check_track_arguments(args)
    settings = settings_from_namespace(ScanSettings, args)
    settings.check_paths()  # a multi-frame scene too: --out is not its input folder
    complete_input(settings, say=print, warn=warn)
    return 0
