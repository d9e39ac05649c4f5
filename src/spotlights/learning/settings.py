"""The settings of one training run (:class:`TrainSettings`): ``spotlights train``'s options as one
object, each field declaring its option (:func:`spotlights.options.option`). This module imports no
torch (``spotlights --help`` reads these declarations)."""

from __future__ import annotations

import argparse
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ..options import (
    DEVICE_HELP,
    MAX_BATCH,
    SEED_HELP,
    batch_size_number,
    non_negative_int,
    option,
    positive_int,
    seed_number,
    settings_from_dict,
)
from .config import MAX_LR, learning_rate
from .registry import MODEL_NAMES

# The options that override one key of the config: config section -> (config key, option field).
CONFIG_OVERRIDES = {
    "train": (
        ("epochs", "epochs"),
        ("batch_size", "batch_size"),
        ("lr", "lr"),
        ("seed", "seed"),
        ("precision", "precision"),
        ("steps_per_epoch", "steps_per_epoch"),
        ("compile", "compile"),
    ),
    "data": (
        ("max_views", "max_views"),
        ("val_max_views", "val_max_views"),
        ("rig", "rig"),
        ("num_workers", "workers"),
    ),
}


@dataclass(frozen=True)
class TrainSettings:
    """Everything one training run is asked to do: ``spotlights train``'s options, named as the
    options (``--batch-size`` is ``batch_size``), plus ``overrides``.

    model : registry key (sanet, sanet-hit, pcn, foldingnet, topnet, atlasnet).
    data : HDF5 dataset file or the index ``.json`` of a sharded one (splits train and val are used).
    config : optional user YAML overriding the packaged config. schedule : optional training
        schedule (packaged ``"cpu"`` / ``"paper"`` or a YAML file), applied before ``config``.
    out : run folder (config.yaml, last.pt, best.pt, log.csv); None: ``runs/MODEL``.
    epochs, batch_size, lr (> 0), seed, precision, steps_per_epoch, compile : ``train.*`` keys of
        the config; max_views, val_max_views, rig, workers (``data.num_workers``) : ``data.*`` keys
        (:data:`CONFIG_OVERRIDES`); None keeps the config's value.
    device, threads : torch device (default CUDA when available, else CPU) and CPU threads.
    resume : continue from ``out/last.pt`` (its config is kept; ``epochs`` may be raised).
    overwrite : start afresh even if ``out`` holds a run (its ``last.pt``, ``best.pt`` and
        ``log.csv`` are removed first).
    stop_after : run at most this many epochs in this call, then return (resume later); the
        schedule still spans ``epochs``. allow_new_data : with ``resume``, continue even if
        ``data`` is not the dataset the run was trained on. quiet : no progress bars.
    overrides : nested dict applied after ``config`` and before the single-key options
        (e.g. ``{"train": {"epochs": 5}}``); not an option.
    """

    model: str = option(choices=MODEL_NAMES, help="which model to train")
    data: str | os.PathLike = option(
        metavar="FILE.h5|INDEX.json",
        help="dataset file (spotlights dataset build), or the index .json of a sharded dataset (--shard-size)",
    )
    config: str | os.PathLike | None = option(
        default=None, metavar="YAML", help="YAML overriding the packaged config (model/data/train sections)"
    )
    schedule: str | os.PathLike | None = option(
        default=None,
        metavar="NAME|YAML",
        help="training schedule applied before --config: 'cpu' (35-70 min per model on 2 cores), 'paper' (the paper-scale GPU run), or a schedule YAML",
    )
    out: str | os.PathLike | None = option(
        "--out",
        "-o",
        default=None,
        metavar="DIR",
        help="run folder (default runs/MODEL): config.yaml, last.pt, best.pt, log.csv",
    )
    epochs: int | None = option(
        default=None, type=positive_int, help="number of epochs (with --resume: raise it to train longer)"
    )
    batch_size: int | None = option(
        default=None, type=batch_size_number, help=f"batch size per process, 1..{MAX_BATCH}"
    )
    lr: float | None = option(
        default=None, type=learning_rate, help=f"learning rate, in (0, {MAX_LR:g}] (default: the config's)"
    )
    max_views: int | None = option(
        default=None, type=positive_int, metavar="V", help="use only views 0..V-1 of each training model"
    )
    val_max_views: int | None = option(default=None, type=positive_int, metavar="V", help="validation views per model")
    rig: str | None = option(
        default=None, help="SA-Net: rig group of the dataset to regress (default: the file's default rig)"
    )
    workers: int | None = option(
        default=None, type=non_negative_int, help="DataLoader worker processes (0: load in the main process)"
    )
    seed: int | None = option(
        default=None, type=seed_number, help=f"random seed, {SEED_HELP} (same seed + config = same weights)"
    )
    device: str | None = option(default=None, help=DEVICE_HELP)
    threads: int | None = option(default=None, type=positive_int, help="torch CPU threads (default: torch's)")
    precision: str | None = option(
        default=None,
        choices=("auto", "fp32", "bf16"),
        help="forward-pass precision: auto (default: bf16 where the CPU or GPU supports it, else fp32), fp32, or bf16 (fp16 with a gradient scaler on GPUs without bf16); weights, losses and metrics stay float32",
    )
    steps_per_epoch: int | None = option(
        default=None,
        type=positive_int,
        metavar="N",
        help="make an epoch N optimizer steps drawn from shuffled passes over the training set (a validation and checkpoint interval) instead of one full pass",
    )
    compile: bool | None = option(
        default=None,
        action=argparse.BooleanOptionalAction,
        help="run the training forward pass through torch.compile (--no-compile: eager; may change on --resume; 1.1-1.4x faster steps at bf16 on CPU after 1.3-2.5 min of compilation; docs/benchmarks.md)",
    )
    resume: bool = option(
        mutex="resume-or-overwrite",
        default=False,
        action="store_true",
        help="continue the run in --out from its last.pt",
    )
    overwrite: bool = option(
        mutex="resume-or-overwrite",
        default=False,
        action="store_true",
        help="start again even if --out holds a run (its last.pt, best.pt and log.csv are removed first)",
    )
    stop_after: int | None = option(
        default=None,
        type=positive_int,
        metavar="K",
        help="run at most K epochs now, then stop (continue later with --resume); the schedule spans --epochs",
    )
    allow_new_data: bool = option(
        default=False,
        action="store_true",
        help="with --resume: continue even if --data is not the dataset the run was trained on (refused by default)",
    )
    quiet: bool = option(default=False, quiet=True, help="no progress bars")
    overrides: dict | None = None

    @classmethod
    def from_dict(cls, d: Mapping, where: str | os.PathLike | None = None) -> TrainSettings:
        """Read settings by the one strict policy (:func:`spotlights.options.settings_from_dict`)."""
        return settings_from_dict(cls, d, where)

    @property
    def run_dir(self) -> Path:
        """The run folder: ``out``, or ``runs/MODEL``."""
        return Path(self.out if self.out is not None else f"runs/{self.model}")

    def config_overrides(self) -> dict | None:
        """``overrides`` with the single-key options that are set merged in (sections ``train``
        and ``data``); just ``overrides`` when none is set."""
        extra = {
            sec: {key: getattr(self, name) for key, name in keys if getattr(self, name) is not None}
            for sec, keys in CONFIG_OVERRIDES.items()
        }
        if not any(extra.values()):
            return self.overrides
        base = dict(self.overrides or {})
        return {**base, **{sec: {**(base.get(sec) or {}), **vals} for sec, vals in extra.items()}}
