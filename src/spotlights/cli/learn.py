"""Learning commands: ``train``, ``evaluate``, ``bench models`` (``complete`` is in :mod:`.complete`).

Thin over :mod:`spotlights.learning`; torch and numpy are imported inside the handlers.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..experiments.curves import learning_curves, summary_markdown
from ..learning.bench import BenchSettings, run_bench
from ..learning.evaluate import EvaluateSettings, run_evaluation
from ..learning.export import export_model
from ..learning.settings import TrainSettings
from ..options import option
from ._util import (
    add_command,
    add_group,
    add_options,
    add_quiet,
    check_suffix,
    positive_float,
    positive_int,
    settings_of,
    unit_interval,
)


@dataclass(kw_only=True)
class CurvesOptions:
    """The options of ``spotlights curves``."""

    runs: list[str] = option(
        "runs", nargs="+", metavar="RUN", help="run folders of 'spotlights train' (each holds log.csv)"
    )
    out: str = option(
        "--out",
        "-o",
        default="curves",
        metavar="DIR",
        help="output folder: curves_samples.png, curves_minutes.png, curves.json, one CSV per run (default ./curves)",
    )
    names: list[str] | None = option(
        default=None, nargs="+", metavar="NAME", help="display names, one per run (default: folder names)"
    )
    budget_minutes: float | None = option(
        default=None,
        type=positive_float,
        metavar="M",
        help="minutes axis in budget minutes: M x (steps done / steps planned), for runs given equal step "
        "budgets measured on a quiet machine (default: each run's wall clock)",
    )
    tail: float = option(
        default=0.2,
        type=unit_interval,
        metavar="SHARE",
        help="share of each run (by steps) judged for flatness (default 0.2: the last 20%%)",
    )
    tolerance: float = option(
        default=0.02,
        type=positive_float,
        metavar="REL",
        help="a curve has flattened when its tail improves it by less than this share (default 0.02)",
    )


@dataclass(kw_only=True)
class ExportOptions:
    """The options of ``spotlights export`` (then ``-q``)."""

    checkpoint: str = option(
        "checkpoint",
        metavar="CHECKPOINT",
        help="a checkpoint file or a short name: 'default' (the package's default model), 'paper' or 'classes' "
        "(class-conditioned: the graph takes each scan's class row too)",
    )
    out: str = option("--out", "-o", metavar="MODEL.onnx", help="the ONNX file to write (.onnx)")
    opset: int = option(
        default=18, type=positive_int, help="ONNX opset, 15 to the newest the installed onnx knows (default 18)"
    )
    no_check: bool = option(
        default=False,
        action="store_true",
        help="skip the parity check (onnxruntime against torch on 8 seeded random scans)",
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
    add_options(p, TrainSettings)

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
    add_options(p, CurvesOptions)

    # ---- export
    p = add_command(
        sub,
        "export",
        "export a trained model to ONNX (rig, clip, p(hit) threshold and class vocabulary stored as metadata)",
        "spotlights export paper --out sanet.onnx\n  spotlights complete car.pcd --box box.json --checkpoint "
        "sanet.onnx --runtime onnx --out car.ply",
        _export,
    )
    add_options(p, ExportOptions)
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
    from ..learning.train import run_training

    res = run_training(settings_of(TrainSettings, args))
    h = res["history"][-1] if res["history"] else None
    if h:
        print(
            f"{args.model}: {res['epochs']} epochs, last val accuracy {h['val_accuracy']:.5f}; checkpoints {res['last']}, {res['best']}"
        )
    return 0


def _evaluate(args) -> int:
    run_evaluation(settings_of(EvaluateSettings, args), log=print)
    return 0


def _curves(args) -> int:
    summary = learning_curves(args.runs, args.names, args.out, args.budget_minutes, args.tail, args.tolerance)
    print(summary_markdown(summary).rstrip())
    print(f"\ncurves -> {args.out}/curves_samples.png, {args.out}/curves_minutes.png, {args.out}/curves.json")
    return 0


def _export(args) -> int:
    from pathlib import Path

    check_suffix(Path(args.out), (".onnx",), "an ONNX model")
    export_model(args.checkpoint, args.out, args.opset, describe=not args.quiet, check=not args.no_check, log=print)
    return 0


def _bench_models(args) -> int:
    check_suffix(args.out, (".json",), "the result (JSON)")
    run_bench(settings_of(BenchSettings, args), log=print)
    return 0
