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

This module is the loop (epochs, steps, saving); a run's preparation and state are
:mod:`.training_run`, its validation :mod:`.validation` (``validate`` is importable from here),
the process group :mod:`.process_group`.
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
from pathlib import Path

import torch
from torch.utils.data import DataLoader
from tqdm import tqdm

from ..errors import SpotlightsError
from ..locks import exclusive_lock
from ..options import check_threads
from ..outputs import atomic_output, output_folder
from ..timing import StageTimer
from .checkpoint import save_checkpoint
from .config import SELECT_BY
from .data import worker_batches
from .device import autocast, default_device
from .domain import LearnedDomain
from .process_group import ProcessGroup
from .settings import TrainSettings
from .training_run import RUN_STATE_FILES, TrainingRun, data_identity, prepare_run
from .validation import collate, float_outputs, to_device, validate, with_boxes

__all__ = ["LOG_COLUMNS", "TrainSettings", "default_device", "run_training", "train", "train_with", "validate"]

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


def _write_csv(path: Path, history: list[dict]) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(LOG_COLUMNS), extrasaction="ignore")
    w.writeheader()
    for row in history:
        w.writerow(row)
    with atomic_output(path) as tmp:
        tmp.write_text(buf.getvalue())


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
    allow_new_data: bool = False,
) -> dict:
    """Train one model on a completion dataset file: :func:`train_with` of the
    :class:`TrainSettings` these arguments name (see it for each one).

    Returns
    -------
    dict: out_dir, last, best (paths), epochs (completed), history (list of rows), param_counts.
    """
    settings = TrainSettings(
        model_name,
        data,
        config=config,
        schedule=schedule,
        out=out_dir,
        resume=resume,
        overwrite=overwrite,
        device=device,
        stop_after=stop_after,
        allow_new_data=allow_new_data,
        quiet=not progress,
        overrides=overrides,
    )
    return train_with(settings, log)


def run_training(settings: TrainSettings, log=_print_flush) -> dict:
    """``spotlights train``: set ``settings.threads`` torch CPU threads, then :func:`train_with`
    inside the run folder (``settings.run_dir``; a run that fails before writing anything leaves
    no empty folder). Returns :func:`train_with`'s dict."""
    if settings.threads:
        torch.set_num_threads(check_threads(settings.threads))
    with output_folder(settings.run_dir):
        return train_with(settings, log)


def train_with(settings: TrainSettings, log=_print_flush) -> dict:
    """Train one model as ``settings`` say (:class:`TrainSettings`; single process, or one rank
    of a torchrun job); ``log`` receives the per-epoch lines (rank 0).

    Returns
    -------
    dict: out_dir, last, best (paths), epochs (completed), history (list of rows), param_counts.
    """
    dist = ProcessGroup(settings.device)
    out_dir = settings.run_dir
    try:
        busy = f"{out_dir}: another 'spotlights train' is writing this run folder right now"
        with (
            output_folder(out_dir) if dist.main else contextlib.nullcontext(),
            exclusive_lock(out_dir / ".train.lock", busy, remove=True) if dist.main else contextlib.nullcontext(),
        ):
            before = _run_files(out_dir)
            old_config = _read_or_none(out_dir / "config.yaml") if dist.main else None
            try:
                return _train(dist, settings, log)
            except (OSError, SpotlightsError):
                # a write failed (a full disk), the data or the loss went wrong (NaN): a run with nothing to
                # resume from leaves nothing behind (output_folder then removes the folders it created). Only
                # the files this call wrote go: a wrong --data or "nothing to resume" keeps an existing run's,
                # and a config.yaml this call replaced is put back.
                if dist.main and not (out_dir / "last.pt").exists():
                    for name, stamp in _run_files(out_dir).items():
                        if before.get(name) == stamp:
                            continue
                        if name == "config.yaml" and old_config is not None:
                            with contextlib.suppress(OSError, SpotlightsError), atomic_output(out_dir / name) as tmp:
                                tmp.write_bytes(old_config)
                        else:
                            (out_dir / name).unlink(missing_ok=True)
                raise
    finally:
        dist.close()


def _read_or_none(path: Path) -> bytes | None:
    """The bytes of ``path``, or None when it cannot be read (missing)."""
    try:
        return path.read_bytes()
    except OSError:
        return None


def _run_files(out_dir: Path) -> dict[str, tuple[int, int, int]]:
    """``{name: (inode, size, mtime_ns)}`` of the run files (config.yaml and :data:`RUN_STATE_FILES`)
    present in ``out_dir``: what a failed call compares to find the files it wrote."""
    stamps = {}
    for name in ("config.yaml", *RUN_STATE_FILES):
        try:
            st = (out_dir / name).stat()
        except OSError:
            continue
        stamps[name] = (st.st_ino, st.st_size, st.st_mtime_ns)
    return stamps


def _epoch_loader(run: TrainingRun, epoch: int) -> DataLoader:
    """This process's DataLoader for ``epoch``: a seeded permutation (one pass) or the next
    ``steps_per_epoch`` batches of the seeded stream of passes, sharded over the processes."""
    seed, dist, bs = run.tcfg.seed, run.dist, run.tcfg.batch_size
    items = run.pass_items  # one pass: every item once, or K times (data.source_repeat)
    if run.tcfg.steps_per_epoch is None:
        gen = torch.Generator().manual_seed(_epoch_seed(seed, epoch))
        perm = torch.randperm(len(items), generator=gen)[: run.shard * dist.world]
    else:
        per_epoch = run.steps_per_epoch * bs * dist.world
        perm = torch.tensor(_stream_indices(len(items), seed, epoch * per_epoch, per_epoch))
    indices = items[perm[dist.rank :: dist.world].numpy()].tolist()
    workers = run.dcfg.num_workers
    return DataLoader(
        run.train_set,
        batch_size=bs,
        sampler=indices,
        num_workers=workers,
        drop_last=run.drop_last,
        collate_fn=collate,
        pin_memory=run.device.type == "cuda",
        worker_init_fn=_worker_init if workers else None,
        generator=torch.Generator().manual_seed(_epoch_seed(seed, epoch)),
    )


def _train_epoch(run: TrainingRun, loader: DataLoader, epoch: int, progress: bool) -> tuple[float, int]:
    """One epoch of optimizer steps (autocast forward, float32 loss, [scaled] backward, [clipped] step).

    Returns (sum of per-sample losses, samples) of this process."""
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
    for batch in worker_batches(bar):
        batch = with_boxes(to_device(batch, run.device), model, run.train_rays, run.train_set.sizes)
        with autocast(run.precision, run.device):
            out = run.net(*model.forward_inputs(batch, run.train_rays))
        loss, _ = model.loss(float_outputs(out), batch, run.global_step / run.total_steps)
        if not torch.isfinite(loss):
            bad = [
                k for k, v in batch.items() if torch.is_tensor(v) and v.is_floating_point() and not v.isfinite().all()
            ]
            cause = (
                f"the batch's {', '.join(sorted(bad))} hold NaN or infinite values: check the dataset {run.data}"
                if bad
                else "lower train.lr or set train.grad_clip"
            )
            raise SpotlightsError(
                f"{run.model_name}: the training loss became {float(loss.detach())} at epoch {epoch + 1}, "
                f"step {run.global_step}; {cause}"
            )
        _step(run, loss)
        run.global_step += 1
        b = batch["partial"].shape[0]
        loss_sum += float(loss.detach()) * b
        seen += b
        bar.set_postfix(loss=f"{loss_sum / seen:.5f}")
    bar.close()
    return loss_sum, seen


def _step(run: TrainingRun, loss: torch.Tensor) -> None:
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


def _save(run: TrainingRun, epoch: int, val: dict, improved: bool) -> None:
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
            "identity": data_identity(run.train_set.info),
            "rig": run.train_set.rig_name,
            "n_train": run.n_train,
            "n_val": len(run.val_set),
        },
        **({"domain": domain.to_dict()} if (domain := _learned_domain(run)) is not None else {}),
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


def _train(dist: ProcessGroup, settings: TrainSettings, log) -> dict:
    run = prepare_run(dist, settings, log)
    tcfg = run.tcfg
    stop_after, model_name, progress = settings.stop_after, settings.model, not settings.quiet
    end_epoch = tcfg.epochs if stop_after is None else min(tcfg.epochs, run.start_epoch + max(int(stop_after), 0))
    for epoch in range(run.start_epoch, end_epoch):
        timer = StageTimer()
        with timer("epoch"):
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
        dt = timer.seconds["epoch"]
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
        "out_dir": str(settings.run_dir),
        "last": str(run.last_path),
        "best": str(run.best_path),
        "epochs": len(run.history),
        "history": run.history,
        "param_counts": run.param_counts,
    }


def _learned_domain(run: TrainingRun) -> LearnedDomain | None:
    """The classes and box sizes of the train split (None for a file without /models/size)."""
    ts = run.train_set
    if ts.sizes is None:
        return None
    rows = ts.model_rows
    return LearnedDomain.from_training_set(
        ts.info.categories[rows],
        ts.sizes[rows],
        source=f"{Path(str(run.data)).name}, train split ({len(rows)} models)",
        classes=ts.classes[rows] if ts.has_stored_classes else None,
    )


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
