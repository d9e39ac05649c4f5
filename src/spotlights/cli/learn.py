"""Learning commands: ``train``, ``evaluate``, ``bench models`` (``complete`` is in :mod:`.complete`).

Thin over :mod:`spotlights.learning`; torch and numpy are imported inside the handlers.
"""

from __future__ import annotations

import argparse

from ..experiments.curves import learning_curves, summary_markdown
from ..learning.bench import BenchSettings, run_bench
from ..learning.evaluate import EvaluateSettings, run_evaluation
from ..learning.export import export_model
from ..learning.models import MODEL_NAMES as MODEL_CHOICES  # registry keys (imports neither torch nor a model)
from ._util import (
    DEVICE_HELP,
    add_command,
    add_group,
    add_options,
    add_quiet,
    check_suffix,
    non_negative_int,
    positive_float,
    positive_int,
    settings_of,
    unit_interval,
)


def register(sub) -> None:
    # ---- train
    p = add_command(
        sub,
        "train",
        "train SA-Net or a baseline on a completion dataset (resumable, validated every epoch)",
        "spotlights train --model sanet --data cars.h5 --epochs 40 --out runs/sanet",
        _train,
    )
    p.add_argument("--model", required=True, choices=MODEL_CHOICES, help="which model to train")
    p.add_argument(
        "--data",
        required=True,
        metavar="FILE.h5|INDEX.json",
        help="dataset file (spotlights dataset build), or the index .json of a sharded dataset (--shard-size)",
    )
    p.add_argument(
        "--config", metavar="YAML", default=None, help="YAML overriding the packaged config (model/data/train sections)"
    )
    p.add_argument(
        "--schedule",
        default=None,
        metavar="NAME|YAML",
        help="training schedule applied before --config: 'cpu' (35-70 min per model on 2 cores), "
        "'paper' (the paper-scale GPU run), or a schedule YAML",
    )
    p.add_argument(
        "--out",
        "-o",
        metavar="DIR",
        default=None,
        help="run folder (default runs/MODEL): config.yaml, last.pt, best.pt, log.csv",
    )
    p.add_argument(
        "--epochs", type=positive_int, default=None, help="number of epochs (with --resume: raise it to train longer)"
    )
    p.add_argument("--batch-size", type=positive_int, default=None, help="batch size per process")
    p.add_argument(
        "--lr", type=positive_float, default=None, help="learning rate, a finite number > 0 (default: the config's)"
    )
    p.add_argument(
        "--max-views", type=positive_int, default=None, metavar="V", help="use only views 0..V-1 of each training model"
    )
    p.add_argument("--val-max-views", type=positive_int, default=None, metavar="V", help="validation views per model")
    p.add_argument(
        "--rig", default=None, help="SA-Net: rig group of the dataset to regress (default: the file's default rig)"
    )
    p.add_argument(
        "--workers",
        type=non_negative_int,
        default=None,
        help="DataLoader worker processes (0: load in the main process)",
    )
    p.add_argument(
        "--seed", type=non_negative_int, default=None, help="random seed (same seed + config = same weights)"
    )
    p.add_argument("--device", default=None, help=DEVICE_HELP)
    p.add_argument("--threads", type=positive_int, default=None, help="torch CPU threads (default: torch's)")
    p.add_argument(
        "--precision",
        choices=("auto", "fp32", "bf16"),
        default=None,
        help="forward-pass precision: auto (default: bf16 where the CPU or GPU supports it, else fp32), "
        "fp32, or bf16 (fp16 with a gradient scaler on GPUs without bf16); weights, losses and "
        "metrics stay float32",
    )
    p.add_argument(
        "--steps-per-epoch",
        type=positive_int,
        default=None,
        metavar="N",
        help="make an epoch N optimizer steps drawn from shuffled passes over the training set "
        "(a validation and checkpoint interval) instead of one full pass",
    )
    p.add_argument(
        "--compile",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="run the training forward pass through torch.compile (--no-compile: eager; may change on --resume; "
        "1.1-1.4x faster steps at bf16 on "
        "CPU after 1.3-2.5 min of compilation; docs/benchmarks.md)",
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", action="store_true", help="continue the run in --out from its last.pt")
    g.add_argument(
        "--overwrite",
        action="store_true",
        help="start again even if --out holds a run (its last.pt, best.pt and log.csv are removed first)",
    )
    p.add_argument(
        "--stop-after",
        type=positive_int,
        default=None,
        metavar="K",
        help="run at most K epochs now, then stop (continue later with --resume); the schedule spans --epochs",
    )
    p.add_argument(
        "--allow-new-data",
        action="store_true",
        help="with --resume: continue even if --data is not the dataset the run was trained on (refused by default)",
    )
    add_quiet(p, "no progress bars")

    # ---- evaluate
    p = add_command(
        sub,
        "evaluate",
        "score checkpoints on a dataset split and write a Table-1 report (Markdown + JSON) "
        "and a figure of predictions beside their ground truth (PNG)",
        "spotlights evaluate --data cars.h5 --checkpoint runs/*/best.pt --out report",
        _evaluate,
    )
    add_options(p, EvaluateSettings)

    # ---- curves
    p = add_command(
        sub,
        "curves",
        "learning curves of training runs: validation CD-L1, accuracy and completeness "
        "against samples seen and minutes, one figure per axis, and whether each curve has flattened",
        "spotlights curves runs/sanet runs/topnet --budget-minutes 45 --out results/curves",
        _curves,
    )
    p.add_argument("runs", nargs="+", metavar="RUN", help="run folders of 'spotlights train' (each holds log.csv)")
    p.add_argument(
        "--out",
        "-o",
        default="curves",
        metavar="DIR",
        help="output folder: curves_samples.png, curves_minutes.png, curves.json, one CSV per run (default ./curves)",
    )
    p.add_argument(
        "--names", nargs="+", default=None, metavar="NAME", help="display names, one per run (default: folder names)"
    )
    p.add_argument(
        "--budget-minutes",
        type=positive_float,
        default=None,
        metavar="M",
        help="minutes axis in budget minutes: M x (steps done / steps planned), for runs given equal step "
        "budgets measured on a quiet machine (default: each run's wall clock)",
    )
    p.add_argument(
        "--tail",
        type=unit_interval,
        default=0.2,
        metavar="SHARE",
        help="share of each run (by steps) judged for flatness (default 0.2: the last 20%%)",
    )
    p.add_argument(
        "--tolerance",
        type=positive_float,
        default=0.02,
        metavar="REL",
        help="a curve has flattened when its tail improves it by less than this share (default 0.02)",
    )

    # ---- export
    p = add_command(
        sub,
        "export",
        "export a trained model to ONNX (rig, clip and p(hit) threshold stored as metadata)",
        "spotlights export paper --out sanet.onnx\n  spotlights complete car.pcd --box box.json --checkpoint "
        "sanet.onnx --runtime onnx --out car.ply",
        _export,
    )
    p.add_argument(
        "checkpoint",
        metavar="CHECKPOINT",
        help="a checkpoint file or a short name: 'default' (the package's default model) or 'paper'",
    )
    p.add_argument("--out", "-o", required=True, metavar="MODEL.onnx", help="the ONNX file to write (.onnx)")
    p.add_argument(
        "--opset",
        type=positive_int,
        default=18,
        help="ONNX opset, 15 to the newest the installed onnx knows (default 18)",
    )
    p.add_argument(
        "--no-check",
        action="store_true",
        help="skip the parity check (onnxruntime against torch on 8 seeded random scans)",
    )
    add_quiet(p, "no summary")

    # ---- bench models (reuses an existing 'bench' group if another module made one)
    bsub = add_group(
        sub,
        "bench",
        "benchmarks (bench models: parameters and latency of the five models)",
        "spotlights bench models --batch 1 32",
        metavar="BENCH",
    )
    p = add_command(
        bsub,
        "models",
        "parameters and median inference latency of the five models, in one run",
        "spotlights bench models --batch 1 32 --json",
        _bench_models,
    )
    add_options(p, BenchSettings)


def _train(args) -> int:
    from ..learning.train import TrainSettings, run_training

    settings = settings_of(
        TrainSettings, args, model_name=args.model, out_dir=args.out, num_workers=args.workers, progress=not args.quiet
    )
    res = run_training(settings)
    h = res["history"][-1] if res["history"] else None
    if h:
        print(
            f"{args.model}: {res['epochs']} epochs, last val accuracy {h['val_accuracy']:.5f}; checkpoints {res['last']}, {res['best']}"
        )
    return 0


def _evaluate(args) -> int:
    run_evaluation(settings_of(EvaluateSettings, args))
    return 0


def _curves(args) -> int:
    summary = learning_curves(args.runs, args.names, args.out, args.budget_minutes, args.tail, args.tolerance)
    print(summary_markdown(summary).rstrip())
    print(f"\ncurves -> {args.out}/curves_samples.png, {args.out}/curves_minutes.png, {args.out}/curves.json")
    return 0


def _export(args) -> int:
    from pathlib import Path

    check_suffix(Path(args.out), (".onnx",), "an ONNX model")
    export_model(args.checkpoint, args.out, args.opset, describe=not args.quiet, check=not args.no_check)
    return 0


def _bench_models(args) -> int:
    check_suffix(args.out, (".json",), "the result (JSON)")
    run_bench(settings_of(BenchSettings, args))
    return 0
