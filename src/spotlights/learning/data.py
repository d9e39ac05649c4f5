"""The synthetic completion dataset for PyTorch: a ``Dataset`` over the data layer's reader.

:class:`TorchCompletionDataset` is a ``torch.utils.data.Dataset`` over one split of a
``spotlights-completion`` dataset, read through :func:`spotlights.data.store.open_dataset`
(the one reader of the format: it validates the format and its version, and reads single
files and sharded datasets alike). This module only shapes training items:

* the per-model arrays (uniform ground truth, Spotlights depths of one rig) are
  small and read once at construction; every observation of a model shares them;
* partial scans are read lazily, one sample per ``__getitem__`` (the reader opens its
  files on first use in each process, so several ``DataLoader`` workers each hold their
  own h5py handles; a handle is never shared across ``fork``), or, with
  ``partials_in_memory=True``, read once per split in contiguous per-model slices;
* the dense ground truth (16,384 points per model, for metrics) is read on demand
  by :meth:`TorchCompletionDataset.gt_dense`.

Items are dicts of tensors::

    partial   (256, 3) float32, unit frame
    gt_points (2048, 3) float32, unit frame (the model's uniform surface samples)
    depths    (N*M,) float32 in [0, 1], 0 = miss (only when a rig is selected)
    model     () int64, row in /models;  view () int64;  index () int64 row in /samples
    cls       () int64, the model's class as a row of ``class_vocab`` (-1: not in it; only when a
              ``class_vocab`` is given: a class-conditioned model's)
    sensor_origin (3,) float32, unit frame: the LiDAR's optical centre (NaN for files without
              /samples/sensor_to_unit; ``has_sensor_origin`` tells)

The dataset holds no randomness: the same index always gives the same bytes, so
results do not depend on the number of workers.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from ..data.store import SPLITS, CompletionDataset, open_dataset
from ..data.vehicle_classes import canonical_class
from ..errors import InputFileError, ParameterError, ProcessFailure, SpotlightsError
from ..geometry.rig import RigSpec

CATEGORY_ORDER = ("hatchback", "sedan", "suv")
"""Report order of the paper's categories; other categories follow, sorted."""


@dataclass(frozen=True)
class DatasetInfo:
    """Table of contents of a dataset file (no bulk arrays).

    Attributes
    ----------
    path : the file. names, categories, splits : (n_models,) str arrays.
    sample_model, sample_view : (n_samples,) int64. rigs : rig name -> its
    :class:`~spotlights.geometry.rig.RigSpec` (read from the group's ``rig_json``).
    default_rig : the file's default rig name. attrs : root attributes (str/int).
    """

    path: Path
    names: np.ndarray
    categories: np.ndarray
    splits: np.ndarray
    sample_model: np.ndarray
    sample_view: np.ndarray
    rigs: dict[str, RigSpec]
    default_rig: str | None
    attrs: dict

    @property
    def n_models(self) -> int:
        return len(self.names)

    def category_order(self) -> list[str]:
        """Categories present, the paper's first (hatchback, sedan, suv), then the others sorted."""
        present = set(self.categories.tolist())
        return [c for c in CATEGORY_ORDER if c in present] + sorted(present - set(CATEGORY_ORDER))

    def resolve_rig(self, rig: str | None) -> str:
        """Rig group name to use: ``rig`` if given (validated), else the file's default rig."""
        name = rig or self.default_rig
        if name is None:
            if len(self.rigs) == 1:
                return next(iter(self.rigs))
            raise InputFileError(
                self.path, f"no default_rig attribute; choose a rig among: {', '.join(sorted(self.rigs)) or 'none'}"
            )
        if name not in self.rigs:
            raise InputFileError(self.path, f"has no rig {name!r} (rigs: {', '.join(sorted(self.rigs)) or 'none'})")
        return name


def read_info(path) -> DatasetInfo:
    """Read and validate the table of contents of a dataset (file or shard index).

    Raises :class:`InputFileError` if it is missing, not HDF5, not of format
    ``spotlights-completion`` (or another version), or lacks a required dataset.
    """
    with open_dataset(path) as ds:
        return _info_of(ds)


def _info_of(ds: CompletionDataset) -> DatasetInfo:
    for key in ("models/gt_points", "samples/partial"):
        if not ds.has(key):
            raise InputFileError(ds.path, f"dataset file lacks /{key}")
    rigs = {}
    for name in ds.rig_names:
        try:
            rigs[name] = ds.rig_spec(name)
        except (KeyError, ValueError):  # ValueError: bad JSON, or a ParameterError of RigSpec.from_dict
            raise InputFileError(ds.path, f"/rigs/{name} lacks a valid rig_json attribute") from None
    return DatasetInfo(
        path=ds.path,
        names=ds.names.astype(object),
        categories=ds.categories.astype(object),
        splits=ds.splits.astype(object),
        sample_model=ds.sample_model,
        sample_view=ds.sample_view,
        rigs=rigs,
        default_rig=ds.attrs.get("default_rig") or None,
        attrs=dict(ds.attrs),
    )


def _split_models(store, info, split: str, only_classes) -> np.ndarray:
    """(k,) int64 the model rows of ``split`` (``"all"``: every model), only those of ``only_classes`` when given."""
    rows = np.flatnonzero(info.splits == split) if split != "all" else np.arange(info.n_models)
    if only_classes:  # a class family's model: only these classes' models of the split
        want = {canonical_class(c) for c in only_classes}
        of = np.array([canonical_class(c) in want for c in np.asarray(store.classes).astype(str)])
        rows = rows[of[rows]]
        if len(rows) == 0:
            raise InputFileError(str(info.path), f"split {split!r} has no models of class {', '.join(sorted(want))}")
    return rows


def _split_samples(info, model_rows: np.ndarray, split: str, max_views: int | None) -> np.ndarray:
    """(n,) int64 the rows of /samples (storage order, model-major) of the models ``model_rows``, only their views
    below ``max_views`` when given."""
    keep = np.isin(info.sample_model, model_rows)
    if max_views is not None:
        if int(max_views) < 1:
            raise ParameterError(f"max_views must be >= 1, got {max_views}")
        keep &= info.sample_view < int(max_views)
    indices = np.flatnonzero(keep).astype(np.int64)  # rows of /samples, storage order (model-major)
    if len(indices) == 0:
        raise InputFileError(
            str(info.path), f"split {split!r} has no samples" + (f" with view < {max_views}" if max_views else "")
        )
    return indices


def _class_rows(classes: np.ndarray, class_vocab) -> np.ndarray:
    """(n_models,) int64 the row of each model's class (``classes``, (n_models,) str) in ``class_vocab``, -1 when
    absent."""
    table = {canonical_class(c): i for i, c in enumerate(class_vocab)}
    return np.array([table.get(canonical_class(c), -1) for c in classes], np.int64)


class TorchCompletionDataset(Dataset):
    """One split of a completion dataset file as a torch ``Dataset`` (see the module docstring).

    Parameters
    ----------
    path : dataset of format ``spotlights-completion``: an HDF5 file or a shard index (JSON).
    split : ``"train"``, ``"val"``, ``"test"`` or ``"all"``.
    rig : rig group whose depths to serve (SA-Net); ``None`` = the file's default rig,
        ``False`` = no depths.
    max_views : keep only observations with view index < max_views (per model).
    partials_in_memory : read all the split's partial scans at construction.
    class_vocab : a class-conditioned model's class names: items get ``cls``, the row of their model's
        class (``/models/class``, or the class of its category for older files) in it, -1 when absent.
    only_classes : keep only the models of these classes (config ``data.classes``: one model per class family;
        the learned domain recorded at training then holds only them); None: every model of the split.

    Attributes: ``rig`` (the served rig's :class:`~spotlights.geometry.rig.RigSpec`, or None; a
    box-targeted spec's rig is aimed at each model's own box), ``extents`` ((n_models, 3) float64
    box half-extents ``size / 2R`` of every model row, or None for files without
    /models/size): ``spotlights.learning.rays.DirectionTable(rig, ds.extents)`` gives
    each sample's rays from its ``model`` row; ``sizes`` ((n_models, 3) float64 box length, width,
    height in metres, or None likewise) and ``info.categories`` ((n_models,) str) of every model
    row, the split's rows being ``model_rows``; ``sensor_origins`` ((len, 3) float32, unit frame: each
    item's LiDAR origin, NaN rows for files without /samples/sensor_to_unit) and ``has_sensor_origin``
    (every item has one).
    """

    def __init__(
        self,
        path,
        split: str = "train",
        rig: str | None | bool = None,
        max_views: int | None = None,
        partials_in_memory: bool = False,
        class_vocab=None,
        only_classes=None,
    ):
        if split not in (*SPLITS, "all"):
            raise ParameterError(f"split must be one of {', '.join(SPLITS)} or all, got {split!r}")
        self.store = store = open_dataset(path)
        try:
            self.info = info = _info_of(store)
            self.path = str(info.path)
            self.split = split
            self.model_rows = _split_models(store, info, split, only_classes)
            self.indices = _split_samples(info, self.model_rows, split, max_views)
            self.rig_name = None if rig is False else info.resolve_rig(rig if rig is not True else None)
            self.rig = info.rigs[self.rig_name] if self.rig_name else None
            self.gt_points = np.ascontiguousarray(store.models_array("gt_points"), dtype=np.float32)
            self.depths = None
            if self.rig_name:
                self.depths = np.ascontiguousarray(store.rig_depths(self.rig_name), dtype=np.float32)
            self.partials = (
                np.ascontiguousarray(store.partials(self.indices), dtype=np.float32) if partials_in_memory else None
            )
            self.sensor_origins = store.sensor_origins(self.indices).astype(np.float32)
            self.has_sensor_origin = bool(np.all(np.isfinite(self.sensor_origins)))
            self.extents = store.extents if store.size is not None else None
            self.sizes = None if store.size is None else np.asarray(store.size, dtype=np.float64)
            self.classes = np.asarray(store.classes).astype(str)  # (n_models,) detector class of every model
            # (n_models,) str mesh source of every model ("" for single-source files)
            self.sources = (
                np.asarray(store.sources).astype(str) if store.sources is not None else np.full(len(self.classes), "")
            )
            self.has_stored_classes = store.stored_classes is not None  # /models/class (else from categories)
            self.class_rows = _class_rows(self.classes, class_vocab) if class_vocab else None
        finally:
            store.close()  # DataLoader workers open their own handles
        if self.rig is not None and self.rig.needs_box and self.extents is None:
            raise InputFileError(
                self.path, f"rig {self.rig_name} is box-targeted but the file has no /models/size (each model's box)"
            )

    def close(self) -> None:
        """Close this process's file handles (they reopen on the next access)."""
        self.store.close()

    # -- Dataset protocol -------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> dict:
        row = int(self.indices[i])
        model = int(self.info.sample_model[row])
        partial = self.partials[i] if self.partials is not None else self.store.partial(row)
        item = {
            "partial": torch.from_numpy(np.array(partial, dtype=np.float32)),
            "gt_points": torch.from_numpy(self.gt_points[model]),
            "model": torch.tensor(model, dtype=torch.int64),
            "view": torch.tensor(int(self.info.sample_view[row]), dtype=torch.int64),
            "index": torch.tensor(row, dtype=torch.int64),
            "sensor_origin": torch.from_numpy(self.sensor_origins[i]),
        }
        if self.class_rows is not None:
            item["cls"] = torch.tensor(int(self.class_rows[model]), dtype=torch.int64)
        if self.depths is not None:
            item["depths"] = torch.from_numpy(self.depths[model])
        return item

    # -- helpers for evaluation -------------------------------------------------------
    @property
    def sample_models(self) -> np.ndarray:
        """(len,) int64 /models row of each item."""
        return self.info.sample_model[self.indices]

    @property
    def sample_categories(self) -> np.ndarray:
        """(len,) str category of each item."""
        return self.info.categories[self.sample_models]

    def gt_dense(self) -> dict[int, np.ndarray]:
        """{model row: (16384, 3) float32 dense unit-frame ground truth} for this split's models."""
        rows = np.unique(self.sample_models)
        if not self.store.has("models/gt_dense"):
            raise InputFileError(self.path, "dataset file lacks /models/gt_dense (needed for the metrics)")
        try:
            dense = self.store.models_array("gt_dense", rows)
        finally:
            self.store.close()
        return {int(m): np.asarray(d, dtype=np.float32) for m, d in zip(rows, dense)}


# torch rebuilds an exception raised in a DataLoader worker from its text alone ("Caught X in DataLoader worker
# process N.\nOriginal Traceback ...\nmodule.X: message"): a RuntimeError for the errors whose constructor takes
# two arguments (InputFileError), the error with the whole traceback as its message for the others
_CAUGHT = re.compile(r"\ACaught (\w+) in DataLoader worker process \d+")


def _worker_error(text: str) -> SpotlightsError | None:
    """The one-line :class:`~spotlights.errors.SpotlightsError` of torch's rebuilt worker exception ``text``,
    or None when the worker's exception was not one of the package's errors."""
    caught = _CAUGHT.match(text)
    if caught is None:
        return None
    name = caught.group(1)
    # the traceback's last "module.Name: message" is the caught exception (earlier ones are its causes)
    found = list(re.finditer(rf"^(spotlights(?:\.\w+)*)\.{name}: ", text, re.MULTILINE))
    last = found[-1] if found else None
    if last is None or text.find("\nThe above exception", last.end()) >= 0:
        return None
    module = sys.modules.get(last.group(1))
    cls = getattr(module, name, None)
    if not (isinstance(cls, type) and issubclass(cls, SpotlightsError)):
        return None
    message = text[last.end() :].strip()
    if issubclass(cls, ParameterError):  # the parameters it names, as `name` (the CLI writes them as its options)
        return ParameterError(message, *dict.fromkeys(re.findall(r"`(\w+)`", message)))
    return (ProcessFailure if issubclass(cls, ProcessFailure) else SpotlightsError)(message)


def worker_batches(batches: Iterable) -> Iterator:
    """Iterate a DataLoader's ``batches`` (or a tqdm over it); a :class:`~spotlights.errors.SpotlightsError` raised
    in a worker process (a damaged sample read lazily) comes out as its own message, with its exit code, instead of
    torch's RuntimeError and the worker's traceback."""
    it = iter(batches)
    while True:
        try:
            batch = next(it)
        except StopIteration:
            return
        except (RuntimeError, SpotlightsError) as exc:
            error = _worker_error(str(exc))
            if error is None:
                raise
            raise error from None
        yield batch
