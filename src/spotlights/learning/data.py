"""Reading the synthetic completion dataset (HDF5, schema in docs / notes contracts) for PyTorch.

:class:`TorchCompletionDataset` is a ``torch.utils.data.Dataset`` over one split of a
``spotlights-completion`` HDF5 file (the format of ``spotlights.data.store``, whose
reader is torch-free and per sample; this one serves training batches):

* the per-model arrays (uniform ground truth, Spotlights depths of one rig) are
  small and read once at construction; every observation of a model shares them;
* partial scans are read lazily, one sample per ``__getitem__`` (the file is opened
  on first use in each process, so several ``DataLoader`` workers each hold their
  own h5py handle; a handle is never shared across ``fork``), or, with
  ``partials_in_memory=True``, read once per split in contiguous per-model slices;
* the dense ground truth (16,384 points per model, for metrics) is read on demand
  by :meth:`TorchCompletionDataset.gt_dense`.

Items are dicts of tensors::

    partial   (256, 3) float32, unit frame
    gt_points (2048, 3) float32, unit frame (the model's uniform surface samples)
    depths    (N*M,) float32 in [0, 1], 0 = miss (only when a rig is selected)
    model     () int64, row in /models;  view () int64;  index () int64 row in /samples

The dataset holds no randomness: the same index always gives the same bytes, so
results do not depend on the number of workers.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from ..errors import InputFileError, ParameterError

FORMAT = "spotlights-completion"
SPLITS = ("train", "val", "test")
CATEGORY_ORDER = ("hatchback", "sedan", "suv")
"""Report order of the paper's categories; other categories follow, sorted."""


def _str_array(ds) -> np.ndarray:
    """h5py string dataset -> numpy array of Python str."""
    raw = ds[()]
    return np.array([x.decode() if isinstance(x, bytes) else str(x) for x in np.asarray(raw).reshape(-1)], dtype=object)


def _attr_str(v) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


@dataclass(frozen=True)
class DatasetInfo:
    """Table of contents of a dataset file (no bulk arrays).

    Attributes
    ----------
    path : the file. names, categories, splits : (n_models,) str arrays.
    sample_model, sample_view : (n_samples,) int64. rigs : rig name -> ``rig_json`` dict
    (``RigSpec.to_dict()``; cap rigs: ``Rig.to_dict()``).
    default_rig : the file's default rig name. attrs : root attributes (str/int).
    """

    path: Path
    names: np.ndarray
    categories: np.ndarray
    splits: np.ndarray
    sample_model: np.ndarray
    sample_view: np.ndarray
    rigs: dict
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
            raise InputFileError(self.path, f"no default_rig attribute; choose a rig among: {', '.join(sorted(self.rigs)) or 'none'}")
        if name not in self.rigs:
            raise InputFileError(self.path, f"has no rig {name!r} (rigs: {', '.join(sorted(self.rigs)) or 'none'})")
        return name


def _open_h5(path):
    import h5py

    p = Path(path)
    if not p.exists():
        raise InputFileError(p, "no such file")
    if p.is_dir():
        raise InputFileError(p, "is a folder, expected a dataset .h5 file")
    try:
        return h5py.File(p, "r")
    except OSError as exc:
        raise InputFileError(p, f"not a readable HDF5 file ({str(exc).splitlines()[0][:80]})") from None


REQUIRED = ("models/name", "models/category", "models/split", "models/gt_points", "samples/partial", "samples/model", "samples/view")


def read_info(path) -> DatasetInfo:
    """Read and validate the table of contents of a dataset file.

    Raises :class:`InputFileError` if the file is missing, not HDF5, not of format
    ``spotlights-completion``, or lacks a required dataset.
    """
    p = Path(path)
    with _open_h5(p) as f:
        fmt = _attr_str(f.attrs.get("format", ""))
        if fmt != FORMAT:
            raise InputFileError(p, f"not a spotlights completion dataset (format attribute {fmt!r}, expected {FORMAT!r})")
        missing = [k for k in REQUIRED if k not in f]
        if missing:
            raise InputFileError(p, f"dataset file lacks {', '.join('/' + m for m in missing)}")
        rigs = {}
        for name, grp in (f["rigs"].items() if "rigs" in f else []):
            try:
                rigs[name] = json.loads(_attr_str(grp.attrs["rig_json"]))
            except (KeyError, ValueError):
                raise InputFileError(p, f"/rigs/{name} lacks a valid rig_json attribute") from None
        attrs = {k: (_attr_str(v) if isinstance(v, (bytes, str)) else v.item() if hasattr(v, "item") else v) for k, v in f.attrs.items()}
        info = DatasetInfo(
            path=p,
            names=_str_array(f["models/name"]),
            categories=_str_array(f["models/category"]),
            splits=_str_array(f["models/split"]),
            sample_model=np.asarray(f["samples/model"][()], dtype=np.int64),
            sample_view=np.asarray(f["samples/view"][()], dtype=np.int64),
            rigs=rigs,
            default_rig=attrs.get("default_rig") or None,
            attrs=attrs,
        )
    n = info.n_models
    if len(info.sample_model) and (info.sample_model.min() < 0 or info.sample_model.max() >= n):
        raise InputFileError(p, "/samples/model refers to rows outside /models")
    return info


class TorchCompletionDataset(Dataset):
    """One split of a completion dataset file as a torch ``Dataset`` (see the module docstring).

    Parameters
    ----------
    path : HDF5 file of format ``spotlights-completion``.
    split : ``"train"``, ``"val"``, ``"test"`` or ``"all"``.
    rig : rig group whose depths to serve (SA-Net); ``None`` = the file's default rig,
        ``False`` = no depths.
    max_views : keep only observations with view index < max_views (per model).
    partials_in_memory : read all the split's partial scans at construction.

    Attributes: ``rig`` (the served rig's ``rig_json`` dict; box-targeted rigs hold the
    spec, each model's rig is aimed at its own box), ``extents`` ((n_models, 3) float64
    box half-extents ``size / 2R`` of every model row, or None for files without
    /models/size): ``spotlights.learning.rays.DirectionTable(rig, ds.extents)`` gives
    each sample's rays from its ``model`` row.
    """

    def __init__(self, path, split: str = "train", rig: str | None | bool = None, max_views: int | None = None,
                 partials_in_memory: bool = False):
        if split not in (*SPLITS, "all"):
            raise ParameterError(f"split must be one of {', '.join(SPLITS)} or all, got {split!r}")
        self.info = info = read_info(path)
        self.path = str(info.path)
        self.split = split
        self.model_rows = np.flatnonzero(info.splits == split) if split != "all" else np.arange(info.n_models)
        keep = np.isin(info.sample_model, self.model_rows)
        if max_views is not None:
            if int(max_views) < 1:
                raise ParameterError(f"max_views must be >= 1, got {max_views}")
            keep &= info.sample_view < int(max_views)
        self.indices = np.flatnonzero(keep).astype(np.int64)  # rows of /samples, file order (model-major)
        if len(self.indices) == 0:
            raise InputFileError(self.path, f"split {split!r} has no samples" + (f" with view < {max_views}" if max_views else ""))
        self.rig_name = None if rig is False else info.resolve_rig(rig if rig is not True else None)
        self.rig = info.rigs[self.rig_name] if self.rig_name else None
        import h5py  # noqa: F401  (fail early if missing)

        with _open_h5(self.path) as f:
            self.gt_points = np.ascontiguousarray(f["models/gt_points"][()], dtype=np.float32)
            self.depths = None
            if self.rig_name:
                key = f"rigs/{self.rig_name}/depths"
                if key not in f:
                    raise InputFileError(self.path, f"/rigs/{self.rig_name} has no depths dataset")
                self.depths = np.ascontiguousarray(f[key][()], dtype=np.float32)
            self.partials = self._read_partials(f) if partials_in_memory else None
            self.extents = None
            if "models/size" in f and "models/radius" in f:
                size = np.asarray(f["models/size"][()], dtype=np.float64)
                self.extents = size / (2.0 * np.asarray(f["models/radius"][()], dtype=np.float64)[:, None])
        if self.rig is not None and self.rig.get("kind", "cap") == "box" and self.extents is None:
            raise InputFileError(self.path, f"rig {self.rig_name} is box-targeted but the file has no /models/size "
                                            "(each model's box)")
        self._h5 = None
        self._pid = None

    # -- per-process lazy file handle -------------------------------------------------
    def _file(self):
        if self._h5 is None or self._pid != os.getpid():
            import h5py

            self._h5 = h5py.File(self.path, "r")
            self._pid = os.getpid()
        return self._h5

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_h5"] = None
        state["_pid"] = None
        return state

    def close(self) -> None:
        """Close this process's file handle (it reopens on the next access)."""
        if self._h5 is not None and self._pid == os.getpid():
            self._h5.close()
        self._h5 = None

    def _read_partials(self, f) -> np.ndarray:
        """(len, 256, 3) float32: read in contiguous runs of /samples rows (one h5py call per run)."""
        ds = f["samples/partial"]
        out = np.empty((len(self.indices), *ds.shape[1:]), dtype=np.float32)
        idx = self.indices
        breaks = np.flatnonzero(np.diff(idx) != 1) + 1
        start = 0
        for run in np.split(np.arange(len(idx)), breaks):
            lo, hi = idx[run[0]], idx[run[-1]] + 1
            out[start:start + len(run)] = ds[lo:hi]
            start += len(run)
        return out

    # -- Dataset protocol -------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> dict:
        row = int(self.indices[i])
        model = int(self.info.sample_model[row])
        if self.partials is not None:
            partial = self.partials[i]
        else:
            partial = np.asarray(self._file()["samples/partial"][row], dtype=np.float32)
        item = {
            "partial": torch.from_numpy(np.array(partial, dtype=np.float32)),
            "gt_points": torch.from_numpy(self.gt_points[model]),
            "model": torch.tensor(model, dtype=torch.int64),
            "view": torch.tensor(int(self.info.sample_view[row]), dtype=torch.int64),
            "index": torch.tensor(row, dtype=torch.int64),
        }
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
        with _open_h5(self.path) as f:
            if "models/gt_dense" not in f:
                raise InputFileError(self.path, "dataset file lacks /models/gt_dense (needed for the metrics)")
            ds = f["models/gt_dense"]
            return {int(m): np.asarray(ds[int(m)], dtype=np.float32) for m in np.unique(self.sample_models)}
