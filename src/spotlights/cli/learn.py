"""Learning commands: ``train``, ``evaluate``, ``complete``, ``bench models``.

Thin over :mod:`spotlights.learning`; torch and numpy are imported inside the handlers.
"""

from __future__ import annotations

import sys

from ._util import add_command, add_group, non_negative_int, positive_float, positive_int, unit_interval

MODEL_CHOICES = ("sanet", "pcn", "foldingnet", "topnet", "atlasnet")


def register(sub) -> None:
    # ---- train
    p = add_command(sub, "train", "train SA-Net or a baseline on a completion dataset (resumable, validated every epoch)",
                    "spotlights train --model sanet --data cars.h5 --epochs 40 --out runs/sanet", _train)
    p.add_argument("--model", required=True, choices=MODEL_CHOICES, help="which model to train")
    p.add_argument("--data", required=True, metavar="FILE.h5", help="dataset file (spotlights dataset build)")
    p.add_argument("--config", metavar="YAML", default=None, help="YAML overriding the packaged config (model/data/train sections)")
    p.add_argument("--schedule", default=None, metavar="NAME|YAML",
                   help="training schedule applied before --config: 'cpu' (35-70 min per model on 2 cores), "
                        "'paper' (the paper-scale GPU run), or a schedule YAML")
    p.add_argument("--out", metavar="DIR", default=None, help="run folder (default runs/MODEL): config.yaml, last.pt, best.pt, log.csv")
    p.add_argument("--epochs", type=positive_int, default=None, help="number of epochs (with --resume: raise it to train longer)")
    p.add_argument("--batch-size", type=positive_int, default=None, help="batch size per process")
    p.add_argument("--lr", type=float, default=None, help="learning rate")
    p.add_argument("--max-views", type=positive_int, default=None, metavar="V", help="use only views 0..V-1 of each training model")
    p.add_argument("--val-max-views", type=positive_int, default=None, metavar="V", help="validation views per model")
    p.add_argument("--rig", default=None, help="SA-Net: rig group of the dataset to regress (default: the file's default rig)")
    p.add_argument("--workers", type=non_negative_int, default=None, help="DataLoader worker processes (0: load in the main process)")
    p.add_argument("--seed", type=int, default=None, help="random seed (same seed + config = same weights)")
    p.add_argument("--device", default=None, help="torch device (default: cuda when available, else cpu)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", action="store_true", help="continue the run in --out from its last.pt")
    g.add_argument("--overwrite", action="store_true", help="start again even if --out holds a run")
    p.add_argument("--stop-after", type=int, default=None, metavar="K",
                   help="run at most K epochs now, then stop (continue later with --resume); the schedule spans --epochs")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")

    # ---- evaluate
    p = add_command(sub, "evaluate", "score checkpoints on a dataset split and write a Table-1 report (Markdown + JSON)",
                    "spotlights evaluate --data cars.h5 --checkpoint runs/*/best.pt --out report", _evaluate)
    p.add_argument("--data", required=True, metavar="FILE.h5", help="dataset file (or the index .json of a sharded dataset)")
    p.add_argument("--checkpoint", required=True, nargs="+", metavar="CKPT", help="one or more checkpoints")
    p.add_argument("--split", default="test", choices=("test", "val", "train"), help="split to score (default test)")
    p.add_argument("--out", default="report", metavar="PATH", help="report path without suffix: writes PATH.md and PATH.json (default ./report)")
    p.add_argument("--max-views", type=positive_int, default=None, metavar="V", help="score only views 0..V-1 of each model (faster)")
    p.add_argument("--clip", type=unit_interval, default=None, metavar="T", help="SA-Net clip for the 'w/ clip' row (default: the checkpoint's, 0.2)")
    p.add_argument("--batch-size", type=positive_int, default=32)
    p.add_argument("--fscore-threshold", type=positive_float, default=0.01, metavar="T", help="F-score distance threshold, unit frame (default 0.01)")
    p.add_argument("--accuracy-only", action="store_true", help="skip the GT -> prediction side (completeness, CD, F-score)")
    p.add_argument("--no-latency", action="store_true", help="do not time the models")
    p.add_argument("--device", default=None)
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--backend", choices=("local", "ray"), default="local",
                   help="ray: the per-model metric work (KD-trees per ground-truth model) as Ray tasks; same values")
    p.add_argument("--ray-address", default=None, metavar="ADDR",
                   help="with --backend ray: 'auto' joins the running cluster; default: a local instance")

    # ---- complete
    p = add_command(sub, "complete", "complete a partial scan of an object given its 3-D box; output in the scan's frame",
                    "spotlights complete car.pcd --box car_box.json --out car_completed.ply --show car.png", _complete)
    p.add_argument("input", metavar="INPUT", help="partial scan: .ply .pcd .npy .npz .xyz .txt")
    p.add_argument("--out", "-o", required=True, metavar="OUTPUT", help="completed cloud: .ply .pcd .npy .xyz .txt (scan's frame)")
    p.add_argument("--checkpoint", default=None, metavar="CKPT", help="checkpoint (default: the pretrained SA-Net shipped with spotlights)")
    p.add_argument("--box", default=None, metavar="BOX.json", help='box JSON: {"center": [x,y,z], "size": [l,w,h], "yaw": radians}')
    p.add_argument("--center", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"), help="box centre (instead of --box)")
    p.add_argument("--size", type=float, nargs=3, default=None, metavar=("L", "W", "H"), help="box length, width, height")
    p.add_argument("--yaw", type=float, default=0.0, metavar="RAD", help="box heading in radians about z (default 0)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--clip", type=unit_interval, default=None, metavar="T", help="SA-Net: drop rays with depth < T (default: the checkpoint's, 0.2)")
    g.add_argument("--no-clip", action="store_true", help="SA-Net: keep every ray with depth > 0")
    p.add_argument("--crop", type=float, default=None, metavar="MARGIN", help="keep only scan points inside the box grown by MARGIN metres")
    p.add_argument("--resample", default="random", choices=("random", "fps"),
                   help="how the scan is brought to 256 points: a seeded random subset (default, as in the training data) or farthest-point sampling")
    p.add_argument("--seed", type=int, default=0, help="seed of the resampling")
    p.add_argument("--show", default=None, metavar="PNG", help="also write a picture of the scan and its completion")
    p.add_argument("--device", default=None)

    # ---- bench models (reuses an existing 'bench' group if another module made one)
    bsub = add_group(sub, "bench", "benchmarks (bench models: parameters and latency of the five models)",
                     "spotlights bench models --batch 1 32", metavar="BENCH")
    p = add_command(bsub, "models", "parameters and median inference latency of the five models, in one run",
                    "spotlights bench models --batch 1 32 --json", _bench_models)
    p.add_argument("--models", nargs="+", default=list(MODEL_CHOICES), choices=MODEL_CHOICES, metavar="MODEL",
                   help=f"models to measure (default all: {', '.join(MODEL_CHOICES)})")
    p.add_argument("--batch", type=positive_int, nargs="+", default=[1, 32], metavar="B", help="batch sizes (default 1 32)")
    p.add_argument("--repeats", type=positive_int, default=10, help="timed runs per measurement (median reported)")
    p.add_argument("--warmup", type=int, default=2, help="untimed warm-up runs")
    p.add_argument("--threads", type=int, default=None, help="torch threads for every model (default: torch's)")
    p.add_argument("--device", default=None)
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--out", default=None, metavar="FILE.json", help="also write the JSON result here")


def _set_threads(n):
    if n:
        import torch

        torch.set_num_threads(int(n))


def _train(args) -> int:
    from ..learning.train import train

    _set_threads(args.threads)
    ov: dict = {"train": {}, "data": {}}
    for key, val in (("epochs", args.epochs), ("batch_size", args.batch_size), ("lr", args.lr), ("seed", args.seed)):
        if val is not None:
            ov["train"][key] = val
    for key, val in (("max_views", args.max_views), ("val_max_views", args.val_max_views), ("rig", args.rig),
                     ("num_workers", args.workers)):
        if val is not None:
            ov["data"][key] = val
    out = args.out or f"runs/{args.model}"
    res = train(args.model, args.data, out, config=args.config, overrides=ov, resume=args.resume, overwrite=args.overwrite,
                device=args.device, progress=not args.no_progress, schedule=args.schedule, stop_after=args.stop_after)
    h = res["history"][-1] if res["history"] else None
    if h:
        print(f"{args.model}: {res['epochs']} epochs, last val accuracy {h['val_accuracy']:.5f}; checkpoints {res['last']}, {res['best']}")
    return 0


def _evaluate(args) -> int:
    from ..learning.evaluate import evaluate_checkpoints, report_markdown, write_report

    _set_threads(args.threads)
    report = evaluate_checkpoints(args.checkpoint, args.data, split=args.split, max_views=args.max_views, clip=args.clip,
                                  batch_size=args.batch_size, device=args.device, fscore_threshold=args.fscore_threshold,
                                  with_completeness=not args.accuracy_only, latency=not args.no_latency,
                                  progress=not args.no_progress, backend=args.backend, ray_address=args.ray_address)
    md, js = write_report(report, args.out)
    print(report_markdown(report).split("\n## ")[0].rstrip())
    print(f"\nreport -> {md}, {js}")
    return 0


def _complete(args) -> int:
    from pathlib import Path

    import numpy as np

    from ..errors import SpotlightsError
    from ..geometry.io import load_points, save_points
    from ..learning.inference import DEFAULT, box_from_dict, complete_scan, load_box, load_completer

    if args.box is not None and (args.center is not None or args.size is not None):
        raise SpotlightsError("give the box either as --box BOX.json or as --center/--size/--yaw, not both")
    if args.box is not None:
        box = load_box(args.box)
    elif args.center is not None and args.size is not None:
        box = box_from_dict({"center": args.center, "size": args.size, "yaw": args.yaw}, "--center/--size")
    else:
        raise SpotlightsError("the object's box is missing: pass --box BOX.json, or --center X Y Z --size L W H [--yaw RAD]")
    points = load_points(args.input)
    completer = load_completer(args.checkpoint, device=args.device)
    clip = None if args.no_clip else (args.clip if args.clip is not None else DEFAULT)
    res = complete_scan(points, box, completer, clip=clip, crop=args.crop, seed=args.seed, resample_method=args.resample)
    outside = float(np.mean(np.linalg.norm(box.normalization().to_unit(points), axis=1) > 1.2))
    if outside > 0.5:
        print(f"spotlights: warning: {outside:.0%} of the scan lies outside the box's sphere; is the box in the scan's frame?",
              file=sys.stderr)
    if len(res["completed"]) == 0:
        raise SpotlightsError(f"{args.input}: the completion is empty (every ray was clipped); try --no-clip or a lower --clip")
    save_points(args.out, res["completed"])
    print(f"{args.input}: {len(points)} points ({res['used_points']} used) -> {completer.model_name} -> "
          f"{len(res['completed'])} points in the scan's frame -> {args.out}")
    if args.show:
        from .. import viz

        layers = [viz.Layer(points, "0.6", "scan", 3.0, 0.6), viz.Layer(res["completed"], "tab:green", "completion", 2.0)]
        viz.render_layers(args.show, layers, title=f"{Path(args.input).name}: {completer.model_name} completion")
        print(f"picture -> {args.show}")
    return 0


def _bench_models(args) -> int:
    import json

    from ..learning.bench import bench_markdown, bench_models
    from ..utils import atomic_output

    res = bench_models(args.models, args.batch, repeats=args.repeats, warmup=args.warmup, threads=args.threads,
                       device=args.device, progress=None if args.json else (lambda m: print(m, file=sys.stderr)))
    text = json.dumps(res, indent=2)
    if args.out:
        with atomic_output(args.out) as tmp:
            tmp.write_text(text)
    print(text if args.json else bench_markdown(res))
    return 0
