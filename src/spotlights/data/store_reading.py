"""Reading a completion dataset file's tables and checking them as it is opened (:mod:`.store`'s reader).

:func:`read_tables` reads the small tables and attributes of one HDF5 file (a dataset, or one shard of a sharded
dataset) and refuses a damaged one with one line (:class:`~spotlights.errors.InputFileError` naming the file and
what is wrong); :func:`check_same_build`, :func:`check_shard_order` and :func:`shared_extra_rigs` check that the
shards of an index make one dataset. :func:`json_attribute` and :func:`int_attribute` read one attribute, checked.
The schema is :mod:`.store`'s docstring.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from ..geometry.rig import parse_rig
from .shard_index import without_extra_rigs
from .store_writer import FORMAT, FORMAT_VERSION, OPTIONAL_MODEL_STRINGS

__all__ = [
    "check_same_build",
    "check_shard_order",
    "int_attribute",
    "json_attribute",
    "read_tables",
    "shared_extra_rigs",
]


def _strings(ds) -> np.ndarray:
    """The HDF5 string dataset ``ds`` as a numpy array of str."""
    return np.array([x.decode() if isinstance(x, bytes) else str(x) for x in ds[()]])


def _attr_value(v):
    """An HDF5 attribute's value as a plain Python value: a scalar for numpy scalars and one-element arrays,
    a list for other arrays (``.item()`` of a two-element array raised ValueError)."""
    if getattr(v, "size", None) == 1 and hasattr(v, "item"):
        return v.item()
    return v.tolist() if hasattr(v, "tolist") else v


_JSON_KINDS = {dict: "object", list: "list"}


def json_attribute(path: str | os.PathLike, attrs, key: str, kind: type, default=None, where: str = ""):
    """The HDF5 attribute ``key`` of ``attrs`` (a file's or group's ``attrs``, or a dict of them) read as JSON
    and checked to be a ``kind`` (``dict`` or ``list``); ``default`` when the attribute is absent (``None``:
    it is required). ``where`` names the group holding it (e.g. ``"/rigs/cap-32x64-60 "``) in the message.

    Raises :class:`InputFileError` naming the file ``path`` and the attribute when it is absent and required,
    not a string of valid JSON, or JSON of another type (``[1, 2]`` where an object is expected)."""
    raw = attrs.get(key)
    if raw is None:
        if default is None:
            raise InputFileError(path, f"damaged dataset file: no {where}{key} attribute")
        return default
    if isinstance(raw, bytes):
        raw = raw.decode("utf-8", errors="replace")
    if not isinstance(raw, str):
        raise InputFileError(path, f"damaged {where}{key} attribute: not a JSON string")
    try:
        value = json.loads(raw)
    except (ValueError, RecursionError):
        raise InputFileError(path, f"damaged {where}{key} attribute: not valid JSON") from None
    if not isinstance(value, kind):
        found = _JSON_KINDS.get(type(value), type(value).__name__ if value is not None else "null")
        raise InputFileError(
            path, f"damaged {where}{key} attribute: a JSON {found}, expected a JSON {_JSON_KINDS[kind]}"
        )
    return value


def int_attribute(path: str | os.PathLike, attrs, key: str, default: int, minimum: int | None = None) -> int:
    """The integer HDF5 attribute ``key`` of ``attrs`` (``default`` when absent). Raises
    :class:`InputFileError` naming the file ``path`` and the attribute when it is not an integer (text, a
    fraction, a boolean) or is below ``minimum``."""
    raw = attrs.get(key, default)
    if isinstance(raw, np.ndarray) and raw.shape == ():
        raw = raw.item()
    value = None
    if isinstance(raw, (int, np.integer)) and not isinstance(raw, (bool, np.bool_)):
        value = int(raw)
    elif isinstance(raw, (float, np.floating)) and np.isfinite(raw) and float(raw).is_integer():
        value = int(raw)
    if value is None:
        shown = raw.decode("utf-8", errors="replace") if isinstance(raw, bytes) else raw
        raise InputFileError(path, f"damaged {key} attribute: {str(shown)[:40]!r} is not an integer")
    if minimum is not None and value < minimum:
        raise InputFileError(path, f"damaged {key} attribute: {value} is below {minimum}")
    return value


def _model_tables(path: Path, f) -> dict:
    """The /models tables, /samples/model and /samples/view and the rig names of the open file ``f`` (``path``)."""
    try:
        m = f["models"]
        t = {
            "names": _strings(m["name"]),
            "categories": _strings(m["category"]),
            "splits": _strings(m["split"]),
            "center": m["center"][()],
            "radius": m["radius"][()],
            "size": m["size"][()] if "size" in m else None,
            "sample_model": f["samples/model"][()].astype(np.int64),
            "sample_view": f["samples/view"][()].astype(np.int64),
            "rigs": list(f["rigs"].keys()),
        }
        for key in OPTIONAL_MODEL_STRINGS:
            t[key] = _strings(m[key]) if key in m else None
    except KeyError as exc:
        raise InputFileError(path, f"incomplete dataset file: missing {exc}") from None
    return t


def read_tables(path: Path, f, entry: dict, index: Path) -> dict:
    """The small tables and attributes of the open HDF5 file ``f`` (``path``: a dataset file, or a shard listed by
    ``entry`` of the index ``index``), checked: ``names``, ``categories``, ``splits`` (n_models,) str, ``center``
    (n_models, 3) and ``radius`` (n_models,) float64 metres, ``size`` (n_models, 3) float64 or None, the optional
    model strings (None where absent), ``sample_model`` and ``sample_view`` (n_samples,) int64 (rows of this file),
    ``rigs`` (rig names), ``attrs`` (the root attributes as plain values), ``config``, ``sensor`` (dict),
    ``skipped`` (list), ``views_per_model`` and ``seed`` (int).

    Raises :class:`InputFileError` naming ``path`` for another format or version, a missing group or dataset, a
    damaged attribute or partial scans, or (``entry`` with counts) other counts than the index states."""
    fmt = f.attrs.get("format")
    if fmt != FORMAT:
        raise InputFileError(path, f"not a spotlights completion dataset (format attribute {fmt!r})")
    version = int_attribute(path, f.attrs, "format_version", -1)
    if version != FORMAT_VERSION:
        raise InputFileError(path, f"dataset format version {version}, this spotlights reads {FORMAT_VERSION}")
    _check_layout(path, f)
    t = _model_tables(path, f)
    t["attrs"] = attrs = {key: _attr_value(v) for key, v in f.attrs.items()}
    t["config"] = json_attribute(path, attrs, "config_json", dict, {})
    t["sensor"] = json_attribute(path, attrs, "sensor_json", dict, {})
    t["skipped"] = json_attribute(path, attrs, "skipped_json", list, [])
    if not all(isinstance(s, dict) and {"file", "problem"} <= s.keys() for s in t["skipped"]):
        raise InputFileError(path, 'damaged skipped_json attribute: expected a list of {"file", "problem"} objects')
    t["views_per_model"] = int_attribute(path, attrs, "views_per_model", 0, minimum=0)
    t["seed"] = int_attribute(path, attrs, "seed", 0)
    _check_partials(path, f["samples"], len(t["sample_model"]), t["config"].get("n_points"))
    if entry["n_models"] is not None and (len(t["names"]), len(t["sample_model"])) != (
        entry["n_models"],
        entry["n_samples"],
    ):
        raise InputFileError(
            path,
            f"holds {len(t['names'])} models and {len(t['sample_model'])} samples, the "
            f"index {index.name} says {entry['n_models']} and {entry['n_samples']}",
        )
    return t


def check_same_build(shards: list[Path], tables: list[dict]) -> None:
    """Refuse shards (``shards``, their :func:`read_tables` ``tables``) whose build differs from the first one's:
    configuration, default rig, views per model, sensor or seed (a configuration that differs only in the extra
    rigs an interrupted add-rig left in some shards is the same). :class:`InputFileError` names the shard."""
    first = tables[0]
    for k, t in enumerate(tables[1:], 1):
        for key in ("config_json", "default_rig", "views_per_model", "sensor_json", "seed"):
            a, b = t["attrs"].get(key), first["attrs"].get(key)
            if key == "config_json":  # an interrupted add-rig leaves some shards with one more rig
                a, b = without_extra_rigs(a), without_extra_rigs(b)
            if a != b:
                raise InputFileError(
                    shards[k],
                    f"shard differs from {shards[0].name} in {key}: not a shard of the same dataset",
                )


def shared_extra_rigs(shards: list[Path], tables: list[dict], rig_names: list[str]) -> list[str]:
    """The extra rigs (rig strings, in the order first listed) of any shard's configuration whose rig every shard
    holds (``rig_names``; an add-rig may be half done). :class:`InputFileError` names a shard whose ``extra_rigs``
    is not a list of rig names."""
    union: list[str] = []
    for k, t in enumerate(tables):
        extra = t["config"].get("extra_rigs") or []
        if not isinstance(extra, list) or not all(isinstance(r, str) for r in extra):
            raise InputFileError(shards[k], "damaged config_json attribute: extra_rigs is not a list of rig names")
        for r in extra:
            if r not in union and parse_rig(r).name in rig_names:
                union.append(r)
    return union


# The groups and datasets every dataset file holds (h5py's own message for a missing one,
# "Unable to synchronously open object (component not found)", names neither).
_GROUPS = ("models", "samples", "rigs")
_REQUIRED = (
    "models/name",
    "models/category",
    "models/split",
    "models/center",
    "models/radius",
    "samples/model",
    "samples/view",
)


def _check_layout(path: Path, f) -> None:
    """Refuse a file that lacks one of the groups or datasets the reader needs, naming it."""
    import h5py

    for key in _GROUPS:
        if not isinstance(f.get(key), h5py.Group):
            raise InputFileError(
                path, f"incomplete dataset file: missing /{key}" if key not in f else f"/{key} is not a group"
            )
    for key in _REQUIRED:
        if not isinstance(f.get(key), h5py.Dataset):
            raise InputFileError(
                path, f"incomplete dataset file: missing /{key}" if key not in f else f"/{key} is not a dataset"
            )


def _check_partials(path: Path, samples, n_samples: int, n_points) -> None:
    """Refuse a ``/samples/partial`` that is not (n_samples, P, 3) floating-point coordinates, P >= 1 and, when
    the build configuration states it (``n_points``), P = that count. Reads only the dataset's header: whether
    the coordinates are finite is checked where they are read (:meth:`CompletionDataset.partials`)."""
    import h5py

    d = samples.get("partial")
    if d is None:  # reported by the readers that need it (spotlights.learning.data: "lacks /samples/partial")
        return
    if not isinstance(d, h5py.Dataset):
        raise InputFileError(path, "/samples/partial is not a dataset")
    if d.dtype.kind != "f":
        raise InputFileError(path, f"/samples/partial holds {d.dtype} values, expected floating-point coordinates")
    want_p = n_points if isinstance(n_points, int) and not isinstance(n_points, bool) and n_points >= 1 else None
    if d.ndim != 3 or d.shape[0] != n_samples or d.shape[2] != 3 or d.shape[1] < 1 or (want_p and d.shape[1] != want_p):
        want = f"({n_samples}, {want_p or 'P'}, 3)"
        stated = " (n_points of its config_json)" if want_p else ""
        raise InputFileError(path, f"/samples/partial has shape {tuple(d.shape)}, expected {want}{stated}")


def check_shard_order(index: Path, shards: list[Path], attrs: list[dict]) -> None:
    """Refuse an index that does not list its build's shards once each, in order: every shard
    records its position (``shard_index``, 0-based, of ``shard_count``). A shard listed twice, a
    missing one or a swapped pair would silently change the dataset (its models, sample order and
    bytes). Shards without a recorded position are not checked."""
    pos = [(a.get("shard_index"), a.get("shard_count")) for a in attrs]
    if any(k is None or n is None for k, n in pos):
        return
    counts = sorted({int(n) for _, n in pos})
    if len(counts) > 1:
        raise InputFileError(index, f"lists shards of different builds (shard counts {counts})")
    count, first = counts[0], {}
    for i, (k, _) in enumerate(pos):
        if int(k) in first:
            raise InputFileError(
                index, f"lists shard {int(k)} of {count} twice ({shards[first[int(k)]].name} and {shards[i].name})"
            )
        first[int(k)] = i
    missing = [k for k in range(count) if k not in first]
    if missing:
        raise InputFileError(
            index, f"lacks shard {missing[0]} of {count} (it lists {len(pos)}): a shard file is missing from the index"
        )
    for i, (k, _) in enumerate(pos):
        if int(k) != i:
            raise InputFileError(
                index, f"lists {shards[i].name} (shard {int(k)} of {count}) in place {i}: list the shards in order"
            )
