"""Training configuration: the schema of ``model`` / ``data`` / ``train``, checked before torch sees it.

A config is the mapping :func:`spotlights.learning.models.load_config` merges (packaged defaults
<- schedule <- user YAML <- command-line overrides) and every checkpoint stores. This module
owns what it may contain:

* :class:`DataConfig` and :class:`TrainConfig` (dataclasses): the keys of the ``data`` and
  ``train`` sections, their types and ranges; ``model.args`` are checked against the model
  class's constructor;
* an unknown key anywhere (a typo such as ``epoch:``) is an error naming the key, the file it
  came from and the closest known key;
* the optimizer and the learning-rate schedule are built from config, ``type`` + arguments,
  through two small registries (:data:`OPTIMIZERS`, :data:`SCHEDULES`).

Configs written before this module (checkpoints of earlier versions, the shipped SA-Net) hold a
subset of these keys and load unchanged; missing keys take the defaults below.
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ..errors import InputFileError, ParameterError
from ..options import check_batch_size, check_seed, did_you_mean, number_type
from .registry import MODEL_REGISTRY, model_class

SECTIONS = ("model", "data", "train")
MODEL_KEYS = ("name", "args", "mirror", "init")
"""``model.init``: a checkpoint whose weights a new run starts from (a fine-tune; parameters it lacks, such as a
new class embedding, keep their initialisation)."""


@dataclass(frozen=True)
class DataConfig:
    """The ``data`` section: what the model is trained and validated on.

    rig : rig group of the dataset whose depths SA-Nets regress (None: the file's default rig).
    max_views : training views per model (views 0..V-1; None = all).
    val_max_views : validation views per model (None = all).
    num_workers : DataLoader worker processes (0: load in the main process).
    partials_in_memory : read a split's partial scans into memory once (else lazily per sample).
    classes : train and validate on these classes' models only (a class family's model, e.g. ``[trailer]``);
        None: every model.
    source_repeat : ``{source: K}``: every training sample of a model from mesh source ``source`` (the
        dataset's ``/models/source``, e.g. ``apolloscape-cars``) comes K times in each pass (K >= 1, at most
        :data:`MAX_SOURCE_REPEAT`), so a small source keeps its weight beside a large procedural one; stored as
        sorted ``(source, K)`` pairs. None: every sample once.
    """

    rig: str | None = None
    max_views: int | None = None
    val_max_views: int | None = 200
    num_workers: int = 0
    partials_in_memory: bool = True
    classes: tuple | None = None
    source_repeat: tuple | None = None


MAX_SOURCE_REPEAT = 100


@dataclass(frozen=True)
class TrainConfig:
    """The ``train`` section.

    epochs : number of epochs (validation intervals with ``steps_per_epoch``); >= 0.
    batch_size : samples per step and process; >= 1.
    optimizer : a registered optimizer type (``adam``, ``adamw``, ``sgd``) or a mapping
        ``{type: NAME, ARG: VALUE, ...}`` with the optimizer's other arguments (betas, eps,
        momentum, ...); the learning rate and weight decay are ``lr`` and ``weight_decay``.
    lr : learning rate (> 0). weight_decay : >= 0.
    lr_schedule : ``{type: NAME, ARG: VALUE}`` (``kind`` is accepted for ``type``): ``constant``,
        ``cosine`` (``min_factor``), ``step`` (``every``, ``gamma``); stepped once per epoch.
    grad_clip : max gradient norm (None: no clipping).
    seed : random seed (same seed + config = same weights).
    precision : ``auto``, ``fp32`` or ``bf16`` (see :mod:`spotlights.learning.device`); the packaged
        configs say ``auto``, a config without the key (older checkpoints) means ``fp32``.
    steps_per_epoch : None (an epoch is one pass) or N steps per epoch (>= 1).
    select_by : ``chamfer_l1``, ``accuracy`` or ``loss``: the validation score ``best.pt`` minimises.
    compile : run the training forward pass through ``torch.compile`` (default false). Measured on
        the 2-core CPU at bf16 (docs/benchmarks.md): SA-Net 1.38x, PCN 1.30x, the hit-aware SA-Net
        on 16,384 rays (9.57M) 1.13x faster per step, after 1.3-2.5 minutes of compilation; fp32
        gains 3-13%.
        Weights and checkpoints are those of the eager model; results differ from an eager run
        in the last bits (fused kernels), so a compiled run is reproducible with itself only.
    """

    epochs: int = 40
    batch_size: int = 32
    optimizer: Any = "adam"
    lr: float = 5.0e-4
    weight_decay: float = 0.0
    lr_schedule: dict = field(default_factory=lambda: {"kind": "cosine", "min_factor": 0.01})
    grad_clip: float | None = None
    seed: int = 0
    precision: str = "fp32"  # a config without the key (written before --precision existed) trained at fp32
    steps_per_epoch: int | None = None
    select_by: str = "chamfer_l1"
    compile: bool = False


MAX_LR = 10.0
"""The largest learning rate (``train.lr``, ``train --lr``): the packaged configs train at 5e-4 to 1e-3 and SGD
is run at up to about 0.1; 100 times that is far past any rate that trains. 1e300 failed inside the optimizer
("value cannot be converted to type float without overflow") after the datasets were loaded."""

learning_rate = number_type(float, lambda v: 0.0 < v <= MAX_LR, f"a learning rate in (0, {MAX_LR:g}]")
"""argparse type: a learning rate, (0, :data:`MAX_LR`] (``train --lr``)."""

MAX_WIDTH = 16384
"""The widest layer ``model.args`` may ask for (``code_size``, ``hidden``, ``encoder_widths``, ``dim``, ...):
16 times the packaged models' widest (1024). One 16384 x 16384 float32 layer is already 1 GiB of weights (4 GiB
with its gradient and Adam's two moments)."""

MAX_MODEL_POINTS = 2**18
"""The most points (or grid cells, tree nodes, neighbours) a count of ``model.args`` may ask for (``num_coarse``,
``n_start``, ``grid``, ``degrees``, ``up_factors``, ...; a list's product): 16 times the 16,384 points the packaged
point decoders output; the Chamfer loss compares every output point with every ground-truth point."""

MAX_LAYERS = 64
"""The longest list of layer widths of ``model.args`` (the packaged models have 2 or 3)."""

MODEL_WIDTH_ARGS = (
    "code_size",
    "seed_code",
    "dim",
    "candidate_width",
    "node_features",
    "attn_hidden",
    "encoder_widths",
    "hidden",
    "coarse_hidden",
    "folding_hidden",
    "root_hidden",
    "local_hidden",
)
"""``model.args`` that are layer widths (a whole number or a list of them, each in 1..:data:`MAX_WIDTH`)."""

MODEL_COUNT_ARGS = (
    "num_coarse",
    "grid_size",
    "n_patches",
    "n_seeds",
    "n_start",
    "k",
    "near_cells",
    "carve_cells",
    "carve_samples",
    "grid",
    "patch_grid",
    "degrees",
    "up_factors",
)
"""``model.args`` that count points, grid cells or neighbours (a whole number, or a list whose product is, in
1..:data:`MAX_MODEL_POINTS`)."""


def check_model_args(args: dict, source=None) -> None:
    """Raise an error naming the key and its range when a size of ``model.args`` (:data:`MODEL_WIDTH_ARGS`,
    :data:`MODEL_COUNT_ARGS`) is not a whole number (or list of them) in its range: 0 or -5 failed deep in torch,
    10^9 allocated for minutes."""
    for key, value in args.items():
        if key in MODEL_WIDTH_ARGS:
            hi, what = MAX_WIDTH, "a layer width"
        elif key in MODEL_COUNT_ARGS:
            hi, what = MAX_MODEL_POINTS, "a count of points"
        else:
            continue
        if value is None and key == "attn_hidden":  # null: the model's default width
            continue
        items = value if isinstance(value, (list, tuple)) else [value]
        ok = len(items) <= MAX_LAYERS and all(
            isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= hi for v in items
        )
        if ok and key in MODEL_COUNT_ARGS and math.prod(items) > hi:
            ok = False
        if not ok:
            form = "a whole number" if not isinstance(value, (list, tuple)) else "a list of whole numbers"
            extra = " (and their product)" if key in MODEL_COUNT_ARGS and isinstance(value, (list, tuple)) else ""
            raise _fail(source, f"model.args.{key} must be {form} in 1..{hi}{extra}, {what}; got {value!r}")


SELECT_BY = {"chamfer_l1": "val_chamfer_l1", "accuracy": "val_accuracy", "loss": "val_loss"}
"""``train.select_by`` -> the validation column ``best.pt`` minimises."""


# --- optimizers and schedules -------------------------------------------------------------


def _adam(params, lr, weight_decay, **kw):
    import torch

    return torch.optim.Adam(params, lr=lr, weight_decay=weight_decay, **kw)


def _adamw(params, lr, weight_decay, **kw):
    import torch

    return torch.optim.AdamW(params, lr=lr, weight_decay=weight_decay, **kw)


def _sgd(params, lr, weight_decay, momentum=0.9, **kw):
    import torch

    return torch.optim.SGD(params, lr=lr, momentum=momentum, weight_decay=weight_decay, **kw)


OPTIMIZERS = {
    "adam": ("torch.optim.Adam", _adam),
    "adamw": ("torch.optim.AdamW", _adamw),
    "sgd": ("torch.optim.SGD", _sgd),
}
"""Optimizer type -> (torch class whose other arguments a config may set, builder)."""


def _constant(epochs):
    return lambda e: 1.0


def _cosine(epochs, min_factor=0.01):
    floor = float(min_factor)
    return lambda e: floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * min(e, epochs) / max(epochs, 1)))


def _step(epochs, every=30, gamma=0.5):
    every, gamma = int(every), float(gamma)
    return lambda e: gamma ** (e // max(every, 1))


SCHEDULES = {"constant": _constant, "cosine": _cosine, "step": _step}
"""Schedule type -> ``f(epochs, **args)`` returning the learning-rate factor of epoch ``e`` (``LambdaLR``)."""


def _optimizer_spec(value) -> tuple[str, dict]:
    if isinstance(value, str):
        return value.lower(), {}
    if isinstance(value, dict):
        args = dict(value)
        kind = args.pop("type", None)
        if kind is None:
            raise ParameterError("train.optimizer: a mapping needs a 'type' (adam, adamw, sgd)")
        return str(kind).lower(), args
    raise ParameterError(f"train.optimizer must be a name or a mapping with a 'type', got {value!r}")


def _schedule_spec(value) -> tuple[str, dict]:
    if value is None:
        return "constant", {}
    if not isinstance(value, dict):
        raise ParameterError(
            f"train.lr_schedule must be a mapping such as {{type: cosine, min_factor: 0.01}}, got {value!r}"
        )
    args = dict(value)
    kind = args.pop("type", None)
    alias = args.pop("kind", None)
    if kind is not None and alias is not None and str(kind) != str(alias):
        raise ParameterError(f"train.lr_schedule: 'type' ({kind}) and 'kind' ({alias}) disagree")
    return str(kind if kind is not None else (alias if alias is not None else "constant")).lower(), args


def _check_args(fn, args: dict, what: str, skip: int) -> None:
    """Arguments ``args`` must be keyword parameters of ``fn`` (after its first ``skip`` positional ones)."""
    params = list(inspect.signature(fn).parameters.values())[skip:]
    names = [p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    for key in args:
        if key not in names:
            raise ParameterError(
                f"{what}: unknown argument {key!r}{_did_you_mean(key, names)} (known: {', '.join(names) or 'none'})"
            )


def check_optimizer(value) -> None:
    """Raise :class:`ParameterError` unless ``train.optimizer`` names a registered type with valid arguments."""
    kind, args = _optimizer_spec(value)
    if kind not in OPTIMIZERS:
        raise ParameterError(f"train.optimizer: unknown type {kind!r} ({', '.join(OPTIMIZERS)})")
    for key in ("lr", "weight_decay", "params"):
        if key in args:
            raise ParameterError(
                f"train.optimizer.{key}: set train.{key} instead"
                if key != "params"
                else "train.optimizer.params: not a config argument"
            )
    import importlib

    mod, cls = OPTIMIZERS[kind][0].rsplit(".", 1)
    _check_args(getattr(importlib.import_module(mod), cls), args, f"train.optimizer ({kind})", skip=1)


def check_schedule(value) -> None:
    """Raise :class:`ParameterError` unless ``train.lr_schedule`` names a registered type with valid arguments."""
    kind, args = _schedule_spec(value)
    if kind not in SCHEDULES:
        raise ParameterError(f"train.lr_schedule: unknown type {kind!r} ({', '.join(SCHEDULES)})")
    _check_args(SCHEDULES[kind], args, f"train.lr_schedule ({kind})", skip=1)
    for name, (lo, hi, low_open) in SCHEDULE_RANGES.items():
        if name not in args:
            continue
        v = args[name]
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        if ok and name == "every":
            ok = float(v).is_integer()
        if not ok or not ((lo < v) if low_open else (lo <= v)) or v > hi:
            interval = f"{'(' if low_open else '['}{lo:g}, {hi:g}]"
            raise ParameterError(f"train.lr_schedule ({kind}): {name} must be a number in {interval}, got {v!r}")


SCHEDULE_RANGES = {"every": (1, 1e9, False), "gamma": (0.0, 1.0, True), "min_factor": (0.0, 1.0, False)}
"""Schedule argument -> (low, high, low end open): a learning rate that only decays and stays positive (a negative
``gamma`` was gradient ascent; ``min_factor`` above 1 made the rate rise; ``every: 0`` was taken as 1)."""


def build_optimizer(params, tcfg: TrainConfig):
    """The torch optimizer ``train.optimizer`` describes, at ``train.lr`` / ``train.weight_decay``."""
    check_optimizer(tcfg.optimizer)
    kind, args = _optimizer_spec(tcfg.optimizer)
    return OPTIMIZERS[kind][1](params, float(tcfg.lr), float(tcfg.weight_decay or 0.0), **args)


def build_scheduler(opt, tcfg: TrainConfig):
    """A ``LambdaLR`` stepped once per epoch with the factor ``train.lr_schedule`` describes over ``train.epochs``."""
    import torch

    check_schedule(tcfg.lr_schedule)
    kind, args = _schedule_spec(tcfg.lr_schedule)
    return torch.optim.lr_scheduler.LambdaLR(opt, SCHEDULES[kind](int(tcfg.epochs), **args))


# --- key and value checks ---------------------------------------------------------------------


def _did_you_mean(key: str, known) -> str:
    return did_you_mean(key, known)


def _fail(source, msg: str):
    """An error naming the config's file when it came from one, else a parameter error."""
    if source is not None and isinstance(source, (str, Path)) and Path(str(source)).suffix.lower() in (".yaml", ".yml"):
        return InputFileError(source, msg)
    where = f"{source}: " if source else ""
    return ParameterError(f"{where}{msg}")


def check_keys(cfg: dict, source=None, model_name: str | None = None) -> None:
    """Raise an error naming the first unknown key of a config layer (a user YAML, a schedule section,
    overrides or a whole config).

    Known: the sections ``model``, ``data``, ``train``; ``model.name`` and ``model.args`` (whose keys
    must be arguments of the model's constructor when ``model_name`` is given); the fields of
    :class:`DataConfig` and :class:`TrainConfig`. ``source`` (a file path or a label) is named in the error.
    """
    if not isinstance(cfg, dict):
        raise _fail(source, "a config must be a mapping with model, data and train sections")
    for sec, body in cfg.items():
        if sec not in SECTIONS:
            raise _fail(
                source, f"unknown config section {sec!r}{_did_you_mean(sec, SECTIONS)} (expected model, data, train)"
            )
        if body is None:
            continue
        if not isinstance(body, dict):
            raise _fail(source, f"config section {sec!r} must be a mapping, got {body!r}")
        known = MODEL_KEYS if sec == "model" else [f.name for f in fields(DataConfig if sec == "data" else TrainConfig)]
        for key in body:
            if key not in known:
                raise _fail(source, f"unknown key '{sec}.{key}'{_did_you_mean(key, known)} (known: {', '.join(known)})")
    args = (cfg.get("model") or {}).get("args")
    name = model_name or (cfg.get("model") or {}).get("name")
    if args is not None:
        if not isinstance(args, dict):
            raise _fail(source, f"model.args must be a mapping, got {args!r}")
        check_model_args(args, source)
        if name is not None:
            if name in MODEL_REGISTRY:
                known = model_arguments(model_class(name))
                for key in args:
                    if key not in known:
                        raise _fail(
                            source,
                            f"unknown key 'model.args.{key}'{_did_you_mean(key, known)} for model "
                            f"{name!r} (known: {', '.join(known)})",
                        )


def model_arguments(cls) -> list[str]:
    """The constructor arguments a config's ``model.args`` may set for model class ``cls`` (``rig`` excluded)."""
    params = list(inspect.signature(cls.__init__).parameters.values())[1:]
    return [p.name for p in params if p.name != "rig" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]


def _int(v, what, lo=None, none_ok=False):
    if v is None and none_ok:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (isinstance(v, float) and not v.is_integer()):
        raise ParameterError(f"{what} must be an integer{' or null' if none_ok else ''}, got {v!r}")
    v = int(v)
    if lo is not None and v < lo:
        raise ParameterError(f"{what} must be >= {lo}, got {v}")
    return v


def _float(v, what, lo=None, strict=False, none_ok=False):
    if v is None and none_ok:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise ParameterError(f"{what} must be a finite number{' or null' if none_ok else ''}, got {v!r}")
    v = float(v)
    if lo is not None and (v <= lo if strict else v < lo):
        raise ParameterError(f"{what} must be {'>' if strict else '>='} {lo}, got {v:g}")
    return v


def _learning_rate(v) -> float:
    """``train.lr``: a number in (0, :data:`MAX_LR`]."""
    lr = _float(v, "train.lr", 0.0, strict=True)
    if lr > MAX_LR:
        raise ParameterError(f"train.lr must be a learning rate in (0, {MAX_LR:g}], got {lr:g}")
    return lr


def data_config(cfg: dict) -> DataConfig:
    """The checked :class:`DataConfig` of a merged config (missing keys: defaults)."""
    d = dict(cfg.get("data") or {})
    rig = d.get("rig")
    if rig is not None and not isinstance(rig, str):
        raise ParameterError(f"data.rig must be a rig group name (e.g. cap-32x64-60) or null, got {rig!r}")
    pim = d.get("partials_in_memory", True)
    if not isinstance(pim, bool):
        raise ParameterError(f"data.partials_in_memory must be true or false, got {pim!r}")
    return DataConfig(
        rig=rig,
        max_views=_int(d.get("max_views"), "data.max_views", 1, none_ok=True),
        val_max_views=_int(d.get("val_max_views", 200), "data.val_max_views", 1, none_ok=True),
        num_workers=_int(d.get("num_workers", 0) or 0, "data.num_workers", 0),
        partials_in_memory=pim,
        classes=_class_list(d.get("classes")),
        source_repeat=_source_repeat(d.get("source_repeat")),
    )


def _source_repeat(value) -> tuple | None:
    """``data.source_repeat``: a mapping of mesh source names to repeat counts -> sorted ``(source, K)`` pairs."""
    if value is None:
        return None
    if not isinstance(value, dict) or not value:
        raise ParameterError(
            f"data.source_repeat must be a mapping {{source: K}}, e.g. {{apolloscape-cars: 4}}; got {value!r}"
        )
    pairs = []
    for name, k in value.items():
        if not isinstance(name, str) or not name:
            raise ParameterError(f"data.source_repeat: a source must be a name, got {name!r}")
        k = _int(k, f"data.source_repeat.{name}", 1)
        if k > MAX_SOURCE_REPEAT:
            raise ParameterError(f"data.source_repeat.{name} must be <= {MAX_SOURCE_REPEAT}, got {k}")
        pairs.append((name, k))
    return tuple(sorted(pairs))


def _class_list(value) -> tuple | None:
    """``data.classes``: a list of class names (None: every model)."""
    if value is None:
        return None
    if not isinstance(value, (list, tuple)) or not value or not all(isinstance(c, str) and c for c in value):
        raise ParameterError(f"data.classes must be a list of class names (e.g. [trailer]), got {value!r}")
    return tuple(value)


def train_config(cfg: dict) -> TrainConfig:
    """The checked :class:`TrainConfig` of a merged config (missing keys: defaults; configs of earlier
    versions lack ``precision`` and ``steps_per_epoch``)."""
    from .device import PRECISIONS

    t = dict(cfg.get("train") or {})
    base = TrainConfig()
    precision = str(t.get("precision", base.precision))
    if precision.lower() not in PRECISIONS:
        raise ParameterError(f"train.precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    select_by = str(t.get("select_by", base.select_by))
    if select_by not in SELECT_BY:
        raise ParameterError(f"train.select_by must be one of {', '.join(SELECT_BY)}, got {select_by!r}")
    compile_ = t.get("compile", base.compile)
    if not isinstance(compile_, bool):
        raise ParameterError(f"train.compile must be true or false, got {compile_!r}")
    out = TrainConfig(
        epochs=_int(t.get("epochs", base.epochs), "train.epochs", 0),
        batch_size=check_batch_size(
            _int(t.get("batch_size", base.batch_size), "train.batch_size", 1), "train.batch_size"
        ),
        optimizer=t.get("optimizer", base.optimizer),
        lr=_learning_rate(t.get("lr", base.lr)),
        weight_decay=_float(t.get("weight_decay", 0.0) or 0.0, "train.weight_decay", 0.0),
        lr_schedule=t.get("lr_schedule") or {"kind": "constant"},
        grad_clip=_float(t.get("grad_clip"), "train.grad_clip", 0.0, strict=True, none_ok=True)
        if t.get("grad_clip")
        else None,
        seed=check_seed(t.get("seed", 0), "train.seed"),
        precision=precision.lower(),
        steps_per_epoch=_int(t.get("steps_per_epoch"), "train.steps_per_epoch", 1, none_ok=True),
        select_by=select_by,
        compile=compile_,
    )
    check_optimizer(out.optimizer)
    check_schedule(out.lr_schedule)
    return out
