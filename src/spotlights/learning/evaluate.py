"""Evaluation of trained checkpoints on a dataset split: the paper's Table 1 (Markdown + JSON).

For each checkpoint the split's partial scans are completed, and every prediction
is scored against its model's dense ground truth (16,384 points, unit frame) with
the metrics of :mod:`spotlights.metrics.completion` (KD-tree per ground-truth model).
SA-Net is reported twice, without clip (rays with depth > 0) and with its clip
(default 0.2), as in the paper; the hit-aware SA-Net once, at the p(hit) threshold its
checkpoint stores (chosen on validation; no clip). Aggregates are given per category and
overall, both as the mean over samples (the paper's "Average") and the mean over categories.

The report's first table is Table 1 under one protocol: accuracy, completeness, CD-L1,
F-score@0.01 and points per completion (means over samples), parameters, the training each
checkpoint had (steps, samples seen, minutes, precision, read from the checkpoint) and, when
asked (``latency=True``, ``spotlights evaluate --latency``), the median latency at batch 1
and 32 (same threads for every model; opt-in because timing every model costs minutes).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import logs
from ..data.store import open_dataset
from ..distributed import check_backend, ray_session
from ..errors import ParameterError
from ..geometry.evidence import SnapTargets, snap_radius
from ..metrics.completion import METRIC_DESCRIPTIONS, evaluate_completions, summarize
from ..options import (
    DEVICE_HELP,
    MAX_BATCH,
    REQUIRED,
    batch_size_number,
    check_threads,
    non_negative_float,
    non_negative_int,
    option,
    positive_float,
    positive_int,
    settings_from_dict,
    unit_interval,
)
from ..outputs import check_writable
from ..timing import StageTimer
from ..viz import render_predictions
from .bench import model_latency
from .checkpoint import load_checkpoint, model_from_checkpoint
from .evaluate_report import TABLE_METRIC as TABLE_METRIC
from .evaluate_report import latency_key as latency_key
from .evaluate_report import model_label as model_label
from .evaluate_report import report_markdown, tag_repeated_models, write_report
from .inference import DEFAULT, load_completer, mirrored
from .ray_metrics import RayMetrics
from .rays import DirectionTable


def _variants(model, clip, snap: float | None, snap_mirror: bool) -> list[tuple[str, float | None]]:
    """The rows a model is scored in: (variant name, clip) pairs (SA-Net without and with clip, the hit-aware
    SA-Net at its threshold, a baseline once), each named with its snap radius when ``snap`` is set."""
    if hasattr(model, "hit_probabilities"):  # hit-aware SA-Net: rays with p(hit) >= the checkpoint's threshold
        # no clip (a clip only if asked)
        variants = [(f"p(hit) >= {model.threshold:g}", None)] + (
            [(f"p(hit) >= {model.threshold:g}, clip {float(clip):g}", float(clip))] if clip is not None else []
        )
    elif model.target == "depths":
        c = model.clip if clip is None else float(clip)
        variants = [("no clip", None)] + ([(f"clip {c:g}", c)] if c is not None else [])
    else:
        variants = [("", None)]
    if snap is not None:
        tag = f"snap {snap:g}" + (" mirrored" if snap_mirror else "")
        variants = [((v + ", " if v else "") + tag, c) for v, c in variants]
    return variants


def _snap_kwargs(batch: dict, snap: float | None, snap_mirror: bool) -> dict:
    """``outputs_to_points``' ``snap`` argument for one batch: its partials (and their mirror images) as targets."""
    if snap is None:
        return {}
    seen = [p.numpy() for p in batch["partial"]]
    observed = [mirrored(p) for p in seen] if snap_mirror else seen
    return {"snap": SnapTargets(observed, snap, batch["sensor_origin"].numpy(), seen)}


@dataclass
class _Predictions:
    """Every variant's completions of a split: {variant: [(M, 3) float arrays]} and the share of rays kept."""

    points: dict
    kept: dict
    seconds: float = 0.0


def _predict(model, ds, dev, variants: list, snap, snap_mirror: bool, loader_kw: dict, desc: str, progress: bool):
    """Complete every scan of ``ds`` with ``model`` in each variant: a :class:`_Predictions`."""
    import torch
    from torch.utils.data import DataLoader
    from tqdm import tqdm

    from .data import worker_batches

    preds = _Predictions({v: [] for v, _ in variants}, {v: [] for v, _ in variants})
    rays = None
    if getattr(model, "needs_box", False):  # box-targeted SA-Net: each sample decodes with its model's box
        rays = DirectionTable(model.rig, ds.extents)
    loader = DataLoader(ds, shuffle=False, **loader_kw)
    timer = StageTimer()
    with timer("predict"), torch.inference_mode():
        bar = tqdm(loader, desc=desc, unit="batch", disable=not progress, leave=False)
        for batch in worker_batches(bar):
            b = {k: (v.to(dev) if torch.is_tensor(v) else v) for k, v in batch.items()}
            if getattr(model, "class_embedding", None) is not None:  # each sample's class, from its model row
                b["cls"] = model.class_indices(ds.classes[batch["model"].numpy()]).to(dev)
            out = model(*model.forward_inputs(b, rays))
            dirs = rays.directions(batch["model"].to(dev)) if rays is not None else None
            snap_kw = _snap_kwargs(batch, snap, snap_mirror)
            for v, c in variants:
                pts = model.outputs_to_points(out, c, dirs, **snap_kw)
                preds.points[v].extend(p.cpu().numpy() for p in pts)
                if model.target == "depths":
                    preds.kept[v].extend(len(p) / model.rig.n_rays for p in pts)
    preds.seconds = timer.seconds["predict"]
    return preds


def _score_rows(model, variants: list, preds: _Predictions, ds, dense, scorer, fscore_threshold, with_completeness):
    """One report row per variant: its clip, the summary of its metrics (and the hit-aware SA-Net's threshold)."""
    models = ds.sample_models
    cats = ds.sample_categories
    order = ds.info.category_order()
    rows = []
    trees: dict = {}
    for v, c in variants:
        per = (scorer or evaluate_completions)(
            preds.points[v], models, _DenseView(dense), fscore_threshold, with_completeness, trees
        )
        if model.target == "depths":
            per["hit_ratio"] = np.asarray(preds.kept[v], dtype=np.float64)
        rows.append(
            {
                "variant": v,
                "clip": c,
                "summary": summarize(per, cats, order),
                **({"threshold": model.threshold} if hasattr(model, "hit_probabilities") else {}),
            }
        )
    return rows


def evaluate_checkpoint(
    checkpoint,
    data,
    split: str = "test",
    batch_size: int = 32,
    max_views: int | None = None,
    clip=None,
    device=None,
    with_completeness: bool = True,
    fscore_threshold: float = 0.01,
    latency: bool = False,
    latency_repeats: int = 10,
    num_workers: int = 0,
    progress: bool = True,
    dataset=None,
    gt_dense=None,
    scorer=None,
    snap: float | None = None,
    snap_mirror: bool = False,
) -> dict:
    """Score one checkpoint on one split.

    Parameters
    ----------
    checkpoint : checkpoint path. data : dataset HDF5 file. split : "test" (default), "val", "train".
    max_views : only views < max_views per model (faster, fewer samples).
    clip : SA-Net clip threshold for the "w/ clip" row (default: the checkpoint's, 0.2).
    with_completeness : also compute the GT -> prediction side (completeness, CD-L1,
        CD-L2, F-score); costs one small KD-tree per prediction.
    latency : measure the median latency at batch 1 and 32 (``latency_repeats`` timed runs each after
        two warm-up runs; off by default: opt-in).
    dataset, gt_dense : an already opened split and its dense GT (to share across checkpoints).
    scorer : the per-model metric work, ``evaluate_completions`` (default) or a drop-in such as
        :class:`~spotlights.learning.ray_metrics.RayMetrics` (``evaluate --backend ray``).
    snap : > 0: every SA-Net row with its rays snapped to each scan's partial within this radius (unit frame;
        :func:`spotlights.geometry.evidence.snap_to_observed`; the rows' names say so); None or 0: off. Models
        without rays (the point-set baselines) are scored unsnapped (their result's ``snap`` is None).
        snap_mirror : and to the partial's mirror image (``y -> -y``).

    Returns
    -------
    dict with ``model``, ``checkpoint``, ``params``, ``training`` ({"steps", "epochs", "best_epoch",
    "samples_seen", "minutes", "precision"} of the checkpoint), ``latency_ms`` (when timed),
    ``rows`` (one per variant: SA-Net "no clip" and "clip 0.2", the hit-aware SA-Net
    "p(hit) >= t" with ``threshold``; baselines one), each with ``summary`` (see
    :func:`~spotlights.metrics.completion.summarize`; SA-Nets add ``hit_ratio``).
    """
    from .data import TorchCompletionDataset
    from .device import resolve_device

    dev = resolve_device(device)
    ckpt = load_checkpoint(checkpoint)
    model = model_from_checkpoint(ckpt, dev)
    name = ckpt["model_name"]
    ds = dataset or TorchCompletionDataset(data, split, rig=False, max_views=max_views, partials_in_memory=True)
    dense = gt_dense if gt_dense is not None else ds.gt_dense()
    snap = snap_radius(snap, snap_mirror)
    if not hasattr(model, "snap_rays"):  # a point model has no rays: scored as it is beside the snapped SA-Nets
        snap, snap_mirror = None, False
    variants = _variants(model, clip, snap, snap_mirror)
    loader_kw = {"batch_size": batch_size, "num_workers": num_workers}
    preds = _predict(model, ds, dev, variants, snap, snap_mirror, loader_kw, f"evaluate {name}", progress)
    rows = _score_rows(model, variants, preds, ds, dense, scorer, fscore_threshold, with_completeness)
    result = {
        "model": name,
        "checkpoint": str(checkpoint),
        "split": ds.split,
        "n_samples": len(ds),
        "params": model.param_counts(),
        "rows": rows,
        "predict_seconds": preds.seconds,
        "snap": snap,
        "snap_mirror": bool(snap_mirror),
        "trained_epochs": int(ckpt.get("epoch", 0) or 0),
        "training": training_facts(ckpt),
    }
    if latency:
        result.update(_latency(model, dev, latency_repeats))
    return result


def _latency(model, dev, repeats: int) -> dict:
    """The model's median latency at batch 1 and 32 in ms (``latency_ms``), the device and torch's threads."""
    import torch

    return {
        "latency_ms": model_latency(model, dev, repeats=repeats),
        "latency_device": str(dev),
        "threads": torch.get_num_threads(),
    }


def training_facts(ckpt: dict) -> dict:
    """What training a checkpoint had: {"steps", "epochs", "best_epoch", "samples_seen", "minutes", "precision"}.

    ``minutes`` is the wall time of training and validation up to the checkpoint's epoch (``log.csv``'s
    ``wall_seconds``; None for checkpoints written before it was logged); ``precision`` is ``fp32`` for
    checkpoints written before ``--precision`` existed.
    """
    hist = ckpt.get("history") or []
    last = hist[-1] if hist else {}
    wall = last.get("wall_seconds")
    if wall is None and hist and all("epoch_seconds" in h for h in hist):
        wall = sum(float(h["epoch_seconds"]) for h in hist)
    batch = ((ckpt.get("config") or {}).get("train") or {}).get("batch_size")
    steps = ckpt.get("global_step")
    seen = last.get("samples_seen", None if steps is None or batch is None else int(steps) * int(batch))
    return {
        "steps": None if steps is None else int(steps),
        "epochs": int(ckpt.get("epoch", 0) or 0),
        "best_epoch": (ckpt.get("best") or {}).get("epoch"),
        "samples_seen": seen,
        "minutes": None if wall is None else float(wall) / 60.0,
        "precision": ckpt.get("precision", "fp32"),
    }


class _DenseView:
    """Index a {model row: (L, 3)} dict like an array (for evaluate_completions)."""

    def __init__(self, d: dict):
        self.d = d

    def __getitem__(self, m):
        return self.d[int(m)]


def evaluate_checkpoints(
    checkpoints,
    data,
    split: str = "test",
    progress: bool = True,
    backend: str = "local",
    ray_address: str | None = None,
    **kw,
) -> dict:
    """Evaluate several checkpoints on the same split (the split and its dense GT are read once).

    backend : ``"local"`` or ``"ray"`` (the per-model metric work as Ray tasks, on the cluster at
        ``ray_address`` or a local instance; the same values).

    Returns a report dict: ``data``, ``split``, ``categories`` (report order), ``metric_descriptions``,
    ``results`` (one :func:`evaluate_checkpoint` dict per checkpoint).
    """
    from .data import TorchCompletionDataset

    if not checkpoints:
        raise ParameterError("give at least one checkpoint to evaluate")
    ds = TorchCompletionDataset(data, split, rig=False, max_views=kw.pop("max_views", None), partials_in_memory=True)
    dense = ds.gt_dense()

    with ray_session(ray_address) if check_backend(backend) == "ray" else contextlib.nullcontext() as ray:
        scorer = None
        if ray is not None:
            scorer = RayMetrics(ray)
        results = [
            evaluate_checkpoint(c, data, split, dataset=ds, gt_dense=dense, progress=progress, scorer=scorer, **kw)
            for c in checkpoints
        ]
    tag_repeated_models(results)
    return {
        "data": str(data),
        "split": split,
        "n_samples": len(ds),
        "n_models": int(len(np.unique(ds.sample_models))),
        "categories": ds.info.category_order(),
        "metric_descriptions": METRIC_DESCRIPTIONS,
        "results": results,
    }


def prediction_examples(
    checkpoints, data, split: str = "test", per_category: int = 2, clip=None, device=None
) -> list[dict]:
    """A few scans per category with every checkpoint's prediction, for
    :func:`spotlights.viz.render_predictions` (``spotlights evaluate`` draws them beside the report).

    The scans: in each category (report order), the first view of the first ``per_category``
    models of the split. SA-Net predictions use ``clip`` (default: the checkpoint's).
    Returns dicts with ``label``, ``partial`` (K, 3), ``gt`` (the dense ground truth, (L, 3)),
    ``predictions`` [(model name, (M, 3))], all float, unit frame.
    """
    completers = [load_completer(c, device=device) for c in checkpoints]
    names = [c.model_name for c in completers]
    names = [
        f"{n} ({Path(c).parent.name or Path(c).stem})" if names.count(n) > 1 else n for n, c in zip(names, checkpoints)
    ]
    out = []
    with open_dataset(data) as ds:
        idx = ds.split_indices(split)
        models = ds.sample_model[idx]
        cats = ds.categories[models]
        for cat in sorted(set(cats.tolist())):
            first = {}
            for i, m in zip(idx[cats == cat], models[cats == cat]):
                first.setdefault(int(m), int(i))
            for i in list(first.values())[:per_category]:
                smp = ds.sample(i)
                preds = []
                for name, c in zip(names, completers):
                    kw = {"extents": smp["extents"][None]} if c.needs_box else {}
                    preds.append(
                        (name, c.complete(smp["partial"][None], clip=DEFAULT if clip is None else clip, **kw)[0])
                    )
                out.append(
                    {
                        "label": f"{smp['model']} ({smp['category']}), view {smp['view']}",
                        "partial": smp["partial"],
                        "gt": smp["gt_dense"],
                        "predictions": preds,
                    }
                )
    return out


@dataclass(frozen=True, kw_only=True)
class EvaluateSettings:
    """What ``spotlights evaluate`` is asked to do: its options as one object, each field declaring
    its option (:func:`spotlights.options.option`: default and help written once).

    checkpoint : checkpoint files (or short names) to score, one report row group each.
    data : dataset file or shard index. split : ``test``, ``val`` or ``train``.
    out : report path without suffix: ``OUT.md``, ``OUT.json`` and the figure ``OUT.png``.
    max_views : score only views ``0..V-1`` of each model (None: all).
    clip : SA-Net depth clip in [0, 1] for the 'w/ clip' row (None: the checkpoint's).
    batch_size : evaluation batch size. fscore_threshold : F-score distance, unit frame.
    accuracy_only : skip the ground truth -> prediction side (completeness, CD, F-score).
    latency, latency_repeats, no_latency : time each model (median ms at batch 1 and 32) when
        ``latency`` and not ``no_latency``, ``latency_repeats`` timed runs after 2 warm-ups.
    examples : scans per category in the figure (0: no figure).
    device, threads : torch device and CPU threads (None: the defaults).
    snap : > 0: SA-Net rows with their rays snapped to each scan's partial within this radius (unit frame); 0: off.
    snap_mirror : with ``snap``, to the partial's mirror image too.
    quiet : no progress bars. backend, ray_address : ``"local"`` or ``"ray"`` metric work.
    """

    data: str | os.PathLike = option(
        default=REQUIRED, metavar="FILE.h5|INDEX.json", help="dataset file (or the index .json of a sharded dataset)"
    )
    checkpoint: list = option(default=REQUIRED, nargs="+", metavar="CKPT", help="one or more checkpoints")
    split: str = option(default="test", choices=("test", "val", "train"), help="split to score (default test)")
    out: str | os.PathLike = option(
        "--out",
        "-o",
        default="report",
        metavar="PATH",
        help="report path without suffix: writes PATH.md, PATH.json and the figure PATH.png (see --examples; "
        "default ./report)",
    )
    max_views: int | None = option(
        default=None, type=positive_int, metavar="V", help="score only views 0..V-1 of each model (faster)"
    )
    clip: float | None = option(
        default=None,
        type=unit_interval,
        metavar="T",
        help="SA-Net clip for the 'w/ clip' row (default: the checkpoint's: 0.2 for the paper SA-Net)",
    )
    batch_size: int = option(
        default=32, type=batch_size_number, help=f"evaluation batch size, 1..{MAX_BATCH} (default 32)"
    )
    fscore_threshold: float = option(
        default=0.01, type=positive_float, metavar="T", help="F-score distance threshold, unit frame (default 0.01)"
    )
    accuracy_only: bool = option(
        default=False, action="store_true", help="skip the GT -> prediction side (completeness, CD, F-score)"
    )
    latency: bool = option(
        default=False,
        action="store_true",
        help="also time every model: median latency at batch 1 and 32 (opt-in: it costs minutes)",
    )
    latency_repeats: int = option(
        default=10,
        type=positive_int,
        metavar="R",
        help="timed runs per model and batch with --latency (default 10, after 2 warm-up runs)",
    )
    no_latency: bool = option(
        default=False, action="store_true", help="do not time the models (the default; kept for scripts)"
    )
    examples: int = option(
        default=2,
        type=non_negative_int,
        metavar="K",
        help="figure PATH.png: K scans per category, each model's prediction beside the ground truth (default 2; "
        "0: no figure)",
    )
    snap: float = option(
        default=0.0,
        type=non_negative_float,
        metavar="R",
        help="SA-Nets: score the completions with every ray that passes within R (unit frame) of an input point "
        "snapped to it, as 'complete --snap R' (default 0: off; the figure shows the models' own outputs)",
    )
    snap_mirror: bool = option(
        default=False,
        action="store_true",
        help="with --snap R: also snap to the input's mirror image across the box's x-z plane, as 'complete "
        "--snap-mirror'",
    )
    device: str | None = option(default=None, help=DEVICE_HELP)
    threads: int | None = option(default=None, type=positive_int, help="torch CPU threads (default: torch's)")
    quiet: bool = option(default=False, quiet=True, help="no progress bar")
    backend: str = option(
        default="local",
        choices=("local", "ray"),
        help="ray: the per-model metric work (KD-trees per ground-truth model) as Ray tasks; same values",
    )
    ray_address: str | None = option(
        default=None,
        metavar="ADDR",
        help="with --backend ray: 'auto' joins the running cluster; default: a local instance",
    )

    @classmethod
    def from_dict(cls, d: Mapping, where: str | os.PathLike | None = None) -> EvaluateSettings:
        """Read settings by the one strict policy (:func:`spotlights.options.settings_from_dict`)."""
        return settings_from_dict(cls, d, where)


def report_path(prefix: str | os.PathLike) -> str:
    """The Markdown file of a report written to ``PREFIX`` (``.md``/``.json`` suffix or none)."""
    text = str(prefix)
    return (
        text[: -len(".json")] if text.endswith(".json") else text[: -len(".md")] if text.endswith(".md") else text
    ) + ".md"


def run_evaluation(s: EvaluateSettings, log: Callable[[str], None] = logs.info) -> dict:
    """``spotlights evaluate``: score ``s.checkpoint`` on ``s.data``, write the report (Markdown
    and JSON) and, with ``s.examples``, the figure of predictions beside the ground truth (PNG).
    ``log`` receives the Table-1 summary and the paths as they are written. Returns the report
    dict of :func:`evaluate_checkpoints`."""
    check_writable(report_path(s.out))
    if s.threads:
        import torch

        torch.set_num_threads(check_threads(s.threads))
    report = evaluate_checkpoints(
        s.checkpoint,
        s.data,
        split=s.split,
        max_views=s.max_views,
        clip=s.clip,
        batch_size=s.batch_size,
        device=s.device,
        fscore_threshold=s.fscore_threshold,
        with_completeness=not s.accuracy_only,
        latency=s.latency and not s.no_latency,
        latency_repeats=s.latency_repeats,
        progress=not s.quiet,
        backend=s.backend,
        ray_address=s.ray_address,
        snap=s.snap or None,
        snap_mirror=s.snap_mirror,
    )
    md, js = write_report(report, s.out)
    log(report_markdown(report).split("\n## ")[0].rstrip())
    log(f"\nreport -> {md}, {js}")
    if s.examples:
        png = render_predictions(
            md.with_suffix(".png"),
            prediction_examples(s.checkpoint, s.data, s.split, per_category=s.examples, clip=s.clip, device=s.device),
            title=f"{s.split} scans of {Path(s.data).name}: predictions beside the ground truth (unit frame)",
        )
        log(f"figure -> {png}")
    return report
