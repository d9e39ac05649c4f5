"""Training loop: seeded, resumable, validated every epoch, single process or DDP (torchrun).

Determinism: the model is initialised under ``torch.manual_seed(seed)``; at the
start of every epoch the global torch RNG is reseeded from ``(seed, epoch)`` and
the shuffling permutation is drawn from a generator seeded the same way. Datasets
hold no randomness, so the result does not depend on the number of DataLoader
workers, and resuming from the checkpoint of epoch ``e`` reproduces exactly the
run that did not stop (model, optimizer and scheduler states are saved each epoch).

Outputs in ``out_dir``: ``config.yaml`` (resolved), ``last.pt`` (every epoch),
``best.pt`` (best validation score, by default the symmetric CD-L1 of the completions:
accuracy alone rewards collapsed predictions), ``log.csv`` (one row per epoch).

Distributed: under ``torchrun`` (``WORLD_SIZE`` > 1) the process group is set up
with NCCL on GPUs, gloo on CPU; each rank trains on its shard of the epoch's
permutation (``batch_size`` is per process), gradients are averaged by
DistributedDataParallel, validation sums are all-reduced, and rank 0 writes files.
"""

from __future__ import annotations

import csv
import io
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from ..errors import InputFileError, SpotlightsError
from ..geometry.rig import RigSpec
from .checkpoint import load_checkpoint, save_checkpoint
from .config import (
    SELECT_BY,
    DataConfig,
    TrainConfig,
    build_optimizer,
    build_scheduler,
    check_keys,
    data_config,
    train_config,
)
from .data import TorchCompletionDataset
from .models import build_model, load_config
from .models.base import CLIP_DEFAULT

LOG_COLUMNS = (
    "epoch",
    "lr",
    "train_loss",
    "val_loss",
    "val_accuracy",
    "val_completeness",
    "val_chamfer_l1",
    "val_n",
    "val_empty",
    "epoch_seconds",
    "samples_per_second",
    "global_step",
    "samples_seen",
    "wall_seconds",
    "val_threshold",
)
"""Columns of ``RUN/log.csv``; ``val_threshold`` (the hit-aware SA-Net's chosen p(hit) threshold) is
empty for the other models."""


def default_device() -> torch.device:
    """CUDA when available (this process's local rank under torchrun), else CPU."""
    if torch.cuda.is_available():
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))
    return torch.device("cpu")


def _epoch_seed(seed: int, epoch: int) -> int:
    return (int(seed) * 1_000_003 + int(epoch) * 7919 + 12345) % (2**63 - 1)


def _stream_indices(n: int, seed: int, start: int, count: int) -> list[int]:
    """Positions ``start .. start+count-1`` of an endless stream of shuffled passes over ``range(n)``.

    Pass ``p`` is a permutation drawn from a generator seeded by ``(seed, p)``, so every sample is
    seen once per pass, and the stream does not depend on where epochs begin or on resuming. Used
    when ``train.steps_per_epoch`` makes an epoch a fixed number of steps (a validation interval)
    rather than one pass over the training set.
    """
    out: list[int] = []
    pos = start
    while len(out) < count:
        p, k = divmod(pos, n)
        gen = torch.Generator().manual_seed(_epoch_seed(seed + 1_000_000_007, p))
        perm = torch.randperm(n, generator=gen)
        take = perm[k : k + (count - len(out))].tolist()
        out.extend(take)
        pos += len(take)
    return out


def _float_outputs(out: dict) -> dict:
    """Model outputs cast to float32 (losses and metrics run in fp32 whatever the autocast dtype)."""
    return {k: (v.float() if torch.is_tensor(v) and v.is_floating_point() else v) for k, v in out.items()}


def _collate(batch_list):
    return torch.utils.data.default_collate(batch_list)


def _to(batch: dict, device) -> dict:
    return {k: (v.to(device, non_blocking=True) if torch.is_tensor(v) else v) for k, v in batch.items()}


class _Dist:
    """Process-group facts; a no-op shell in a single process."""

    def __init__(self):
        self.world = int(os.environ.get("WORLD_SIZE", "1"))
        self.rank = int(os.environ.get("RANK", "0"))
        self.active = self.world > 1
        self.owned = False
        if self.active and not torch.distributed.is_initialized():
            backend = "nccl" if torch.cuda.is_available() else "gloo"
            if torch.cuda.is_available():
                torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", 0)))
            torch.distributed.init_process_group(backend=backend)
            self.owned = True

    @property
    def main(self) -> bool:
        return self.rank == 0

    def all_sum(self, values: list[float], device) -> list[float]:
        if not self.active:
            return values
        t = torch.tensor(values, dtype=torch.float64, device=device)
        torch.distributed.all_reduce(t)
        return t.tolist()

    def barrier(self):
        if self.active:
            torch.distributed.barrier()

    def close(self):
        if self.owned:
            torch.distributed.destroy_process_group()


def _write_csv(path: Path, history: list[dict]) -> None:
    from ..utils import atomic_output

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(LOG_COLUMNS), extrasaction="ignore")
    w.writeheader()
    for row in history:
        w.writerow(row)
    with atomic_output(path) as tmp:
        tmp.write_text(buf.getvalue())


def _write_yaml(path: Path, cfg: dict) -> None:
    import yaml

    from ..utils import atomic_output

    with atomic_output(path) as tmp:
        tmp.write_text(yaml.safe_dump(cfg, sort_keys=False))


@torch.no_grad()
def validate(
    model,
    dataset: TorchCompletionDataset,
    batch_size: int,
    device,
    gt_trees: dict,
    dist: _Dist | None = None,
    num_workers: int = 0,
    rays=None,
    precision: str = "fp32",
    thresholds=None,
) -> dict:
    """Validation loss and point metrics of the completions (SA-Net clipped at its default).

    Parameters
    ----------
    gt_trees : {model row: (L, 3) dense GT array or its NearestNeighbors}; arrays are
        replaced by their KD-tree on first use (so one tree per GT model per run).
    rays : a :class:`~spotlights.learning.rays.DirectionTable` for a box-targeted SA-Net (each
        sample decodes with its model's box); default: built from ``dataset.extents``.
    precision : ``"fp32"``, ``"bf16"`` or ``"fp16"``: autocast of the forward pass (the run's
        training precision); loss and metrics are computed in float32.
    thresholds : hit-aware SA-Net only: the p(hit) thresholds to score (default: the model's
        ``threshold_grid``, else its ``threshold``); the metrics of the one with the lowest
        CD-L1 are returned (ties: the first), with ``val_threshold`` and ``val_threshold_scan``.

    Returns
    -------
    {"val_loss": mean loss over samples,
     "val_accuracy": mean over samples of the one-sided CD prediction -> dense GT,
     "val_completeness": mean over samples of the one-sided CD dense GT -> prediction,
     "val_chamfer_l1": (accuracy + completeness) / 2, "val_n": samples,
     "val_empty": samples whose completion is empty (left out of the point metrics)}.
    Hit-aware models add ``val_threshold`` (the chosen threshold) and ``val_threshold_scan``
    ({threshold: {"accuracy", "completeness", "chamfer_l1", "empty"}}).
    With ``dist`` active, each rank evaluates a contiguous shard and the sums are all-reduced.
    """
    from ..geometry.distances import accuracy, combine_directions, completeness
    from ..geometry.neighbors import NearestNeighbors
    from .device import autocast
    from .rays import DirectionTable

    if rays is None and getattr(model, "needs_box", False):
        rays = DirectionTable(model.rig, dataset.extents)
    hit_aware = hasattr(model, "hit_probabilities")
    if hit_aware:
        grid = thresholds if thresholds is not None else (model.threshold_grid or (model.threshold,))
        grid = [float(t) for t in grid]
    else:
        grid = [None]
    active = dist is not None and dist.active
    world, rank = (dist.world, dist.rank) if active else (1, 0)
    n = len(dataset)
    lo, hi = n * rank // world, n * (rank + 1) // world
    subset = torch.utils.data.Subset(dataset, range(lo, hi))
    loader = DataLoader(subset, batch_size=batch_size, shuffle=False, num_workers=num_workers, collate_fn=_collate)
    model.eval()
    loss_sum = 0.0
    count = 0
    acc_sum, comp_sum, scored = [0.0] * len(grid), [0.0] * len(grid), [0] * len(grid)
    for batch in loader:
        batch = _to(batch, device)
        with autocast(precision, device):
            out = model(batch["partial"])
        out = _float_outputs(out)
        b = batch["partial"].shape[0]
        loss, _ = model.loss(out, batch, 1.0)
        loss_sum += float(loss) * b
        count += b
        dirs = rays.directions(batch["model"]) if rays is not None else None
        for j, t in enumerate(grid):
            if hit_aware:
                preds = model.outputs_to_points(out, CLIP_DEFAULT, dirs, threshold=t)
            else:
                preds = model.outputs_to_points(out, CLIP_DEFAULT, dirs)
            for p, m in zip(preds, batch["model"].tolist()):
                if len(p) == 0:
                    continue
                if m not in gt_trees:
                    raise SpotlightsError(f"no dense ground truth for model row {m}")
                tree = gt_trees[m]
                if not isinstance(tree, NearestNeighbors):
                    tree = gt_trees[m] = NearestNeighbors(tree)
                pts = p.detach().cpu().numpy()
                acc_sum[j] += accuracy(pts, tree)
                comp_sum[j] += completeness(pts, tree)
                scored[j] += 1
    sums = [loss_sum, float(count), *acc_sum, *comp_sum, *map(float, scored)]
    if active:
        sums = dist.all_sum(sums, device)
    k = len(grid)
    loss_sum, count = sums[0], sums[1]
    acc_sum, comp_sum, scored = sums[2 : 2 + k], sums[2 + k : 2 + 2 * k], sums[2 + 2 * k : 2 + 3 * k]
    scan = []
    for j in range(k):
        acc = acc_sum[j] / scored[j] if scored[j] else float("nan")
        comp = comp_sum[j] / scored[j] if scored[j] else float("nan")
        scan.append(
            {
                "accuracy": acc,
                "completeness": comp,
                "chamfer_l1": combine_directions(acc, comp, "mean"),
                "empty": int(count - scored[j]),
            }
        )
    # The chosen threshold: the lowest CD-L1 (the first on ties); NaN (every completion empty) never wins.
    finite = [j for j in range(k) if math.isfinite(scan[j]["chamfer_l1"])]
    best = min(finite, key=lambda j: scan[j]["chamfer_l1"]) if finite else 0
    row = scan[best]
    res = {
        "val_loss": loss_sum / count if count else float("nan"),
        "val_accuracy": row["accuracy"],
        "val_completeness": row["completeness"],
        "val_chamfer_l1": row["chamfer_l1"],
        "val_n": int(count),
        "val_empty": row["empty"],
    }
    if hit_aware:
        res["val_threshold"] = grid[best]
        res["val_threshold_scan"] = {f"{t:g}": v for t, v in zip(grid, scan)}
    return res


def _print_flush(msg: str) -> None:
    print(msg, flush=True)


def train(
    model_name: str,
    data,
    out_dir,
    config=None,
    overrides: dict | None = None,
    resume: bool = False,
    overwrite: bool = False,
    device=None,
    progress: bool = True,
    log=_print_flush,
    schedule=None,
    stop_after: int | None = None,
) -> dict:
    """Train one model on a completion dataset file.

    Parameters
    ----------
    model_name : registry key (sanet, pcn, foldingnet, topnet, atlasnet).
    data : HDF5 dataset file (splits train and val are used).
    out_dir : run folder (config.yaml, last.pt, best.pt, log.csv).
    config : optional user YAML overriding the packaged config.
    schedule : optional training schedule (packaged ``"cpu"`` / ``"paper"`` or a YAML file),
        applied between the packaged config and ``config``.
    overrides : nested dict applied last (e.g. ``{"train": {"epochs": 5}}``).
    resume : continue from ``out_dir/last.pt`` (its config is kept; ``train.epochs`` may be raised).
    overwrite : start afresh even if ``out_dir`` holds a run.
    device : torch device (default CUDA when available, else CPU).
    progress : show tqdm bars (rank 0 only).
    stop_after : run at most this many epochs in this call, then return (resume later with
        ``resume=True``); the schedule still spans ``train.epochs``. For time-boxed sessions.

    Returns
    -------
    dict: out_dir, last, best (paths), epochs (completed), history (list of rows), param_counts.
    """
    dist = _Dist()
    try:
        return _train(
            dist,
            model_name,
            data,
            Path(out_dir),
            config,
            overrides,
            resume,
            overwrite,
            device,
            progress,
            log,
            schedule,
            stop_after,
        )
    finally:
        dist.close()


@dataclass
class _Run:
    """What one training run holds between epochs (built by :func:`_prepare`)."""

    model_name: str
    data: object
    out_dir: Path
    cfg: dict
    dcfg: DataConfig
    tcfg: TrainConfig
    device: torch.device
    precision: str
    dist: _Dist
    train_set: TorchCompletionDataset
    val_set: TorchCompletionDataset
    rig: RigSpec | None
    gt_trees: dict
    val_rays: object
    model: torch.nn.Module
    net: torch.nn.Module
    opt: torch.optim.Optimizer
    sched: object
    scaler: object
    param_counts: dict
    start_epoch: int = 0
    global_step: int = 0
    history: list = field(default_factory=list)
    best: dict = field(default_factory=dict)
    wall: float = 0.0

    @property
    def last_path(self) -> Path:
        return self.out_dir / "last.pt"

    @property
    def best_path(self) -> Path:
        return self.out_dir / "best.pt"

    @property
    def n_train(self) -> int:
        return len(self.train_set)

    @property
    def shard(self) -> int:
        """Training samples per process and epoch (one pass split over the processes)."""
        return self.n_train // self.dist.world

    @property
    def drop_last(self) -> bool:
        return True if self.tcfg.steps_per_epoch is not None else self.shard >= self.tcfg.batch_size

    @property
    def steps_per_epoch(self) -> int:
        if self.tcfg.steps_per_epoch is not None:  # an epoch = a fixed number of steps (_stream_indices)
            return int(self.tcfg.steps_per_epoch)
        b = self.tcfg.batch_size  # an epoch = one pass over the training set
        return (self.shard // b) if self.drop_last else math.ceil(self.shard / b)

    @property
    def total_steps(self) -> int:
        return max(1, self.steps_per_epoch * self.tcfg.epochs)


def _resolve_config(model_name, out_dir: Path, config, overrides, resume, overwrite, schedule, dist, log):
    """The run's config and, when resuming, the state of ``last.pt`` (its config is kept; only
    ``train.epochs`` may change). Returns ``(cfg, state, extended)``."""
    last_path = out_dir / "last.pt"
    if not resume:
        if last_path.exists() and not overwrite:
            raise SpotlightsError(
                f"{out_dir}: holds a run already; pass --resume to continue it or --overwrite to start again"
            )
        return load_config(model_name, config, overrides, schedule=schedule), None, False
    if not last_path.exists():
        raise SpotlightsError(f"{last_path}: nothing to resume (no last.pt in the run folder)")
    state = load_checkpoint(last_path, expect_model=model_name)
    cfg = state["config"]
    check_keys(cfg, last_path, model_name)
    extended = False
    if overrides and "train" in overrides and "epochs" in overrides["train"]:
        extended = int(overrides["train"]["epochs"]) != int(cfg["train"]["epochs"])
        cfg["train"]["epochs"] = int(overrides["train"]["epochs"])
    ignored = [
        f"{sec}.{key}"
        for sec, vals in (overrides or {}).items()
        if isinstance(vals, dict)
        for key, val in vals.items()
        if (sec, key) != ("train", "epochs") and cfg.get(sec, {}).get(key) != val
    ]
    ignored += ["--config"] * (config is not None) + ["--schedule"] * (schedule is not None)
    if ignored and dist.main:
        log(
            f"warning: resuming keeps the run's own config; ignored: {', '.join(ignored)} "
            "(only --epochs may change; start a new run with --overwrite to change the rest)"
        )
    return cfg, state, extended


def _prepare(
    dist, model_name, data, out_dir: Path, config, overrides, resume, overwrite, device, log, schedule
) -> _Run:
    """Config, device, precision, datasets, model, optimizer and schedule of a run (restored from
    ``last.pt`` when resuming); writes ``config.yaml`` (rank 0)."""
    from .device import resolve_device, resolve_precision
    from .models import model_class
    from .rays import DirectionTable, rig_spec

    device = resolve_device(device) if device is not None else default_device()
    if dist.active and device.type == "cuda" and device.index is None:
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))  # one GPU per process
    cfg, state, extended = _resolve_config(
        model_name, out_dir, config, overrides, resume, overwrite, schedule, dist, log
    )
    dcfg, tcfg = data_config(cfg), train_config(cfg)
    precision = resolve_precision(tcfg.precision, device)

    wants_depths = model_class(model_name).target == "depths"
    rig_sel = dcfg.rig if wants_depths else False
    train_set = TorchCompletionDataset(
        data, "train", rig=rig_sel, max_views=dcfg.max_views, partials_in_memory=dcfg.partials_in_memory
    )
    val_set = TorchCompletionDataset(
        data, "val", rig=rig_sel, max_views=dcfg.val_max_views, partials_in_memory=dcfg.partials_in_memory
    )
    rig = rig_spec(train_set.rig) if wants_depths else None
    if state is not None and wants_depths and rig_spec(state.get("rig")) != rig:
        raise SpotlightsError(
            f"{out_dir / 'last.pt'}: was trained on rig {state.get('rig')}, the dataset serves {rig.to_dict()}"
        )
    val_rays = None
    if rig is not None and rig.needs_box:
        val_rays = DirectionTable(rig, val_set.extents)  # each validation sample decodes with its model's box

    torch.manual_seed(tcfg.seed)
    np.random.seed(tcfg.seed % (2**32))
    model = build_model(cfg, rig=rig).to(device)
    opt = build_optimizer(model.parameters(), tcfg)
    sched = build_scheduler(opt, tcfg)
    scaler = torch.amp.GradScaler(device.type) if precision == "fp16" else None
    run = _Run(
        model_name,
        data,
        out_dir,
        cfg,
        dcfg,
        tcfg,
        device,
        precision,
        dist,
        train_set,
        val_set,
        rig,
        val_set.gt_dense(),
        val_rays,
        model,
        model,
        opt,
        sched,
        scaler,
        model.param_counts(),
        best={"epoch": None, "select_by": tcfg.select_by, "value": float("inf")},
    )
    if state is not None:
        _restore(run, state, extended)
        if dist.main:
            log(f"resuming {model_name} from {run.last_path} after epoch {run.start_epoch}")
    if dist.active:
        run.net = torch.nn.parallel.DistributedDataParallel(
            model, device_ids=[device.index] if device.type == "cuda" else None
        )
    if dist.main:
        out_dir.mkdir(parents=True, exist_ok=True)
        _write_yaml(out_dir / "config.yaml", cfg)
        pc = run.param_counts
        log(
            f"{model_name}: {pc['total']:,} parameters (encoder {pc['encoder']:,}, decoder {pc['decoder']:,}); "
            f"{len(train_set)} train / {len(val_set)} val samples; device {device}; {dist.world} process(es)"
        )
        if precision != "fp32":
            log(f"{model_name}: training at {precision} (autocast forward, float32 weights, losses and metrics)")
    return run


def _restore(run: _Run, state: dict, extended: bool) -> None:
    """Load model, optimizer, schedule, scaler, counters, history and best from a ``last.pt`` state.

    Raises :class:`InputFileError` naming ``last.pt`` when the state does not fit (a damaged or
    foreign checkpoint is a bad file, not a crash)."""
    try:
        run.model.load_state_dict(state["model_state"])
        if state.get("hit_threshold") is not None:
            run.model.threshold = float(state["hit_threshold"]["value"])
        run.opt.load_state_dict(state["optimizer_state"])
        run.sched.load_state_dict(state["scheduler_state"])
        int(state["epoch"]), int(state["global_step"])
    except (RuntimeError, KeyError, TypeError, ValueError) as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0][:160]
        raise InputFileError(
            run.last_path, f"cannot resume from this checkpoint ({type(exc).__name__}: {first})"
        ) from None
    if extended:  # a new total length: the learning-rate schedule is recomputed from here on
        for group, base, lam in zip(run.opt.param_groups, run.sched.base_lrs, run.sched.lr_lambdas):
            group["lr"] = base * lam(run.sched.last_epoch)
    if run.scaler is not None and state.get("scaler_state"):
        run.scaler.load_state_dict(state["scaler_state"])
    run.start_epoch, run.global_step = int(state["epoch"]), int(state["global_step"])
    run.history, run.best = list(state.get("history", [])), dict(state.get("best", run.best))
    run.wall = float(run.history[-1].get("wall_seconds") or 0.0) if run.history else 0.0


def _epoch_loader(run: _Run, epoch: int) -> DataLoader:
    """This process's DataLoader for ``epoch``: a seeded permutation (one pass) or the next
    ``steps_per_epoch`` batches of the seeded stream of passes, sharded over the processes."""
    seed, dist, bs = run.tcfg.seed, run.dist, run.tcfg.batch_size
    if run.tcfg.steps_per_epoch is None:
        gen = torch.Generator().manual_seed(_epoch_seed(seed, epoch))
        perm = torch.randperm(run.n_train, generator=gen)[: run.shard * dist.world]
    else:
        per_epoch = run.steps_per_epoch * bs * dist.world
        perm = torch.tensor(_stream_indices(run.n_train, seed, epoch * per_epoch, per_epoch))
    indices = perm[dist.rank :: dist.world].tolist()
    workers = run.dcfg.num_workers
    return DataLoader(
        run.train_set,
        batch_size=bs,
        sampler=indices,
        num_workers=workers,
        drop_last=run.drop_last,
        collate_fn=_collate,
        pin_memory=run.device.type == "cuda",
        worker_init_fn=_worker_init if workers else None,
        generator=torch.Generator().manual_seed(_epoch_seed(seed, epoch)),
    )


def _train_epoch(run: _Run, loader: DataLoader, epoch: int, progress: bool) -> tuple[float, int]:
    """One epoch of optimizer steps (autocast forward, float32 loss, [scaled] backward, [clipped] step).

    Returns (sum of per-sample losses, samples) of this process."""
    from tqdm import tqdm

    from .device import autocast

    model, tcfg = run.model, run.tcfg
    run.net.train()
    loss_sum, seen = 0.0, 0
    bar = tqdm(
        loader,
        desc=f"{run.model_name} epoch {epoch + 1}/{tcfg.epochs}",
        unit="batch",
        leave=False,
        disable=not (progress and run.dist.main),
        dynamic_ncols=True,
    )
    for batch in bar:
        batch = _to(batch, run.device)
        with autocast(run.precision, run.device):
            out = run.net(batch["partial"])
        loss, _ = model.loss(_float_outputs(out), batch, run.global_step / run.total_steps)
        if not torch.isfinite(loss):
            raise SpotlightsError(
                f"{run.model_name}: the training loss became {float(loss)} at epoch {epoch + 1}, "
                f"step {run.global_step}; lower train.lr or set train.grad_clip"
            )
        _step(run, loss)
        run.global_step += 1
        b = batch["partial"].shape[0]
        loss_sum += float(loss.detach()) * b
        seen += b
        bar.set_postfix(loss=f"{loss_sum / seen:.5f}")
    bar.close()
    return loss_sum, seen


def _step(run: _Run, loss: torch.Tensor) -> None:
    """Backward and optimizer step; fp16 (CUDA without bf16) scales the loss and unscales before clipping."""
    opt, clip = run.opt, run.tcfg.grad_clip
    opt.zero_grad(set_to_none=True)
    if run.scaler is not None:
        run.scaler.scale(loss).backward()
        if clip:
            run.scaler.unscale_(opt)
            torch.nn.utils.clip_grad_norm_(run.model.parameters(), float(clip))
        run.scaler.step(opt)
        run.scaler.update()
    else:
        loss.backward()
        if clip:
            torch.nn.utils.clip_grad_norm_(run.model.parameters(), float(clip))
        opt.step()


def _save(run: _Run, epoch: int, val: dict, improved: bool) -> None:
    """Write ``best.pt`` (when improved, first), ``last.pt`` and ``log.csv`` (rank 0)."""
    payload = {
        "model_name": run.model_name,
        "config": run.cfg,
        "rig": None if run.rig is None else run.rig.to_dict(),
        "model_state": run.model.state_dict(),
        "optimizer_state": run.opt.state_dict(),
        "scheduler_state": run.sched.state_dict(),
        "epoch": epoch + 1,
        "global_step": run.global_step,
        "best": run.best,
        "history": run.history,
        "param_counts": run.param_counts,
        "precision": run.precision,
        **({"hit_threshold": _threshold_record(val)} if "val_threshold" in val else {}),
        **({"scaler_state": run.scaler.state_dict()} if run.scaler is not None else {}),
        "dataset": {
            "path": str(run.data),
            "rig": run.train_set.rig_name,
            "n_train": run.n_train,
            "n_val": len(run.val_set),
        },
    }
    # best.pt first: a kill between the two writes must not leave a last.pt that names
    # this epoch as best while best.pt still holds an older one.
    if improved:
        save_checkpoint(
            run.best_path,
            {k: v for k, v in payload.items() if k not in ("optimizer_state", "scheduler_state", "scaler_state")},
        )
    save_checkpoint(run.last_path, payload)
    _write_csv(run.out_dir / "log.csv", run.history)


def _train(
    dist,
    model_name,
    data,
    out_dir: Path,
    config,
    overrides,
    resume,
    overwrite,
    device,
    progress,
    log,
    schedule,
    stop_after,
):
    run = _prepare(dist, model_name, data, out_dir, config, overrides, resume, overwrite, device, log, schedule)
    tcfg = run.tcfg
    end_epoch = tcfg.epochs if stop_after is None else min(tcfg.epochs, run.start_epoch + max(int(stop_after), 0))
    for epoch in range(run.start_epoch, end_epoch):
        t0 = time.perf_counter()
        torch.manual_seed(_epoch_seed(tcfg.seed, epoch))
        loss_sum, seen = _train_epoch(run, _epoch_loader(run, epoch), epoch, progress)
        lr = run.opt.param_groups[0]["lr"]
        run.sched.step()
        train_sum, train_n = dist.all_sum([loss_sum, float(seen)], run.device)
        val = validate(
            run.model,
            run.val_set,
            tcfg.batch_size,
            run.device,
            run.gt_trees,
            dist,
            rays=run.val_rays,
            precision=run.precision,
        )
        dt = time.perf_counter() - t0
        run.wall += dt
        row = {
            "epoch": epoch + 1,
            "global_step": run.global_step,
            "samples_seen": run.global_step * tcfg.batch_size * dist.world,
            "lr": lr,
            "train_loss": train_sum / max(train_n, 1),
            **{k: v for k, v in val.items() if k != "val_threshold_scan"},
            "epoch_seconds": round(dt, 3),
            "samples_per_second": round(train_n / dt, 2) if dt > 0 else 0.0,
            "wall_seconds": round(run.wall, 3),
        }
        run.history.append(row)
        if "val_threshold" in val:  # hit-aware SA-Net: decode with the threshold chosen on validation
            run.model.threshold = float(val["val_threshold"])
        value, prev = val[SELECT_BY[tcfg.select_by]], run.best["value"]
        # The first epoch always gives a best.pt; later a finite value below the best so far.
        improved = run.best["epoch"] is None or (math.isfinite(value) and not (math.isfinite(prev) and value >= prev))
        if improved:
            run.best = {
                "epoch": epoch + 1,
                "select_by": tcfg.select_by,
                "value": value,
                "val_accuracy": val["val_accuracy"],
            }
            if "val_threshold" in val:
                run.best["hit_threshold"] = float(val["val_threshold"])
        if dist.main:
            _save(run, epoch, val, improved)
            log(
                f"{model_name} epoch {epoch + 1}/{tcfg.epochs}: train loss {row['train_loss']:.5f}, val loss "
                f"{row['val_loss']:.5f}, val accuracy {row['val_accuracy']:.5f}, completeness {row['val_completeness']:.5f}"
                + (f" at p(hit) >= {row['val_threshold']:g}" if "val_threshold" in row else "")
                + f"{' (best)' if improved else ''}, {dt:.1f} s"
            )
        dist.barrier()
    return {
        "out_dir": str(out_dir),
        "last": str(run.last_path),
        "best": str(run.best_path),
        "epochs": len(run.history),
        "history": run.history,
        "param_counts": run.param_counts,
    }


def _threshold_record(val: dict) -> dict:
    """The ``hit_threshold`` entry of a hit-aware SA-Net's checkpoint: the chosen p(hit) threshold and the
    validation scan it was chosen from (CD-L1, accuracy, completeness per grid value)."""
    return {
        "value": float(val["val_threshold"]),
        "chosen_on": "val",
        "criterion": "min val_chamfer_l1",
        "scan": val["val_threshold_scan"],
    }


def _worker_init(worker_id: int) -> None:
    """DataLoader worker: one torch thread (the main process does the math), fresh h5py handle on first read."""
    torch.set_num_threads(1)
