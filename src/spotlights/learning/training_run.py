"""The state of one training run and its preparation: config, device, datasets, model, optimizer, schedule.

:func:`prepare_run` builds a :class:`TrainingRun` (restored from ``last.pt`` when resuming) that the
loop of :mod:`spotlights.learning.train` carries from epoch to epoch.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import yaml

from ..data.shard_index import without_extra_rigs
from ..errors import InputFileError, ParameterError, SpotlightsError
from ..geometry.rig import RigSpec
from ..outputs import atomic_output
from .checkpoint import load_checkpoint
from .config import DataConfig, TrainConfig, build_optimizer, build_scheduler, check_keys, data_config, train_config
from .data import TorchCompletionDataset
from .device import default_device, resolve_device, resolve_precision
from .models import build_model, load_config, model_class
from .process_group import ProcessGroup
from .rays import DirectionTable, rig_spec
from .settings import TrainSettings


@dataclass
class TrainingRun:
    """What one training run holds between epochs (built by :func:`prepare_run`).

    ``dcfg``, ``tcfg`` (the checked sections of ``cfg``), ``gt_trees`` (the validation models'
    dense ground truth), ``net`` (the module the training forward runs: ``model``, wrapped
    for DDP or ``torch.compile`` by :func:`prepare_run`) and ``param_counts`` follow from the
    fields given."""

    settings: TrainSettings
    cfg: dict
    device: torch.device
    precision: str
    dist: ProcessGroup
    train_set: TorchCompletionDataset
    val_set: TorchCompletionDataset
    rig: RigSpec | None
    val_rays: object
    model: torch.nn.Module
    opt: torch.optim.Optimizer
    sched: object
    scaler: object
    train_rays: object = None
    dcfg: DataConfig = field(init=False)
    tcfg: TrainConfig = field(init=False)
    gt_trees: dict = field(init=False)
    net: torch.nn.Module = field(init=False)
    param_counts: dict = field(init=False)
    pass_items: np.ndarray = field(init=False)  # (P,) int64 the items of one pass (repeated_items)
    start_epoch: int = 0
    global_step: int = 0
    history: list = field(default_factory=list)
    best: dict = field(default_factory=dict)
    wall: float = 0.0

    def __post_init__(self) -> None:
        self.dcfg, self.tcfg = data_config(self.cfg), train_config(self.cfg)
        self.pass_items = repeated_items(self.train_set, self.dcfg.source_repeat)
        self.gt_trees = self.val_set.gt_dense()
        self.net = self.model
        self.param_counts = self.model.param_counts()
        self.best = self.best or {"epoch": None, "select_by": self.tcfg.select_by, "value": float("inf")}

    @property
    def model_name(self) -> str:
        """The registry key of the model trained (``settings.model``)."""
        return self.settings.model

    @property
    def data(self) -> str | os.PathLike:
        """The dataset file or shard index trained on (``settings.data``)."""
        return self.settings.data

    @property
    def out_dir(self) -> Path:
        """The run folder (``settings.run_dir``)."""
        return self.settings.run_dir

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
        return len(self.pass_items) // self.dist.world

    @property
    def drop_last(self) -> bool:
        return True if self.tcfg.steps_per_epoch is not None else self.shard >= self.tcfg.batch_size

    @property
    def steps_per_epoch(self) -> int:
        if self.tcfg.steps_per_epoch is not None:  # an epoch = a fixed number of steps (train._stream_indices)
            return int(self.tcfg.steps_per_epoch)
        b = self.tcfg.batch_size  # an epoch = one pass over the training set
        return (self.shard // b) if self.drop_last else math.ceil(self.shard / b)

    @property
    def total_steps(self) -> int:
        return max(1, self.steps_per_epoch * self.tcfg.epochs)


RESUME_KEYS = (("train", "compile"),)
"""Config keys that say how a run executes, not what it learns: a resumed run takes them from the command line."""


RUN_STATE_FILES = ("last.pt", "best.pt", "log.csv")
"""The files of a run's progress (``--overwrite`` removes them before a fresh start)."""


def training_rays(model, rig, train_set):
    """The training batches' ray table, or None: a
    :class:`~spotlights.learning.rays.DirectionTable` over ``train_set``'s boxes (``train_set.extents``) when
    ``rig`` (the dataset's :class:`~spotlights.geometry.rig.RigSpec`, or None for point models) is box-targeted
    and ``model`` needs each sample's rays in training: its forward looks along them (``uses_evidence``) or its
    loss scores each ray's point against the box (``box_weight > 0``). One owner for the training loop and the
    GPU recipe's step-time probe (scripts/gpu_train.py)."""
    if rig is None or not rig.needs_box:
        return None
    if getattr(model, "uses_evidence", False) or getattr(model, "box_weight", 0.0):
        return DirectionTable(rig, train_set.extents)
    return None


def resolve_run_config(
    model_name: str, out_dir: Path, config, overrides, resume: bool, overwrite: bool, schedule, dist, log
) -> tuple[dict, dict | None, bool]:
    """:func:`run_config` of these :class:`TrainSettings` fields (the positional form)."""
    settings = TrainSettings(
        model_name,
        "",
        out=out_dir,
        config=config,
        schedule=schedule,
        overrides=overrides,
        resume=resume,
        overwrite=overwrite,
    )
    return run_config(settings, dist, log)


def run_config(settings: TrainSettings, dist: ProcessGroup, log) -> tuple[dict, dict | None, bool]:
    """The run's config and, when resuming, the state of ``last.pt`` (its config is kept; only
    ``train.epochs`` and the execution keys of :data:`RESUME_KEYS` may change). Returns ``(cfg, state, extended)``."""
    model_name, out_dir, config, schedule = settings.model, settings.run_dir, settings.config, settings.schedule
    overrides, resume, overwrite = settings.config_overrides(), settings.resume, settings.overwrite
    last_path = out_dir / "last.pt"
    if not resume:
        if last_path.exists() and not overwrite:
            raise SpotlightsError(
                f"{out_dir}: holds a run already; pass --resume to continue it or --overwrite to start again"
            )
        cfg = load_config(model_name, config, overrides, schedule=schedule)
        return cfg, None, False
    if not last_path.exists():
        raise SpotlightsError(f"{last_path}: nothing to resume (no last.pt in the run folder)")
    state = load_checkpoint(last_path, expect_model=model_name)
    cfg = state["config"]
    check_keys(cfg, last_path, model_name)
    extended = False
    if overrides and "train" in overrides and "epochs" in overrides["train"]:
        extended = int(overrides["train"]["epochs"]) != int(cfg["train"]["epochs"])
        cfg["train"]["epochs"] = int(overrides["train"]["epochs"])
    for sec, key in RESUME_KEYS:
        if key in ((overrides or {}).get(sec) or {}):
            cfg.setdefault(sec, {})[key] = overrides[sec][key]
    ignored = [
        f"{sec}.{key}"
        for sec, vals in (overrides or {}).items()
        if isinstance(vals, dict)
        for key, val in vals.items()
        if (sec, key) != ("train", "epochs") and cfg.get(sec, {}).get(key) != val  # RESUME_KEYS were taken above
    ]
    ignored += ["--config"] * (config is not None) + ["--schedule"] * (schedule is not None)
    if ignored and dist.main:
        log(
            f"warning: resuming keeps the run's own config; ignored: {', '.join(ignored)} "
            "(only --epochs and --compile may change; start a new run with --overwrite to change the rest)"
        )
    return cfg, state, extended


def data_identity(info) -> str:
    """A digest (hex str) of the data a run learns from: the models (names and splits), the number
    of samples, the build's seed and config (without ``extra_rigs``, which ``add-rig`` changes) of
    a dataset's ``info`` (``TorchCompletionDataset.info``). A copy or a rebuild of a dataset has
    the same digest wherever it lies; another dataset has another."""
    import hashlib
    import json

    key = {
        "names": [str(x) for x in info.names],
        "splits": [str(x) for x in info.splits],
        "n_samples": int(len(info.sample_model)),
        "seed": str(info.attrs.get("seed")),
        "config": without_extra_rigs(info.attrs.get("config_json")),
    }
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()


def check_same_data(state: dict, last_path: Path, data, identity: str) -> None:
    """Refuse to resume a run on other data than it was trained on (``--allow-new-data`` skips
    this). Checkpoints without a data digest (older ones) compare the dataset's path."""
    recorded = state.get("dataset") if isinstance(state.get("dataset"), dict) else {}
    if recorded.get("identity") is not None:
        same = recorded["identity"] == identity
    elif recorded.get("path"):
        same = os.path.abspath(str(recorded["path"])) == os.path.abspath(os.fspath(data))
    else:
        return
    if not same:
        raise InputFileError(
            last_path,
            f"was trained on {recorded.get('path')}, not on --data {data} (other models, splits or "
            "samples); pass --allow-new-data to continue on it anyway, or train a new run",
        )


def prepare_run(dist: ProcessGroup, settings: TrainSettings, log) -> TrainingRun:
    """Config, device, precision, datasets, model, optimizer and schedule of a run (restored from
    ``last.pt`` when resuming; a resume on other data than the run's is refused unless
    ``settings.allow_new_data``); writes ``config.yaml`` (rank 0)."""
    model_name, data = settings.model, settings.data
    device = _run_device(dist, settings.device)
    cfg, state, extended = run_config(settings, dist, log)
    dcfg, tcfg = data_config(cfg), train_config(cfg)
    precision = resolve_precision(tcfg.precision, device)

    wants_depths = model_class(model_name).target == "depths"
    train_set, val_set = _datasets(data, cfg, dcfg, wants_depths)
    rig = train_set.rig if wants_depths else None  # the dataset's RigSpec
    if state is not None:
        _check_resumed_data(settings, state, train_set, rig, wants_depths)
    val_rays = None
    if rig is not None and rig.needs_box:
        val_rays = DirectionTable(rig, val_set.extents)  # each validation sample decodes with its model's box
    _check_sensor_origins(model_name, train_set, val_set)

    torch.manual_seed(tcfg.seed)
    np.random.seed(tcfg.seed % (2**32))
    model = build_model(cfg, rig=rig).to(device)
    train_rays = training_rays(model, rig, train_set)
    init = (cfg.get("model") or {}).get("init")
    if state is None and init:
        init_from_checkpoint(model, init)
        if dist.main:
            log(f"{model_name}: weights initialised from {init}")
    opt = build_optimizer(model.parameters(), tcfg)
    sched = build_scheduler(opt, tcfg)
    scaler = torch.amp.GradScaler(device.type) if precision == "fp16" else None
    run = TrainingRun(
        settings,
        cfg,
        device,
        precision,
        dist,
        train_set,
        val_set,
        rig,
        val_rays,
        model,
        opt,
        sched,
        scaler,
        train_rays=train_rays,
    )
    if state is not None:
        restore_run(run, state, extended)
        if dist.main:
            log(f"resuming {model_name} from {run.last_path} after epoch {run.start_epoch}")
    if dist.active:
        run.net = torch.nn.parallel.DistributedDataParallel(
            model, device_ids=[device.index] if device.type == "cuda" else None
        )
    if tcfg.compile:  # the training forward only; validation and checkpoints use the eager model
        run.net = torch.compile(run.net)
    if dist.main:
        _start_run_folder(run, fresh=state is None, log=log)
    return run


def _run_device(dist: ProcessGroup, device) -> torch.device:
    """The run's device: ``device`` (a name or None: the default), one GPU per process under DDP."""
    device = resolve_device(device) if device is not None else default_device()
    if dist.active and device.type == "cuda" and device.index is None:
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))  # one GPU per process
    return device


def _datasets(data, cfg: dict, dcfg: DataConfig, wants_depths: bool):
    """The (train, val) :class:`TorchCompletionDataset` of ``data`` for the run's data config (with rays for a
    model whose target is depths; the class vocabulary of ``cfg``'s model)."""
    rig_sel = dcfg.rig if wants_depths else False
    vocab = ((cfg.get("model") or {}).get("args") or {}).get("classes")

    def split(name: str, max_views) -> TorchCompletionDataset:
        return TorchCompletionDataset(
            data,
            name,
            rig=rig_sel,
            max_views=max_views,
            partials_in_memory=dcfg.partials_in_memory,
            class_vocab=vocab,
            only_classes=dcfg.classes,
        )

    train_set, val_set = split("train", dcfg.max_views), split("val", dcfg.val_max_views)
    return train_set, val_set


def _check_resumed_data(
    settings: TrainSettings, state: dict, train_set: TorchCompletionDataset, rig, wants_depths: bool
) -> None:
    """Refuse to resume a run (``state``: its ``last.pt``) on other data (unless ``settings.allow_new_data``) or,
    for a model that learns depths (``wants_depths``), on another rig (``rig``: the dataset's) than it was trained on."""
    out_dir = settings.run_dir
    if not settings.allow_new_data:
        check_same_data(state, out_dir / "last.pt", settings.data, data_identity(train_set.info))
    if wants_depths and rig_spec(state.get("rig")) != rig:
        raise SpotlightsError(
            f"{out_dir / 'last.pt'}: was trained on rig {state.get('rig')}, the dataset serves {rig.to_dict()}"
        )


def _check_sensor_origins(model_name: str, train_set: TorchCompletionDataset, val_set: TorchCompletionDataset):
    """Refuse datasets without each sample's sensor origin for a model that reads free space."""
    if getattr(model_class(model_name), "uses_evidence", False):
        if not (train_set.has_sensor_origin and val_set.has_sensor_origin):
            raise InputFileError(
                train_set.path,
                f"has no sensor origin per sample (/samples/sensor_to_unit), which {model_name} needs; "
                "rebuild the dataset with `spotlights dataset build`",
            )


def _start_run_folder(run: TrainingRun, fresh: bool, log) -> None:
    """Rank 0's start of the run folder: the old run's state files removed (a fresh start with ``overwrite``),
    ``config.yaml`` written, the model's size and the run's data and device logged."""
    settings, out_dir, model_name = run.settings, run.settings.run_dir, run.settings.model
    out_dir.mkdir(parents=True, exist_ok=True)
    if settings.overwrite and fresh:
        # the old run's state goes now, once the data and the model are found sound (a mistyped --data keeps
        # it), and not at the new run's first save: a fresh start stopped before its first interval must not
        # leave the old last.pt beside the new config.yaml (a --resume would then continue the old run)
        for name in RUN_STATE_FILES:
            (out_dir / name).unlink(missing_ok=True)
    _write_yaml(out_dir / "config.yaml", run.cfg)
    pc = run.param_counts
    log(
        f"{model_name}: {pc['total']:,} parameters (encoder {pc['encoder']:,}, decoder {pc['decoder']:,}); "
        f"{len(run.train_set)} train / {len(run.val_set)} val samples; device {run.device}; {run.dist.world} process(es)"
    )
    if len(run.pass_items) != len(run.train_set):
        repeats = ", ".join(f"{source} x{k}" for source, k in run.dcfg.source_repeat)
        log(
            f"{model_name}: a pass over the training set is {len(run.pass_items)} samples (data.source_repeat: {repeats})"
        )
    if run.precision != "fp32":
        log(f"{model_name}: training at {run.precision} (autocast forward, float32 weights, losses and metrics)")


def repeated_items(train_set, source_repeat) -> np.ndarray:
    """(P,) int64 item indices of ``train_set`` for one pass: ``arange(len(train_set))``, with every item of a
    model whose source ``source_repeat`` (``((source, K), ...)``, config ``data.source_repeat``) names repeated
    K times in place. A named source the training split lacks is a :class:`ParameterError` naming the split's
    sources."""
    n = len(train_set)
    if not source_repeat:
        return np.arange(n, dtype=np.int64)
    item_sources = train_set.sources[train_set.sample_models]
    present = set(item_sources.tolist())
    reps = np.ones(n, dtype=np.int64)
    for source, k in source_repeat:
        if source not in present:
            known = ", ".join(sorted(s for s in present if s)) or "none recorded"
            raise ParameterError(
                f"data.source_repeat names source {source!r}, which no training model has (sources: {known})"
            )
        reps[item_sources == source] = k
    return np.repeat(np.arange(n, dtype=np.int64), reps)


def init_from_checkpoint(model: torch.nn.Module, path) -> None:
    """Load a checkpoint's weights into a new run's ``model`` (config ``model.init``, a fine-tune).

    Every weight of the checkpoint must fit; the model's parameters it lacks must be new ones that start
    neutral (a class embedding or class templates, zero-initialised), so the model starts as the checkpoint's. Its hit threshold
    is taken too. Raises :class:`InputFileError` naming the checkpoint otherwise."""
    ckpt = load_checkpoint(path)
    try:
        state = ckpt["model_state"]
        if hasattr(model, "init_state"):  # e.g. a plain decoder's weights for a per-viewpoint decoder
            state = model.init_state(state)
        missing, unexpected = model.load_state_dict(state, strict=False)
    except (RuntimeError, ValueError) as exc:
        first = (str(exc).splitlines() or [""])[0][:160]
        raise InputFileError(ckpt["path"], f"its weights do not fit the model of this run ({first})") from None
    bad = [k for k in missing if not k.startswith(("class_embedding.", "class_template."))] + list(unexpected)
    if bad:
        raise InputFileError(ckpt["path"], f"its weights do not fit the model of this run ({', '.join(bad[:3])})")
    chosen = ckpt.get("hit_threshold")
    if chosen is not None and hasattr(model, "threshold"):
        model.threshold = float(chosen["value"] if isinstance(chosen, dict) else chosen)


def restore_run(run: TrainingRun, state: dict, extended: bool) -> None:
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
    except Exception as exc:  # noqa: BLE001 - whatever does not fit is the file's fault
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


def _write_yaml(path: Path, cfg: dict) -> None:
    with atomic_output(path) as tmp:
        tmp.write_text(yaml.safe_dump(cfg, sort_keys=False))
