"""``spotlights real``: real LiDAR datasets -> partial observations, completed frames, consistency (paper Table 2)."""

from __future__ import annotations

import argparse
import json
import math

from ..data.real import open_reader
from ..data.real.base import CLASSES
from ..data.real.extract import ExtractConfig, extract, read_observations, write_observations
from ..data.real.frames import frame_rows
from ..data.tracks import MAX_GAP_S, MAX_TRANSLATION_M, MAX_YAW_RAD, TIME_UNIT_S, WINDOW_HELP, parse_window
from ..errors import InputFileError, ParameterError, SpotlightsError
from ..experiments.real_evaluation import (
    complete_all,
    evaluate_consistency,
    reference_shapes,
    report_markdown,
    write_report,
    write_report_json,
)
from ..experiments.scene import HEADING_MARGIN
from ..experiments.tracks import TrackPlan
from ..metrics.consistency import consecutive_pairs
from ..utils import check_writable, output_folder
from ..viz import html, render_frame
from ..viz.rerun_log import check_rerun_path, open_recording
from ..viz.scene import frame_objects, read_frame_scan
from ._util import (
    DEVICE_HELP,
    add_command,
    add_group,
    add_quiet,
    check_picture,
    check_suffix,
    non_negative_int,
    positive_int,
    unit_interval,
)
from .complete import add_completion_arguments, classes_arg, load_model, scene_config, warn
from .real_frames import complete_frames, file_stem
from .view import add_html_argument, write_page

FORMAT_CHOICES = ("kitti", "kitti360", "av2", "nuscenes", "generic")
SOURCE_HELP = (
    "kitti: a training/ folder (velodyne[_reduced]/, label_2/, calib/); kitti360: the KITTI-360 folder; "
    "av2: a log folder or a folder of logs; nuscenes: the folder with samples/ and the v1.0-* tables; "
    "generic: a scan file (see --boxes), a folder of scans with NAME.json box files, or a sequence .json. "
    "Several SOURCEs of one format are read one after another"
)


def _frames_range(text: str):
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
        raise argparse.ArgumentTypeError(f"expected START:STOP[:STEP] with integers, got {text!r}") from None
    return (start, stop, step)


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
    p.add_argument(
        "--margin",
        type=float,
        default=0.15,
        metavar="M",
        help="grow each box by M metres on the sides and top (default 0.15)",
    )
    p.add_argument(
        "--ground-clearance",
        type=float,
        default=0.10,
        metavar="M",
        help="drop points less than M metres above the box bottom: ground returns (default 0.10)",
    )
    p.add_argument(
        "--min-points", type=int, default=10, metavar="K", help="skip boxes with fewer than K points (default 10)"
    )
    p.add_argument(
        "--points", type=int, default=256, metavar="P", help="points per observation after resampling (default 256)"
    )
    p.add_argument("--seed", type=non_negative_int, default=0, help="resampling seed (default 0)")
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
    p.add_argument("--no-pictures", action="store_true", help="do not draw FRAME.png (faster)")
    p.add_argument(
        "--html",
        action="store_true",
        help="also write FRAME.html, an interactive 3-D page per frame (needs plotly); the pages share "
        "OUT/plotly.min.js, so copy the folder as a whole: it opens offline",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="skip the frames an earlier run with the same model and options finished (their FRAME.json exists)",
    )
    _track_arguments(p)
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
        help="one or more models: checkpoint files or short names ('default', 'paper'); default: the package's default model",
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
    p.add_argument("--batch-size", type=positive_int, default=64, help="completion batch size (default 64)")
    p.add_argument(
        "--clip",
        type=unit_interval,
        default=None,
        metavar="T",
        help="depth clip passed to the models (default: each model's own)",
    )
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
        help="model: a checkpoint file or a short name ('default', 'paper'); default: the package's default model",
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


def _window(text: str):
    try:
        return parse_window(text)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _track_arguments(p) -> None:
    g = p.add_argument_group("tracks (fuse each vehicle's frames in its box frame; docs/real-data.md)")
    g.add_argument(
        "--fuse",
        type=_window,
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
        "--max-gap",
        type=float,
        default=MAX_GAP_S,
        metavar="S",
        help=f"with --fuse: the longest time between two frames of one track, seconds (default {MAX_GAP_S:g})",
    )
    g.add_argument(
        "--rerun",
        default=None,
        metavar="FILE.rrd",
        help="also log every frame (scan, given and used boxes, fused inputs, completions) on a time line into a "
        "rerun recording (needs the rerun extra; docs/viewer.md)",
    )


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


def _frames_select(text: str):
    """--frames of 'real complete': a START:STOP[:STEP] range of positions, or comma-separated frame ids."""
    if ":" in text:
        return ("range", _frames_range(text))
    ids = [t.strip() for t in text.split(",") if t.strip()]
    if not ids:
        raise argparse.ArgumentTypeError(f"expected START:STOP[:STEP] or frame ids separated by commas, got {text!r}")
    return ("ids", ids)


def _open(args):
    """The reader of the shared dataset options (validated)."""
    options = {}
    if args.format == "kitti":
        options["velodyne"] = args.velodyne
    elif args.format in ("kitti360", "nuscenes"):
        options["sequences"] = args.sequence
        if (
            args.format == "kitti360"
            and getattr(args, "frames", None) is not None
            and not isinstance(args.frames[0], str)
        ):
            options["frames"] = args.frames
    elif args.format == "generic":
        options["boxes"] = args.boxes
    frames_k360 = getattr(args, "frames", None) is not None and not isinstance(args.frames[0], str)
    for name, val, fmts in (
        ("--velodyne", args.velodyne != "auto", ("kitti",)),
        ("--sequence", args.sequence, ("kitti360", "nuscenes")),
        ("--frames", frames_k360, ("kitti360",)),
        ("--boxes", args.boxes, ("generic",)),
    ):
        if val and args.format not in fmts:
            raise ParameterError(f"{name} applies to --format {' or '.join(fmts)} only")
    return open_reader(args.source, args.format, **options)


def _print_summary(obs) -> None:
    from collections import Counter

    classes = Counter(obs.cls)
    pairs = consecutive_pairs(obs.object_keys(), obs.timestamp)
    tracked = {obs.object_keys()[i] for p in pairs for i in p}
    print(
        f"{len(obs)} observations from {obs.meta['n_frames']} frames ({obs.meta['n_boxes']} boxes): "
        + (", ".join(f"{c} {n}" for c, n in sorted(classes.items())) or "none")
    )
    print(f"objects observed in two or more frames: {len(tracked)} ({len(pairs)} consecutive pairs)")
    sk = obs.meta["skipped"]
    print("skipped boxes: " + ", ".join(f"{k} {v}" for k, v in sk.items()))
    if obs.meta["skipped_labels"]:
        print("  excluded labels: " + ", ".join(f"{k} {v}" for k, v in obs.meta["skipped_labels"].items()))


def _extract(args) -> int:
    check_suffix(args.out, (".h5", ".hdf5"), "the observations file (HDF5)")
    check_writable(args.out)
    classes = tuple(c.strip() for c in args.classes.split(",") if c.strip())
    config = ExtractConfig(
        margin=args.margin,
        ground_clearance=args.ground_clearance,
        min_points=args.min_points,
        n_points=args.points,
        seed=args.seed,
        classes=classes,
    )
    reader = _open(args)
    obs = extract(reader, config, progress=not args.quiet)
    write_observations(args.out, obs)
    _print_summary(obs)
    print(f"wrote {args.out}")
    return 0


def _load_completers(paths, device):
    try:
        from ..learning.checkpoint import resolve_checkpoint
        from ..learning.inference import load_completer
    except ImportError as exc:
        raise SpotlightsError(f"model loading is not available ({exc}); install spotlights[learn]") from None
    for p in paths:
        resolve_checkpoint(p)  # every file or name checked before any model is loaded
    return [load_completer(p, device=device) for p in paths]


def _evaluate(args) -> int:
    from pathlib import Path

    if args.reference_split and not args.reference:
        raise ParameterError("--reference-split needs --reference DATASET.h5")

    if args.equal_points < 0:
        raise ParameterError(f"--equal-points must be >= 0, got {args.equal_points}")
    if not (args.equal_density >= 0 and args.equal_density < float("inf")):
        raise ParameterError(f"--equal-density must be a voxel size >= 0, got {args.equal_density}")

    margin = HEADING_MARGIN if args.heading_margin is None else args.heading_margin
    if not 0.0 <= margin < 1.0:
        raise ParameterError(f"--heading-margin must be in [0, 1), got {args.heading_margin}")
    checkpoints = args.checkpoint or ["default"]
    if args.names is not None and (len(args.names) != len(checkpoints) or len(set(args.names)) != len(args.names)):
        raise ParameterError(
            f"--names: give {len(checkpoints)} distinct names, one per checkpoint, got {len(args.names)}: "
            + " ".join(args.names)
        )
    prefix = args.out or str(Path(args.file).with_suffix("")) + "_consistency"
    check_writable(prefix + ".md")
    obs = read_observations(args.file)  # validate before loading models
    classes = classes_arg(args.classes)
    if classes:
        bad = [c for c in classes if c not in CLASSES]
        if bad:
            raise ParameterError(f"unknown class(es) {', '.join(bad)}; choose among {', '.join(CLASSES)}")
    refs, ref_info = (None, None)
    if args.reference:
        refs, ref_info = reference_shapes(args.reference, args.reference_split)
    completers = _load_completers(checkpoints, args.device)
    names = [c.model_name for c in completers]
    dup = {n for n in names if names.count(n) > 1}
    # two checkpoints of one model: tell them apart by file name, or by run folder for best.pt / last.pt
    tag = [Path(p).parent.name if Path(p).stem in ("best", "last") else Path(p).stem for p in checkpoints]
    names = args.names or [f"{n} ({t})" if n in dup else n for n, t in zip(names, tag)]

    js_path, partial = Path(prefix + ".json"), Path(prefix + ".partial.json")
    previous = []  # the finished table and an interrupted run's models, each with its own settings
    if args.resume:
        for f in (js_path, partial):
            if f.is_file():
                try:
                    earlier = json.loads(f.read_text(encoding="utf-8"))
                    if not isinstance(earlier["data"]["settings"], dict) or not isinstance(earlier["models"], list):
                        raise TypeError
                except (OSError, ValueError, KeyError, TypeError):
                    warn([f"{f}: not a report of 'real evaluate' with settings; not reused"])
                    continue
                previous.append(earlier)
    reused = []

    def save_partial(report_so_far: dict, was_reused: bool) -> None:
        if was_reused:
            reused.append(report_so_far["models"][-1]["name"])
            if not args.quiet:
                print(f"reusing {reused[-1]} (same checkpoint and settings) from {prefix}")
        report_so_far["data"]["file"] = str(args.file)
        write_report_json(report_so_far, partial)

    try:
        report = evaluate_consistency(
            obs,
            completers,
            names=names,
            checkpoints=checkpoints,
            batch_size=args.batch_size,
            progress=not args.quiet,
            clip=args.clip,
            references=refs,
            reference_info=ref_info,
            classes=classes,
            equal_points=args.equal_points or None,
            equal_density=args.equal_density or None,
            noise_floor=not args.no_noise_floor,
            heading_check=not args.no_heading_check,
            heading_margin=margin,
            previous=previous,
            on_model=save_partial,
        )
    except InputFileError as exc:
        if exc.path != "<observations>":
            raise
        raise InputFileError(args.file, exc.problem) from None  # name the file the user gave
    report["data"]["file"] = str(args.file)
    md, js = write_report(report, prefix)
    partial.unlink(missing_ok=True)
    if any(rep["models"] for rep in previous) and not reused:
        warn([f"--resume: no model of {prefix} was reused (other settings, names or checkpoint files)"])

    warn(
        [
            f"{m['name']}: {m['out_of_domain']['n_observations']} of {report['data']['n_observations_tracked']} observations "
            "are outside what the model learned (see the report)"
            for m in report["models"]
            if m.get("out_of_domain", {}).get("n_observations")
        ]
    )
    print(report_markdown(report).split("\n## ")[0].strip())
    print(f"wrote {md} and {js}")
    return 0


def _show(args) -> int:
    from pathlib import Path

    if args.max_objects < 1:
        raise ParameterError("--max-objects must be >= 1")

    check_picture(args.out)
    check_suffix(args.html, (".html", ".htm"), "the page (HTML)", "--html")
    obs = read_observations(args.file)
    rows = frame_rows(obs, args.sequence, args.frame)
    rows = sorted(rows, key=lambda i: -int(obs.n_points_raw[i]))[: args.max_objects]
    default_out = str(Path(args.file).with_suffix("")) + f"_{file_stem(obs.frame_id[rows[0]])}.png"
    check_writable(args.out or (None if args.html else default_out), args.html)
    completions, model = None, None
    if args.no_completion and args.checkpoint:
        raise ParameterError("--no-completion draws no model: it takes no --checkpoint")
    if not args.no_completion:
        completer = _load_completers([args.checkpoint or "default"], args.device)[0]

        completions = complete_all(
            completer, obs.partial[rows], progress=False, clip=args.clip, box_sizes=obs.box_size[rows]
        )
        model = completer.model_name
    i0 = rows[0]
    frame = obs.frame_id[i0]
    out = args.out or default_out
    title = f"{obs.meta.get('source_format')} {obs.sequence[i0] + '/' if obs.sequence[i0] else ''}{frame}" + (
        f" - {model}" if model else ""
    )
    objects = f"{len(rows)} object{'' if len(rows) == 1 else 's'} of frame {frame}"
    if args.html:
        scan = read_frame_scan(obs, i0)
        write_page(
            args.html, [("scene", html.scene_traces(scan, frame_objects(obs, rows, completions)))], title, quiet=True
        )
        print(f"wrote {args.html} ({objects}, interactive)")
        if not args.out:
            return 0
    render_frame(out, obs, rows, completions, title=title)
    print(f"wrote {out} ({objects})")
    return 0


def _select_frames(keys, spec):
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


def _complete(args) -> int:
    reader = _open(args)
    keys = _select_frames(reader.frame_keys(), args.frames)
    if not keys:
        raise ParameterError("--frames selects no frame")
    config = scene_config(args, single=False)
    if args.rerun is not None:
        check_rerun_path(args.rerun)
    tracks = None
    if args.fuse.fuses:
        if args.resume:
            raise ParameterError("--resume does not apply with --fuse (a frame's input depends on its track)")
        tracks = TrackPlan(args.fuse, config, args.refine_boxes, args.max_gap).build(reader, keys)
    elif args.refine_boxes:
        raise ParameterError("--refine-boxes needs --fuse all, past:K or centered:K (the frames to register to)")
    completer = load_model(args.checkpoint, args.device, args.runtime, args.precision)
    with output_folder(args.out) as out, open_recording(args.rerun, TIME_UNIT_S.get(reader.format)) as rec:
        return complete_frames(args, reader, keys, config, completer, out, tracks=tracks, recorder=rec)
