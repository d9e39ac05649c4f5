"""``spotlights complete``: complete the vehicles of a LiDAR scan (a whole frame with its boxes, or one object)."""

from __future__ import annotations

import argparse
import sys

from ..data.real.boxfiles import read_box_file, with_class
from ..data.real.scans import read_scan
from ..errors import ParameterError
from ..experiments.scene import (
    SceneConfig,
    check_completed,
    complete_scene,
    describe,
    render_result,
    render_result_html,
    require_points,
    write_scene,
)
from ..geometry.boxes import box_from_dict
from ..geometry.io import axes_rotation
from ..inputs import read_json
from ..learning.runtime import load_completer
from ..utils import atomic_output, check_writable
from ._util import DEVICE_HELP, add_command, check_picture, check_suffix, non_negative_int, positive_int, unit_interval
from .view import add_html_argument

CROP_DOC = (
    "each box's points: the box grown by --margin on its sides and top, its bottom raised by --ground-clearance "
    "(ground returns)"
)


def add_completion_arguments(p, single: bool) -> None:
    """Options shared by ``complete`` and ``real complete``: model, selection, crop, input, heading check."""
    p.add_argument(
        "--checkpoint",
        "-c",
        default=None,
        metavar="CKPT",
        help="model: a checkpoint file or a short name, 'default' (the package's default model, used when "
        "this is not given) or 'paper' (the paper-faithful SA-Net)",
    )
    p.add_argument(
        "--classes",
        default=None,
        metavar="LIST",
        help="comma-separated classes to complete (default: every vehicle class: car, truck, caravan, trailer, "
        "bus, construction, emergency; the model learned cars, others get a warning)",
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
    g.add_argument(
        "--margin",
        type=float,
        default=None,
        metavar="M",
        help="grow each box by M metres on its sides and top (default 0.15)",
    )
    if single:
        g.add_argument(
            "--crop", type=float, default=None, metavar="MARGIN", help="same as --margin (kept for older scripts)"
        )
        g.add_argument(
            "--no-crop",
            action="store_true",
            help="single object: use every point of the scan (a scan that is already cropped to the object)",
        )
    g.add_argument(
        "--ground-clearance",
        type=float,
        default=0.10,
        metavar="M",
        help="drop points less than M metres above the box bottom: ground returns (default 0.10)",
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
    g.add_argument("--seed", type=non_negative_int, default=0, help="seed of the resampling (default 0)")
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
        choices=("fp32", "bf16", "auto"),
        default="fp32",
        help="torch runtime: fp32 (default) or bf16 autocast (4x faster per scan measured on a 2-core CPU with "
        "AMX-BF16, docs/benchmarks.md; depths move by up to ~0.01); auto = bf16 where supported",
    )
    p.add_argument(
        "--runtime",
        choices=("torch", "onnx"),
        default=None,
        help="run the model with torch (default) or onnxruntime (--checkpoint is then a 'spotlights export' "
        ".onnx file; a .onnx checkpoint selects it; pip install 'spotlights[onnx]')",
    )


def register(sub) -> None:
    p = add_command(
        sub,
        "complete",
        "complete the vehicles of a LiDAR scan given their 3-D boxes (a whole frame, or one object); "
        "output in the scan's frame",
        "spotlights complete 002155.bin --boxes label_2/002155.txt --calib calib/002155.txt --out 002155.ply --show 002155.png\n"
        "  spotlights complete car.pcd --center 12.1 -3.4 0.9 --size 4.3 1.8 1.5 --yaw 0.52 --out car_completed.ply",
        _complete,
    )
    p.add_argument(
        "input",
        metavar="SCAN",
        help="the scan: KITTI .bin (N x 4), nuScenes .pcd.bin (N x 5), AV2 .feather, .ply .pcd .npy .npz .xyz .txt, "
        ".las .laz (pip install 'spotlights[las]')",
    )
    p.add_argument(
        "--out",
        "-o",
        required=True,
        metavar="OUT.ply",
        help="the scene: .ply with x y z, 'source' (0 raw point, 1 partial input of an object, 2 completion) and "
        "'object' (box index, or integer track id; -1 outside every box); other suffixes (.pcd .npy .xyz .txt) "
        "hold the completion points only",
    )
    g = p.add_argument_group("boxes (one of)")
    g.add_argument(
        "--boxes",
        default=None,
        metavar="BOXES",
        help='every box of the frame: a JSON list [{"center": [x,y,z], "size": [l,w,h], "yaw": rad (or "rotation": '
        '3x3 or quaternion w,x,y,z), "label": "car", "track_id": 7}, ...] or {"boxes": [...]}; or a KITTI '
        "label_2 .txt with --calib",
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
        "--yaw", type=float, default=0.0, metavar="RAD", help="its heading in radians about the up axis (default 0)"
    )
    add_completion_arguments(p, single=True)
    p.add_argument("--up", default="z", help="the scan's up axis (x, y, z, -x, ...); PCN-style scans are y (default z)")
    p.add_argument("--forward", default="x", help="the scan's forward axis: a box's yaw 0 points along it (default x)")
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
        help="also draw the scene: bird's-eye view with box outlines and ids, close-ups with a 1 m ruler",
    )
    add_html_argument(p)
    p.add_argument("--quiet", "-q", action="store_true", help="print nothing but warnings and errors")


def classes_arg(text):
    """``--classes`` text -> tuple of class names, or None."""
    if text is None:
        return None
    return tuple(c.strip().lower() for c in text.split(",") if c.strip())


def scene_config(args, single: bool):
    """The :class:`~spotlights.experiments.scene.SceneConfig` of the shared options."""
    margin = args.margin
    if single and args.crop is not None:
        if margin is not None and margin != args.crop:
            raise ParameterError("give the crop margin once: --margin or --crop")
        margin = args.crop
    clip = None if args.no_clip else ("default" if args.clip is None else float(args.clip))
    no_crop = bool(single and args.no_crop)
    if args.heading_margin is not None and not args.heading_check:
        raise ParameterError("--heading-margin goes with --heading-check")
    if no_crop and margin is not None:
        raise ParameterError("--no-crop uses every point: it takes no --margin/--crop")
    return SceneConfig(
        margin=0.15 if margin is None else float(margin),
        ground_clearance=float(args.ground_clearance),
        min_points=int(args.min_points),
        classes=classes_arg(args.classes),
        crop=not no_crop,
        resample=args.resample,
        seed=int(args.seed),
        heading_check=bool(args.heading_check),
        clip=clip,
        keep_observed=bool(args.keep_observed),
        complete_unknown=bool(args.complete_unknown),
        **({} if args.heading_margin is None else {"heading_margin": float(args.heading_margin)}),
    )


def load_model(checkpoint, device, runtime=None, precision="fp32"):
    """The completer of a --checkpoint value (None = the default model) and --runtime: see
    :func:`spotlights.learning.runtime.load_completer`."""
    return load_completer(checkpoint, runtime=runtime, device=device, precision=precision)


def warn(lines) -> None:
    for w in lines:
        print(f"spotlights: warning: {w}", file=sys.stderr)


def _complete(args) -> int:
    import dataclasses
    from pathlib import Path

    import numpy as np

    single_given = [
        n for n, v in (("--box", args.box), ("--center/--size", args.center is not None or args.size is not None)) if v
    ]
    if args.boxes is not None and single_given:
        raise ParameterError(f"give the boxes either as --boxes or as {single_given[0]} (one object), not both")
    if len(single_given) > 1:
        raise ParameterError("give the box either as --box BOX.json or as --center/--size/--yaw, not both")
    if args.calib is not None and args.boxes is None:
        raise ParameterError("--calib goes with a KITTI label_2 file in --boxes")
    single = args.boxes is None
    if single and (args.center is None) != (args.size is None) and args.box is None:
        raise ParameterError("one object's box needs both --center X Y Z and --size L W H")
    if single and args.box is None and args.center is None:
        raise ParameterError(
            "the boxes are missing: pass --boxes BOXES (a frame), or one object's --box BOX.json or "
            "--center X Y Z --size L W H [--yaw RAD]"
        )
    if not single and args.no_crop:
        raise ParameterError("--no-crop is for one object already cropped; the boxes of a frame are always cropped")
    config = scene_config(args, single)
    if single:
        if args.classes is not None:
            raise ParameterError("--classes chooses among the boxes of --boxes; one object's box is always completed")
        config = dataclasses.replace(config, any_label=True)

    check_picture(args.show, "--show")
    check_suffix(args.html, (".html", ".htm"), "the page (HTML)", "--html")
    check_suffix(args.summary, (".json",), "the summary (JSON)", "--summary")
    check_writable(args.out, args.show, args.html, args.summary)
    if args.per_object is not None:  # every destination before anything is written
        check_writable(Path(args.per_object) / "object_0.ply")
    axes = axes_rotation(args.up, args.forward)
    points = read_scan(args.input)
    require_points(points, config.min_points, args.input)
    if args.boxes is not None:
        boxes = read_box_file(args.boxes, calib=args.calib, axes=axes).boxes
        box_src = args.boxes
    else:
        if args.box is not None:
            box = box_from_dict(read_json(args.box), args.box, axes=axes)  # yaw: about the scan's up axis
            box_src = args.box
        else:
            box = box_from_dict(
                {"center": args.center, "size": args.size, "yaw": args.yaw}, "--center/--size", axes=axes
            )
            box_src = "--center/--size"
        if not box.is_valid():
            raise ParameterError(f"{box_src}: box size must be positive, got {box.size.tolist()}")
        boxes = [with_class(box)]
    completer = load_model(args.checkpoint, args.device, args.runtime, args.precision)
    result = complete_scene(
        points, boxes, completer, config, axes=axes, checkpoint=str(args.checkpoint) if args.checkpoint else "default"
    )
    if single:
        o = result.objects[0]
        if o.status == "too_few_points":
            raise ParameterError(
                f"{box_src}: {len(o.input_indices)} scan point(s) lie in the box (grown by {config.margin} m, "
                f"bottom raised {config.ground_clearance} m); at least {config.min_points} are needed - check "
                "the box and the scan's frame (--no-crop for an already cropped scan)"
            )
        if o.status == "empty_completion":
            raise ParameterError(
                f"{args.input}: the completion is empty (every ray was clipped); try --no-clip or a lower --clip"
            )
        if not config.crop:
            unit = o.used_box.normalization().to_unit(np.asarray(points, dtype=np.float64) @ axes.T)
            outside = float(np.mean(np.linalg.norm(unit, axis=1) > 1.2))
            if outside > 0.5:
                warn([f"{outside:.0%} of the scan lies outside the box's sphere; is the box in the scan's frame?"])
    else:
        check_completed(result, box_src)
    written = write_scene(result, args.out, per_object=args.per_object, scan_name=Path(args.input).name)
    warn(result.warnings())
    if args.summary:
        _write_json(
            args.summary, {"scan": str(args.input), "boxes": str(box_src), "out": str(args.out), **result.summary()}
        )
    if not args.quiet:
        print(
            f"{args.input}: {len(points)} points, {describe(result)} ({result.model}) -> {args.out}"
            + (f" (+{len(written) - 1} per-object files in {args.per_object})" if args.per_object else "")
        )
    title = f"{Path(args.input).name}: {result.model} completion of {len(result.completed)} object(s), scan frame"
    if args.show:
        render_result(result, args.show, title)
        if not args.quiet:
            print(f"picture -> {args.show}")
    if args.html:
        render_result_html(result, args.html, title)
        if not args.quiet:
            print(f"page -> {args.html}")
    return 0


def _write_json(path, data) -> None:
    import json

    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=float) + "\n", encoding="utf-8")
