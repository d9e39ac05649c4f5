"""``spotlights complete``: complete the vehicles of a LiDAR scan (a whole frame with its boxes, or one object)."""

from __future__ import annotations

import argparse
import math
import sys

from ..completion.frames import complete_input
from ..completion.scan import ScanSettings
from ..completion.shapes import SIZE_TOLERANCE
from ..data.tracks import MAX_GAP_S, MAX_TRANSLATION_M, MAX_YAW_RAD, WINDOW_HELP, parse_window
from ..errors import ParameterError
from ..learning.fit import FIT_DOC, FIT_STEPS_DOC, parse_fit_steps
from ..options import settings_from_namespace
from ._util import (
    DEVICE_HELP,
    SEED_HELP,
    add_command,
    add_crop_arguments,
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


def add_completion_arguments(p, single: bool) -> None:
    """Options shared by ``complete`` and ``real complete``: model, selection, crop, input, heading check."""
    p.add_argument(
        "--checkpoint",
        "-c",
        default=None,
        metavar="CKPT",
        help="model: a checkpoint file or a short name, 'default' (the package's default model, cars, used when "
        "this is not given), 'paper' (the paper-faithful SA-Net) or 'classes' (cars, vans, trucks, buses, "
        "trailers; the default model's --fallback)",
    )
    p.add_argument(
        "--classes",
        default=None,
        metavar="LIST",
        help="comma-separated classes to complete (default: every vehicle class: car, truck, caravan, trailer, "
        "bus, construction, emergency; the default model learned cars, its --fallback the others but construction "
        "and emergency vehicles, which are left as observed points)",
    )
    p.add_argument(
        "--fallback",
        default="auto",
        metavar="CKPT",
        help="a second model for the boxes --checkpoint's model did not learn but it did (a checkpoint file or short "
        "name); 'auto' (default): 'classes', the packaged class model (vans, trucks, buses, trailers), beside the "
        "car-only default model, none beside a model you chose; 'none': such boxes are left as observed points",
    )
    p.add_argument(
        "--complete-unknown",
        action="store_true",
        help="also complete boxes whose class (or size, far outside its class's range) the model did not learn "
        "(default: left as their observed points and counted as not_learned)",
    )
    p.add_argument(
        "--keep-observed",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="return each object's observed points (the model's input) beside its predicted ones (default on; "
        "fidelity and the heading check score the predicted points alone)",
    )
    p.add_argument(
        "--snap",
        type=non_negative_float,
        default=0.0,
        metavar="R",
        help=SNAP_HELP + "; not with --heading-check",
    )
    p.add_argument("--snap-mirror", action="store_true", help=SNAP_MIRROR_HELP)
    p.add_argument("--fit", action="store_true", help=FIT_DOC)
    p.add_argument("--fit-steps", type=argparse_type(parse_fit_steps), default=None, metavar="N", help=FIT_STEPS_DOC)
    p.add_argument(
        "--heading-check",
        action="store_true",
        help="complete each box also turned by 180 degrees and keep the heading whose completion is clearly "
        "closer to the observed points (for detector boxes that may point backwards)",
    )
    p.add_argument(
        "--heading-margin",
        type=float,
        default=None,
        metavar="M",
        help="the turned heading wins when its fidelity is below (1 - M) x the given one's (default 0.5: the "
        "default model turned 0-3.1%% of correct real boxes at 0.5, 5.5-15.6%% at 0.3; with --checkpoint paper "
        "0.3 turned none of the real cars; docs/real-data.md)",
    )
    g = p.add_argument_group("crop (" + CROP_DOC + ")")
    add_crop_arguments(g, margin_default=None)
    if single:
        g.add_argument(
            "--crop", type=crop_metres, default=None, metavar="MARGIN", help="same as --margin (kept for older scripts)"
        )
        g.add_argument(
            "--no-crop",
            action="store_true",
            help="single object: use every point of the scan (a scan that is already cropped to the object)",
        )
    g.add_argument(
        "--min-points",
        type=positive_int,
        default=10,
        metavar="K",
        help="boxes holding fewer than K points are not completed; a scan needs at least K points (default 10)",
    )
    g = p.add_argument_group("model input (the same observation always gives the same completion)")
    g.add_argument(
        "--resample",
        default="random",
        choices=("random", "fps"),
        help="how an object's points are brought to the 256 the model takes: a random subset seeded with --seed "
        "(default, as in the training data) or farthest-point sampling from a seeded start; either way the "
        "points are first sorted, so the same points give the same input",
    )
    g.add_argument("--seed", type=seed_number, default=0, help=f"seed of the resampling, {SEED_HELP} (default 0)")
    m = g.add_mutually_exclusive_group()
    m.add_argument(
        "--clip",
        type=unit_interval,
        default=None,
        metavar="T",
        help="SA-Net: drop rays with depth < T (default: the checkpoint's: 0.2 for the paper SA-Net, none for the hit-aware default)",
    )
    m.add_argument("--no-clip", action="store_true", help="SA-Net: keep every ray with depth > 0")
    p.add_argument("--device", default=None, help=DEVICE_HELP)
    p.add_argument(
        "--precision",
        choices=("auto", "fp32", "bf16"),
        default="auto",
        help="torch runtime: bf16 autocast or fp32; auto (default): bf16 where the CPU multiplies bfloat16 natively "
        "(avx512_bf16 or AMX flags), else fp32; onnxruntime runs fp32. bf16 took 2.0-2.6x less CPU per scan than fp32 "
        "(one thread, batch 1-32) on an AMD EPYC with avx512_bf16 and no AMX; depths move by up to 0.02 "
        "(docs/studies/speed.md)",
    )
    p.add_argument(
        "--threads",
        type=thread_count,
        default=None,
        metavar="N",
        help="CPU threads of the model: torch's (default: one per core; with the track worker of --fuse, one less, "
        "leaving a core to it) or, run by onnxruntime, its intra-op threads; N is used as it is, up to 4 "
        "per CPU (at least 64)",
    )
    p.add_argument(
        "--runtime",
        choices=("auto", "torch", "onnx"),
        default="auto",
        help="auto (default): onnxruntime on the CPU for the packaged default and class models (their ONNX exports "
        "ship with them; no torch start-up), torch for other checkpoints, on CUDA or with --precision bf16; torch; "
        "or onnx (a 'spotlights export' .onnx --checkpoint, or a packaged model's export; a .onnx checkpoint "
        "selects it; pip install 'spotlights[onnx]')",
    )


def add_track_arguments(p) -> None:
    """Options of multi-frame input shared by ``complete`` and ``real complete``: track fusion, box refinement,
    the longest gap in a track, the track worker process, the rerun recording."""
    g = p.add_argument_group(
        "tracks of a multi-frame input (fuse each vehicle's frames in its box frame; docs/real-data.md)"
    )
    g.add_argument(
        "--fuse",
        type=argparse_type(parse_window),
        default=parse_window("none"),
        metavar="WINDOW",
        help="which frames of a vehicle's track are fused into its input: " + WINDOW_HELP + "; default none. "
        "Also writes [SEQUENCE/]tracks/TRACK.ply (fused input and completion, box frame) and tracks.json",
    )
    g.add_argument(
        "--refine-boxes",
        action="store_true",
        help="with --fuse: register each frame's points to the other frames of its window and correct its box "
        f"(x, y, yaw; at most {MAX_TRANSLATION_M:g} m and {math.degrees(MAX_YAW_RAD):g} degrees, else kept and "
        "flagged); the refined boxes are used and written to tracks.json",
    )
    g.add_argument(
        "--track-shape",
        action="store_true",
        help="with --fuse all: one completion per track (its whole track fused, completed once) shown in every frame "
        "through that frame's box (refined with --refine-boxes); with --fuse past:K: a shape made again every K "
        "frames from the past K, never from later frames. A track whose boxes differ in size by more than "
        f"{100 * SIZE_TOLERANCE:g}%% a side is split (tracks.json: split_from); docs/fusion.md",
    )
    g.add_argument(
        "--max-gap",
        type=positive_float,
        default=argparse.SUPPRESS,  # not given: the settings' default, MAX_GAP_S (check_track_arguments)
        metavar="S",
        help=f"with --fuse: the longest time between two frames of one track, seconds (default {MAX_GAP_S:g})",
    )
    g.add_argument(
        "--no-track-worker",
        dest="track_worker",
        action="store_false",
        help="with --fuse: crop, refine and fuse the tracks in this process (default: in a second process a frame "
        "ahead of the completion, where two CPUs are usable; the same outputs; a worker silent for 120 s ends the "
        "run)",
    )
    g.add_argument(
        "--rerun",
        default=None,
        metavar="FILE.rrd",
        help="also log every frame (scan, given and used boxes, fused inputs, completions) on a time line into a "
        "rerun recording (needs the rerun extra; docs/viewer.md)",
    )


def check_track_arguments(args) -> None:
    """Refuse in one line, before any work, a track option given without ``--fuse`` (as ``--heading-margin``
    without ``--heading-check``): ``--max-gap``, which would be ignored. Not given, ``--max-gap`` is absent from
    ``args`` and the settings keep their default (:data:`~spotlights.data.tracks.MAX_GAP_S`)."""
    if hasattr(args, "max_gap") and not args.fuse.fuses:
        raise ParameterError("--max-gap goes with --fuse (the longest time between two fused frames of a track)")


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
    p.add_argument(
        "input",
        metavar="SCAN",
        help="the scan: KITTI .bin (N x 4), nuScenes .pcd.bin (N x 5), AV2 .feather, .ply .pcd .npy .npz .xyz .txt, "
        ".las .laz (pip install 'spotlights[las]'); or a multi-frame generic scene: a folder of scans with NAME.json "
        "box files, or a sequence .json ('dataset sequences' writes DIR/seqNNNN/sequence.json; docs/real-data.md)",
    )
    p.add_argument(
        "--out",
        "-o",
        required=True,
        metavar="OUT",
        help="the scene: .ply with x y z, 'source' (0 raw point, 1 partial input of an object, 2 completion) and "
        "'object' (box index, or integer track id; -1 outside every box); other suffixes (.pcd .npy .xyz .txt) "
        "hold the completion points only. A multi-frame scene: a folder, as 'real complete' writes it: "
        "[SEQUENCE/]FRAME.ply (these fields) and FRAME.json per frame, summary.json; with --fuse "
        "[SEQUENCE/]tracks/TRACK.ply and tracks.json",
    )
    g = p.add_argument_group("boxes (one of)")
    g.add_argument(
        "--boxes",
        default=None,
        metavar="BOXES",
        help='every box of the frame: a JSON list [{"center": [x,y,z], "size": [l,w,h], "yaw": rad (or "rotation": '
        '3x3 or quaternion w,x,y,z), "label": "car", "track_id": 7}, ...] or {"boxes": [...]}; or a KITTI '
        "label_2 .txt with --calib; at most 2000 boxes a frame",
    )
    g.add_argument("--calib", default=None, metavar="CALIB.txt", help="the KITTI calib file of a label_2 --boxes file")
    g.add_argument(
        "--box",
        default=None,
        metavar="BOX.json",
        help='one object\'s box: {"center": [x,y,z], "size": [l,w,h], "yaw": radians}',
    )
    g.add_argument(
        "--center",
        type=float,
        nargs=3,
        default=None,
        metavar=("X", "Y", "Z"),
        help="one object's box centre (instead of --box)",
    )
    g.add_argument(
        "--size", type=float, nargs=3, default=None, metavar=("L", "W", "H"), help="its length, width, height (metres)"
    )
    g.add_argument(
        "--yaw", type=float, default=None, metavar="RAD", help="its heading in radians about the up axis (default 0)"
    )
    add_completion_arguments(p, single=True)
    p.add_argument(
        "--sensor",
        type=float,
        nargs=3,
        default=None,
        metavar=("X", "Y", "Z"),
        help="the LiDAR's position in the scan's frame, metres (default: the scan's origin, as in a sensor-frame "
        "scan): the free space that the ray-local model and --snap's occlusion rule read; one scan only",
    )
    p.add_argument("--up", default="z", help="the scan's up axis (x, y, z, -x, ...); PCN-style scans are y (default z)")
    p.add_argument(
        "--forward", default="x", help="the scan's forward axis (x, -y, ...): yaw 0 points along it (default x)"
    )
    p.add_argument(
        "--per-object", default=None, metavar="DIR", help="also write DIR/object_<id>.ply per completed object"
    )
    p.add_argument(
        "--summary", default=None, metavar="JSON", help="also write a JSON summary (objects, warnings, timings)"
    )
    p.add_argument(
        "--show",
        default=None,
        metavar="PNG",
        help="also draw the scene: a bird's-eye view with box outlines and ids and the objects' captions (a raster, "
        "a few hundredths of a second)",
    )
    p.add_argument(
        "--closeups",
        action="store_true",
        help="with --show: also a 3-D close-up of every object with a 1 m ruler (matplotlib; most of a second)",
    )
    add_html_argument(p)
    add_track_arguments(p)
    p.add_argument("--quiet", "-q", action="store_true", help="print nothing but warnings and errors")


def warn(line: str) -> None:
    """Print ``line`` as a warning on stderr."""
    print(f"spotlights: warning: {line}", file=sys.stderr)


def _complete(args) -> int:
    check_track_arguments(args)
    settings = settings_from_namespace(ScanSettings, args)
    settings.check_paths()  # a multi-frame scene too: --out is not its input folder
    complete_input(settings, say=print, warn=warn)
    return 0
