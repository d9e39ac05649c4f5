"""``spotlights real``: real LiDAR scans -> partial observations -> completions and consistency (paper Table 2)."""

from __future__ import annotations

import argparse

from ._util import add_command, add_group, positive_int, unit_interval
from .view import add_html_argument


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
    rs = add_group(sub, "real", "real LiDAR data: extract vehicles, complete them, score consistency, draw them",
                   "spotlights real extract ../shared/data/lidar/argoverse2 --format av2 --out av2.h5")

    p = add_command(rs, "extract", "cut the points of every vehicle box out of real scans into unit-frame partial observations (HDF5)",
                    "spotlights real extract ../shared/data/lidar/kitti-object/training --format kitti --out kitti.h5", _extract)
    p.add_argument("source", metavar="SOURCE",
                   help="kitti: a training/ folder (velodyne[_reduced]/, label_2/, calib/); kitti360: the KITTI-360 folder; "
                        "av2: a log folder or a folder of logs; generic: a scene .json or a point-cloud file (see --boxes)")
    p.add_argument("--format", "-f", required=True, choices=("kitti", "kitti360", "av2", "generic"), help="dataset format")
    p.add_argument("--out", "-o", required=True, metavar="FILE.h5", help="output HDF5 of observations")
    p.add_argument("--margin", type=float, default=0.15, metavar="M", help="grow each box by M metres on the sides and top (default 0.15)")
    p.add_argument("--ground-clearance", type=float, default=0.10, metavar="M",
                   help="drop points less than M metres above the box bottom: ground returns (default 0.10)")
    p.add_argument("--min-points", type=int, default=10, metavar="K", help="skip boxes with fewer than K points (default 10)")
    p.add_argument("--points", type=int, default=256, metavar="P", help="points per observation after resampling (default 256)")
    p.add_argument("--seed", type=int, default=0, help="resampling seed (default 0)")
    p.add_argument("--classes", default="car,truck,caravan,trailer", help="comma-separated classes to keep (default all four)")
    p.add_argument("--velodyne", default="auto", choices=("auto", "velodyne", "velodyne_reduced"),
                   help="kitti: which scan folder (default: velodyne/ if present, else velodyne_reduced/)")
    p.add_argument("--sequence", action="append", default=None, metavar="SEQ",
                   help="kitti360: a sequence to read, e.g. 2013_05_28_drive_0000_sync (repeatable; default all)")
    p.add_argument("--frames", type=_frames_range, default=None, metavar="START:STOP[:STEP]", help="kitti360: frame range")
    p.add_argument("--boxes", default=None, metavar="JSON", help="generic: the box list of a single point-cloud SOURCE (default SOURCE with .json)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")

    p = add_command(rs, "evaluate", "complete the tracked observations with each model and write the consistency table (Markdown + JSON)",
                    "spotlights real evaluate av2.h5 --checkpoint runs/sanet.pt runs/pcn.pt --out results/av2_consistency", _evaluate)
    p.add_argument("file", metavar="FILE.h5", help="observations from 'spotlights real extract'")
    p.add_argument("--checkpoint", "-c", nargs="+", required=True, metavar="CKPT", help="one or more model checkpoints")
    p.add_argument("--out", "-o", default=None, metavar="PREFIX",
                   help="writes PREFIX.md and PREFIX.json (default: FILE without .h5 + '_consistency')")
    p.add_argument("--batch-size", type=positive_int, default=64, help="completion batch size (default 64)")
    p.add_argument("--clip", type=unit_interval, default=None, metavar="T", help="depth clip passed to the models (default: each model's own)")
    p.add_argument("--device", default=None, help="torch device for the models (default: the loader's choice)")
    p.add_argument("--reference", default=None, metavar="DATASET.h5",
                   help="completion dataset whose ground-truth cars are the reference set of the minimal matching "
                        "distance (MMD) reported beside consistency and fidelity (default: no MMD)")
    p.add_argument("--reference-split", default=None, choices=["train", "val", "test"],
                   help="use only this split of --reference (default: every model)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")

    p = add_command(rs, "show", "draw one scan: raw points (grey), partial inputs (purple), completions (green), in the sensor frame",
                    "spotlights real show kitti.h5 --checkpoint runs/sanet.pt --frame 002155 --out kitti_002155.png", _show)
    p.add_argument("file", metavar="FILE.h5", help="observations from 'spotlights real extract'")
    p.add_argument("--checkpoint", "-c", default=None, metavar="CKPT", help="model checkpoint (without it: no completion drawn)")
    p.add_argument("--frame", default=None, metavar="ID", help="frame id (default: the frame with the most observations)")
    p.add_argument("--sequence", default=None, metavar="SEQ", help="sequence / log of the frame, when frame ids repeat")
    p.add_argument("--max-objects", type=int, default=6, metavar="K", help="close-ups of the K objects with most points (default 6)")
    p.add_argument("--out", "-o", default=None, metavar="PNG",
                   help="output picture (default: FILE_FRAME.png beside FILE; with --html alone, no picture)")
    p.add_argument("--clip", type=unit_interval, default=None, metavar="T", help="depth clip passed to the model (default: its own)")
    p.add_argument("--device", default=None, help="torch device for the model")
    add_html_argument(p)


def _print_summary(obs) -> None:
    from collections import Counter

    from ..data.consistency import consecutive_pairs

    classes = Counter(obs.cls)
    pairs = consecutive_pairs(obs.object_keys(), obs.timestamp)
    tracked = {obs.object_keys()[i] for p in pairs for i in p}
    print(f"{len(obs)} observations from {obs.meta['n_frames']} frames ({obs.meta['n_boxes']} boxes): "
          + (", ".join(f"{c} {n}" for c, n in sorted(classes.items())) or "none"))
    print(f"objects observed in two or more frames: {len(tracked)} ({len(pairs)} consecutive pairs)")
    sk = obs.meta["skipped"]
    print("skipped boxes: " + ", ".join(f"{k} {v}" for k, v in sk.items()))
    if obs.meta["skipped_labels"]:
        print("  excluded labels: " + ", ".join(f"{k} {v}" for k, v in obs.meta["skipped_labels"].items()))


def _extract(args) -> int:
    from ..data.real import open_reader
    from ..data.real.extract import ExtractConfig, extract, write_observations
    from ..errors import ParameterError

    options = {}
    if args.format == "kitti":
        options["velodyne"] = args.velodyne
    elif args.format == "kitti360":
        options["sequences"] = args.sequence
        options["frames"] = args.frames
    elif args.format == "generic":
        options["boxes"] = args.boxes
    for name, val, fmt in (("--velodyne", args.velodyne != "auto", "kitti"), ("--sequence", args.sequence, "kitti360"),
                           ("--frames", args.frames, "kitti360"), ("--boxes", args.boxes, "generic")):
        if val and args.format != fmt:
            raise ParameterError(f"{name} applies to --format {fmt} only")
    classes = tuple(c.strip() for c in args.classes.split(",") if c.strip())
    config = ExtractConfig(margin=args.margin, ground_clearance=args.ground_clearance, min_points=args.min_points,
                           n_points=args.points, seed=args.seed, classes=classes)
    reader = open_reader(args.source, args.format, **options)
    obs = extract(reader, config, progress=not args.quiet)
    write_observations(args.out, obs)
    _print_summary(obs)
    print(f"wrote {args.out}")
    return 0


def _load_completers(paths, device):
    from pathlib import Path

    from ..errors import InputFileError, SpotlightsError

    for p in paths:
        if not Path(p).is_file():
            raise InputFileError(p, "checkpoint not found")
    try:
        from ..learning.inference import load_completer
    except ImportError as exc:
        raise SpotlightsError(f"model loading is not available ({exc}); install spotlights[learn]") from None
    return [load_completer(p, device=device) for p in paths]


def _evaluate(args) -> int:
    from pathlib import Path

    from ..experiments.real_evaluation import evaluate_consistency, report_markdown, write_report
    from ..data.real.extract import read_observations

    if args.reference_split and not args.reference:
        from ..errors import ParameterError

        raise ParameterError("--reference-split needs --reference DATASET.h5")
    obs = read_observations(args.file)  # validate before loading models
    refs, ref_info = (None, None)
    if args.reference:
        from ..experiments.real_evaluation import reference_shapes

        refs, ref_info = reference_shapes(args.reference, args.reference_split)
    completers = _load_completers(args.checkpoint, args.device)
    names = [c.model_name for c in completers]
    dup = {n for n in names if names.count(n) > 1}
    # two checkpoints of one model: tell them apart by file name, or by run folder for best.pt / last.pt
    tag = [Path(p).parent.name if Path(p).stem in ("best", "last") else Path(p).stem for p in args.checkpoint]
    names = [f"{n} ({t})" if n in dup else n for n, t in zip(names, tag)]
    report = evaluate_consistency(obs, completers, names=names, checkpoints=args.checkpoint,
                                  batch_size=args.batch_size, progress=not args.quiet, clip=args.clip,
                                  references=refs, reference_info=ref_info)
    report["data"]["file"] = str(args.file)
    prefix = args.out or str(Path(args.file).with_suffix("")) + "_consistency"
    md, js = write_report(report, prefix)
    print(report_markdown(report).split("\n## ")[0].strip())
    print(f"wrote {md} and {js}")
    return 0


def _show(args) -> int:
    from pathlib import Path

    from ..data.real.extract import read_observations
    from ..data.real.frames import frame_rows
    from ..errors import ParameterError
    from ..viz import render_frame

    if args.max_objects < 1:
        raise ParameterError("--max-objects must be >= 1")
    obs = read_observations(args.file)
    rows = frame_rows(obs, args.sequence, args.frame)
    rows = sorted(rows, key=lambda i: -int(obs.n_points_raw[i]))[: args.max_objects]
    completions, model = None, None
    if args.checkpoint:
        completer = _load_completers([args.checkpoint], args.device)[0]
        from ..experiments.real_evaluation import complete_all

        completions = complete_all(completer, obs.partial[rows], progress=False, clip=args.clip, box_sizes=obs.box_size[rows])
        model = completer.model_name
    i0 = rows[0]
    frame = obs.frame_id[i0]
    out = args.out or str(Path(args.file).with_suffix("")) + f"_{frame}.png"
    title = f"{obs.meta.get('source_format')} {obs.sequence[i0] + '/' if obs.sequence[i0] else ''}{frame}" + (f" - {model}" if model else "")
    objects = f"{len(rows)} object{'' if len(rows) == 1 else 's'} of frame {frame}"
    if args.html:
        from ..viz import html
        from ..viz.scene import frame_objects, read_frame_scan
        from .view import write_page

        scan = read_frame_scan(obs, i0)
        write_page(args.html, [("scene", html.scene_traces(scan, frame_objects(obs, rows, completions)))], title, quiet=True)
        print(f"wrote {args.html} ({objects}, interactive)")
        if not args.out:
            return 0
    render_frame(out, obs, rows, completions, title=title)
    print(f"wrote {out} ({objects})")
    return 0
