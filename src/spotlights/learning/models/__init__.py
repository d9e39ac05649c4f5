"""Model registry and configurations.

A model is one module (``spotlights/learning/models/<name>.py``) and one YAML
config (``spotlights/learning/configs/<name>.yaml``); the registry (:mod:`spotlights.learning.registry`, re-exported here) maps a name to
``"module:Class"`` and imports the module only when the model is built, so nothing
imports every model (or torch) at start-up.

Config layout (every file is complete; a user YAML overrides any subset)::

    model: {name: sanet, args: {...}, mirror: false}   # constructor arguments; mirror: y -> -y copies of the input
    data:  {rig, max_views, val_max_views, num_workers, partials_in_memory}
    train: {epochs, batch_size, lr, weight_decay, lr_schedule, grad_clip, seed}
"""

from __future__ import annotations

import copy
from importlib import resources
from pathlib import Path

from ...errors import InputFileError, ParameterError
from ..config import check_keys, data_config, train_config
from ..rays import rig_spec
from ..registry import DISPLAY_NAMES, MODEL_NAMES, MODEL_REGISTRY, SCHEDULE_FALLBACK, check_model_name, model_class

__all__ = [
    "DISPLAY_NAMES",
    "MODEL_NAMES",
    "MODEL_REGISTRY",
    "SCHEDULE_FALLBACK",
    "build_model",
    "check_model_name",
    "default_config_path",
    "deep_merge",
    "load_config",
    "load_schedule",
    "model_class",
    "schedule_path",
]


def default_config_path(name: str) -> Path:
    """Path of the packaged YAML config of model ``name``."""
    return Path(str(resources.files("spotlights.learning") / "configs" / f"{check_model_name(name)}.yaml"))


def _read_yaml(path) -> dict:
    import yaml

    p = Path(path)
    if not p.is_file():
        raise InputFileError(p, "no such config file")
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise InputFileError(p, f"invalid YAML ({str(exc).splitlines()[0]})") from None
    except UnicodeDecodeError:
        raise InputFileError(p, "not a YAML text file (not UTF-8)") from None
    except RecursionError:
        raise InputFileError(p, "invalid YAML (nested too deeply)") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputFileError(p, "a config must be a YAML mapping (model:, data:, train:)")
    return data


REPLACED_WHOLE = frozenset({"lr_schedule"})
"""Config keys whose mapping value replaces the previous one instead of merging into it."""


def deep_merge(base: dict, override: dict) -> dict:
    """A copy of ``base`` with ``override`` merged in recursively (mappings merge, other values replace;
    the keys in ``REPLACED_WHOLE`` are replaced whole)."""
    out = copy.deepcopy(base)
    for k, v in (override or {}).items():
        if isinstance(v, dict) and isinstance(out.get(k), dict) and k not in REPLACED_WHOLE:
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def schedule_path(schedule) -> Path:
    """Path of a training schedule: a packaged name (``cpu``, ``paper``) or a YAML file."""
    p = Path(str(schedule))
    if p.suffix.lower() in (".yaml", ".yml") or p.is_file():
        return p
    packaged = Path(str(resources.files("spotlights.learning") / "configs" / "schedules" / f"{schedule}.yaml"))
    if not packaged.is_file():
        names = sorted(q.stem for q in packaged.parent.glob("*.yaml"))
        raise ParameterError(
            f"unknown schedule {schedule!r}; packaged schedules: {', '.join(names)} (or give a YAML file)"
        )
    return packaged


def load_schedule(schedule, name: str) -> dict:
    """The overrides a schedule gives model ``name``: its ``default`` section merged with its ``name`` section
    (a variant without a section of its own uses its parent's, :data:`SCHEDULE_FALLBACK`)."""
    p = schedule_path(schedule)
    data = _read_yaml(p)
    unknown = set(data) - {"default", *MODEL_NAMES, "description"}
    if unknown:
        raise InputFileError(
            p, f"unknown schedule section(s) {', '.join(sorted(unknown))} (expected default or model names)"
        )

    for sec in ("default", *MODEL_NAMES):
        if data.get(sec) is not None:
            check_keys(data[sec], p, None if sec == "default" else sec)
    section = name
    while section not in data and section in SCHEDULE_FALLBACK:  # sanet-local -> sanet-hit -> sanet
        section = SCHEDULE_FALLBACK[section]
    return deep_merge(data.get("default") or {}, data.get(section) or {})


def load_config(name: str, path=None, overrides: dict | None = None, schedule=None) -> dict:
    """The configuration of model ``name``.

    Merge order (later wins): packaged defaults <- ``schedule`` (a packaged schedule
    name such as ``"cpu"`` or a schedule YAML) <- user YAML ``path`` <- ``overrides``.

    Every layer's keys are checked (:func:`spotlights.learning.config.check_keys`): an unknown
    section or key (a typo such as ``epoch:``) is an error naming it and its file; the merged
    values are checked by :func:`~spotlights.learning.config.train_config` and ``data_config``.

    Raises :class:`InputFileError` for a missing/invalid YAML, an unknown key in a file, and when
    the user YAML names another model; :class:`ParameterError` for unknown override keys and
    invalid values.
    """
    cfg = _read_yaml(default_config_path(name))
    if schedule is not None:
        cfg = deep_merge(cfg, load_schedule(schedule, name))
    if path is not None:
        user = _read_yaml(path)
        check_keys(user, path, name)
        other = (user.get("model") or {}).get("name")
        if other is not None and other != name:
            raise InputFileError(path, f"config is for model {other!r}, not {name!r}")
        cfg = deep_merge(cfg, user)
    if overrides:
        check_keys(overrides, "overrides", name)
        cfg = deep_merge(cfg, overrides)
    cfg["model"]["name"] = name
    check_keys(cfg, "config", name)
    data_config(cfg), train_config(cfg)
    return cfg


def build_model(config: dict, rig=None):
    """Instantiate the model a config describes.

    Parameters
    ----------
    config : a config from :func:`load_config` (only ``config["model"]`` is used).
    rig : ``RigSpec`` (or a ``Rig``, or the ``to_dict()`` of either); required for SA-Nets (the
        depths' rig), ignored otherwise.

    Raises :class:`ParameterError` for an unknown ``model.args`` key (naming it) or a value the
    model refuses.
    """
    name = config["model"]["name"]
    cls = model_class(name)
    args = dict(config["model"].get("args") or {})
    check_keys({"model": {"name": name, "args": args}}, "config", name)
    mirror = config["model"].get("mirror", False) or False
    if not isinstance(mirror, bool):
        raise ParameterError(f"model.mirror must be true or false, got {mirror!r}")
    try:
        if cls.target == "depths":
            if rig is None:
                raise ParameterError(f"model {name!r} needs a rig")
            model = cls(rig=rig_spec(rig), **args)
        else:
            model = cls(**args)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"invalid arguments for model {name!r} in config: {exc}") from None
    if mirror:  # every model's encoder input: the points and their mirror image (y -> -y)
        if not hasattr(getattr(model, "encoder", None), "mirror"):
            raise ParameterError(f"model {name!r} has no encoder that takes model.mirror")
        model.encoder.mirror = True
    return model
