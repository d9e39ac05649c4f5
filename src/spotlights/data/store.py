"""The synthetic completion dataset file (HDF5): schema, streaming writer, lazy reader.

The reader (:class:`CompletionDataset`, :func:`open_dataset`) is here, the checks it makes of a file as it opens
it in :mod:`.store_reading`, the writer and the schema's constants in :mod:`.store_writer` (importable from here
too).

Schema (``format = "spotlights-completion"``, ``format_version = 1``; see docs/dataset.md)
-----------------------------------------------------------------------------------------
Root attributes: ``format``, ``format_version``, ``spotlights_version``, ``config_json``
(the full build configuration), ``seed``, ``sensor_json`` (the sensor model),
``default_rig`` (e.g. ``"cap-32x64-60"``), ``views_per_model``, ``skipped_json``
(meshes that could not be read: ``[{"file", "problem"}]``).

========================== ====================== ======== ==================================================
dataset                    shape                  dtype    meaning
========================== ====================== ======== ==================================================
/models/name               (n_models,)            utf-8    mesh id: relative path without suffix
/models/file               (n_models,)            utf-8    mesh file, relative to the meshes folder
/models/sha256             (n_models,)            utf-8    SHA-256 of the mesh file
/models/category           (n_models,)            utf-8    e.g. hatchback, sedan, suv
/models/split              (n_models,)            utf-8    train / val / test
/models/gt_points          (n_models, 2048, 3)    float32  uniform surface samples, unit frame
/models/gt_dense           (n_models, 16384, 3)   float32  dense uniform surface samples, unit frame
/models/center             (n_models, 3)          float64  object-frame box centre (metres)
/models/radius             (n_models,)            float64  half the box diagonal R (metres)
/models/size               (n_models, 3)          float64  box length, width, height (metres)
/models/source             (n_models,)            utf-8    mesh source (folder) name; multi-source builds only
/models/origin             (n_models,)            utf-8    the mesh a model was made from (its own name for a mesh
                                                           file; an augmented copy's origin); augmented builds only
/models/augment            (n_models,)            utf-8    a copy's transform as JSON ({"mirror", "scale": [sx, sy,
                                                           sz]}), "" for a mesh file; augmented builds only
/models/class              (n_models,)            utf-8    detector class (car, caravan, truck, bus, trailer, other);
                                                           builds with procedural vehicles only (older files: the
                                                           class of the category, see ``classes``)
/rigs/<rig_name>/depths    (n_models, N*M)        float32  Spotlights depths; attr ``rig_json`` (RigSpec.to_dict;
                                                           box-targeted rigs: each model's own box, see rig())
/samples/partial           (n_samples, 256, 3)    float32  partial scan, unit frame; chunked per sample
/samples/model             (n_samples,)           int32    row in /models
/samples/view              (n_samples,)           int32    observation index within the model
/samples/sensor_to_unit    (n_samples, 4, 4)      float64  sensor frame -> unit frame (column vectors); its
                                                           translation is the sensor origin (sensor_origins())
/samples/distance          (n_samples,)           float32  horizontal sensor -> box-centre distance, metres
/samples/azimuth           (n_samples,)           float32  bearing of the box centre in the sensor frame, rad
/samples/heading           (n_samples,)           float32  vehicle yaw in the sensor frame, rad
/samples/n_raw             (n_samples,)           int32    returns on the vehicle before resampling
/samples/n_draws           (n_samples,)           int16    poses drawn until one gave enough returns
/samples/n_rays            (n_samples,)           int32    rays cast for the accepted pose (the window)
========================== ====================== ======== ==================================================

Samples are stored model-major: sample ``m * views_per_model + v`` is view ``v`` of model ``m``.
The samples of a split are those whose model's split equals it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputFileError, ParameterError
from ..geometry.boxes import unit_extents
from ..geometry.rig import RigSpec
from .shard_index import is_shard_index, read_shard_index
from .store_reading import (
    check_same_build,
    check_shard_order,
    int_attribute,
    json_attribute,
    read_tables,
    shared_extra_rigs,
)
from .store_summary import dataset_info
from .store_writer import (
    COMPRESSION,
    FORMAT,
    FORMAT_VERSION,
    OPTIONAL_MODEL_STRINGS,
    SAMPLE_FIELDS,
    SPLITS,
    write_dataset,
    write_rig_group,
)
from .vehicle_classes import class_of_category

__all__ = [
    "COMPRESSION",
    "FORMAT",
    "FORMAT_VERSION",
    "MAX_PARTIAL_POINTS",
    "OPTIONAL_MODEL_STRINGS",
    "SAMPLE_FIELDS",
    "SPLITS",
    "CompletionDataset",
    "int_attribute",
    "json_attribute",
    "open_dataset",
    "write_dataset",
    "write_rig_group",
]


MAX_PARTIAL_POINTS = 65_536
"""Points per partial observation (``dataset build --points``, ``real extract --points``): 256 times the paper's
256, and twice what a car a few metres from a 128-beam LiDAR returns; a build's work unit of 250 views then holds
197 MB of them per worker (2e9 asked for 5.5 TiB)."""


def _joined(tables: list[dict], key: str) -> np.ndarray | None:
    """The shards' table ``key`` concatenated (rows in shard order); None when a shard lacks it."""
    return np.concatenate([t[key] for t in tables]) if all(t[key] is not None for t in tables) else None


class CompletionDataset:
    """Lazy reader of a dataset: one HDF5 file, or a shard index (JSON) and its HDF5 shards,
    read as one logical dataset (global model rows and sample indices); safe to use across
    ``fork`` (handles reopen in a new process).

    Small tables (models, per-sample model index) are read at open; arrays are read on demand.
    Use as a context manager or call :meth:`close`.

    Attributes: ``names``, ``categories``, ``splits`` (n_models,) str; ``center`` (n_models, 3),
    ``radius`` (n_models,), ``size`` (n_models, 3) or None, float64 metres; ``sources``,
    ``origins``, ``augments`` (n_models,) str or None (multi-source / augmented builds);
    ``sample_model``, ``sample_view`` (n_samples,) int64; ``rig_names``, ``default_rig``,
    ``views_per_model``, ``config``, ``sensor``, ``skipped`` (meshes the build could not read: list of
    ``{"file", "problem"}``), ``seed``; ``shards`` (list of shard paths;
    ``[path]`` for a single file).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.exists():
            raise InputFileError(self.path, "no such file")
        if self.path.is_dir():
            raise InputFileError(self.path, "is a folder, expected a dataset file (.h5) or a shard index (.json)")
        self._files: dict = {}
        self._pid = None
        self._gt_cache: dict = {}
        self._meta: dict | None = None
        if is_shard_index(self.path):
            entries = read_shard_index(self.path)
            self.sharded = True
        else:
            entries = [{"path": self.path, "n_models": None, "n_samples": None}]
            self.sharded = False
        self.shards = [e["path"] for e in entries]
        tables = [self._read_tables(k, e) for k, e in enumerate(entries)]
        check_same_build(self.shards, tables)
        if self.sharded:
            check_shard_order(self.path, self.shards, [t["attrs"] for t in tables])
        self._join_tables(tables)
        self._take_build(tables)
        if len(self.sample_model) and (self.sample_model.min() < 0 or self.sample_model.max() >= len(self.names)):
            raise InputFileError(self.path, "/samples/model refers to rows outside /models")

    def _join_tables(self, tables: list[dict]) -> None:
        """The shards' tables joined into the dataset's (global model rows and sample indices)."""
        self.model_offset = np.cumsum([0] + [len(t["names"]) for t in tables]).astype(np.int64)
        self.sample_offset = np.cumsum([0] + [len(t["sample_model"]) for t in tables]).astype(np.int64)
        self.names, self.categories = _joined(tables, "names"), _joined(tables, "categories")
        self.splits = _joined(tables, "splits")
        self.center, self.radius, self.size = (
            _joined(tables, "center"),
            _joined(tables, "radius"),
            _joined(tables, "size"),
        )
        self.sources, self.origins = _joined(tables, "source"), _joined(tables, "origin")
        self.augments = _joined(tables, "augment")
        self.stored_classes = _joined(tables, "class")
        self._classes = None
        self.sample_model = np.concatenate([t["sample_model"] + self.model_offset[k] for k, t in enumerate(tables)])
        self.sample_view = _joined(tables, "sample_view")
        # a rig is the dataset's when every shard holds it (an interrupted add-rig adds it to some only)
        self.rig_names = sorted(set.intersection(*[set(t["rigs"]) for t in tables]))

    def _take_build(self, tables: list[dict]) -> None:
        """The build's attributes, configuration, sensor, skipped meshes and seed (the first shard's; a sharded
        configuration lists the extra rigs every shard holds)."""
        first = tables[0]
        attrs = first["attrs"]
        self.attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in attrs.items()}
        self.default_rig = str(attrs.get("default_rig", self.rig_names[0] if self.rig_names else ""))
        self.views_per_model = first["views_per_model"]
        self.config = dict(first["config"])
        if self.sharded:  # the extra rigs of any shard that every shard holds (an add-rig may be half done)
            union = shared_extra_rigs(self.shards, tables, self.rig_names)
            if "extra_rigs" in self.config:
                self.config["extra_rigs"] = union
        self.sensor = first["sensor"]
        self.skipped = first["skipped"]
        self.seed = first["seed"]

    def _read_tables(self, k: int, entry: dict) -> dict:
        """Small tables and attributes of shard ``k``, validated (:func:`~.store_reading.read_tables`)."""
        path = entry["path"]
        if not path.exists():
            raise InputFileError(path, f"no such file (a shard of {self.path})" if self.sharded else "no such file")
        return read_tables(path, self._h5(k), entry, self.path)

    # --- file handles ---------------------------------------------------------------------
    def _h5(self, k: int = 0):
        """The open HDF5 handle of shard ``k`` (the file itself for a single-file dataset), opened
        on first use in each process."""
        import h5py

        if self._pid != os.getpid():
            self._files = {}
            self._pid = os.getpid()
        f = self._files.get(k)
        if f is None:
            path = self.shards[k]
            try:
                f = h5py.File(path, "r")
            except OSError as exc:
                raise InputFileError(path, f"not a readable HDF5 file ({str(exc).splitlines()[0][:100]})") from None
            self._files[k] = f
        return f

    def handle(self, k: int = 0):
        """The open h5py ``File`` of shard ``k`` (``0``: the file of a single-file dataset), read-only,
        owned by this reader (do not close it)."""
        return self._h5(k)

    def has(self, key: str) -> bool:
        """Whether every shard holds the HDF5 dataset or group ``key`` (e.g. ``"models/gt_dense"``)."""
        return all(key in self._h5(k) for k in range(len(self.shards)))

    def is_open(self) -> bool:
        """Whether this process holds an open handle (DataLoader parents should not)."""
        return self._pid == os.getpid() and bool(self._files)

    def close(self) -> None:
        """Close the HDF5 handles (they reopen on the next access)."""
        if self._pid == os.getpid():
            for f in self._files.values():
                f.close()
        self._files = {}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __getstate__(self):  # picklable for DataLoader workers: the handles are reopened there
        d = dict(self.__dict__)
        d["_files"] = {}
        d["_pid"] = None
        d["_gt_cache"] = {}
        d["_meta"] = None
        return d

    # --- locating rows in shards ----------------------------------------------------------
    def _model_shard(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(shard, local row) of global model rows (K,) int64."""
        k = np.searchsorted(self.model_offset, rows, side="right") - 1
        return k, rows - self.model_offset[k]

    def _sample_shard(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(shard, local index) of global sample indices (K,) int64."""
        k = np.searchsorted(self.sample_offset, idx, side="right") - 1
        return k, idx - self.sample_offset[k]

    def _gather(self, key: str, rows, locate) -> np.ndarray:
        """Rows ``rows`` (K,) of dataset ``key`` across shards, in the given order: contiguous
        runs of each shard read with one h5py call each."""
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        shard, local = locate(rows)
        order = np.lexsort((local, shard))
        out = None
        pos = 0
        s_sorted, l_sorted = shard[order], local[order]
        breaks = np.flatnonzero((np.diff(s_sorted) != 0) | (np.diff(l_sorted) != 1)) + 1
        for run in np.split(np.arange(len(rows)), breaks) if len(rows) else []:
            k, lo, hi = int(s_sorted[run[0]]), int(l_sorted[run[0]]), int(l_sorted[run[-1]]) + 1
            block = self._h5(k)[key][lo:hi]
            if out is None:
                out = np.empty((len(rows),) + block.shape[1:], dtype=block.dtype)
            out[order[pos : pos + len(run)]] = block
            pos += len(run)
        if out is None:
            d = self._h5(0)[key]
            out = np.empty((0,) + d.shape[1:], dtype=d.dtype)
        return out

    def models_array(self, key: str, rows=None) -> np.ndarray:
        """``/models/<key>`` (e.g. ``gt_points`` (K, 2048, 3) f32, ``gt_dense``) for global model
        rows ``rows`` (default: all), in that order."""
        rows = np.arange(self.n_models) if rows is None else rows
        return self._gather(f"models/{key}", rows, self._model_shard)

    def rig_depths(self, name: str | None = None, rows=None) -> np.ndarray:
        """(K, N*M) float32 depths of rig ``name`` (default rig) for model rows ``rows`` (default: all)."""
        name = name or self.default_rig
        if name not in self.rig_names:
            self.rig_spec(name)  # raises a clear error
        rows = np.arange(self.n_models) if rows is None else rows
        return self._gather(f"rigs/{name}/depths", rows, self._model_shard)

    def partials(self, indices) -> np.ndarray:
        """(K, n_points, 3) float32 partial scans of global samples ``indices`` (K,), in that order.
        Raises :class:`InputFileError` naming the file and the sample when one holds NaN or infinite
        coordinates."""
        indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        out = self._gather("samples/partial", indices, self._sample_shard)
        if not np.isfinite(out).all():
            self._refuse_partial(int(indices[np.flatnonzero(~np.isfinite(out).all(axis=(1, 2)))[0]]))
        return out

    def partial(self, index: int) -> np.ndarray:
        """(n_points, 3) float32 partial scan of one global sample (InputFileError when it holds NaN
        or infinite coordinates)."""
        k, i = self._sample_shard(np.array([int(index)]))
        out = self._h5(int(k[0]))["samples/partial"][int(i[0])]
        if not np.isfinite(out).all():
            self._refuse_partial(int(index))
        return out

    def _refuse_partial(self, index: int) -> None:
        """Raise the error for global sample ``index``, whose partial scan is not finite, naming its file."""
        k, i = (int(x[0]) for x in self._sample_shard(np.array([index])))
        raise InputFileError(
            self.shards[k], f"/samples/partial[{i}]: partial scans contain NaN or infinite coordinates"
        )

    def __len__(self) -> int:
        return len(self.sample_model)

    # --- tables ---------------------------------------------------------------------------
    @property
    def n_models(self) -> int:
        """Number of models (rows of /models)."""
        return len(self.names)

    @property
    def n_samples(self) -> int:
        """Number of samples (rows of /samples)."""
        return len(self.sample_model)

    def _check_split(self, split: str) -> str:
        if split not in SPLITS:
            raise ParameterError(f"unknown split {split!r}; choose from {', '.join(SPLITS)}")
        return split

    def split_models(self, split: str) -> np.ndarray:
        """(K,) int64 rows of /models in ``split``."""
        return np.flatnonzero(self.splits == self._check_split(split)).astype(np.int64)

    def split_indices(self, split: str) -> np.ndarray:
        """(S,) int64 sample indices of ``split``, in storage order (model-major)."""
        in_split = self.splits == self._check_split(split)
        return np.flatnonzero(in_split[self.sample_model]).astype(np.int64)

    @property
    def extents(self) -> np.ndarray:
        """(n_models, 3) float64 box half-extents in each model's unit frame, ``size / (2 R)``
        (``|e| = 1``): what a box-targeted rig is aimed at. Raises InputFileError for files
        without ``/models/size``."""
        if self.size is None:
            raise InputFileError(
                self.path,
                "has no /models/size, so box-targeted rigs cannot be resolved (rebuild it with this spotlights)",
            )
        return unit_extents(self.size, self.radius)

    def rig_spec(self, name: str | None = None):
        """The :class:`~spotlights.geometry.rig.RigSpec` stored under ``name`` (default: the default rig).

        For a cap rig, ``rig_spec(name).for_box(None)`` is the rig; for a box-targeted rig
        each model's rig is ``rig_spec(name).for_box(extents[model])`` (:meth:`rig`)."""
        return RigSpec.from_dict(self.rig_dict(name))

    def rig_dict(self, name: str | None = None) -> dict:
        """The stored ``rig_json`` of rig ``name`` (default rig) as a dict (``RigSpec.to_dict()``)."""
        name = name or self.default_rig
        if name not in self.rig_names:
            raise ParameterError(f"{self.path}: no rig {name!r}; stored rigs: {', '.join(self.rig_names)}")
        return json_attribute(self.path, self._h5()[f"rigs/{name}"].attrs, "rig_json", dict, where=f"/rigs/{name} ")

    def rig(self, name: str | None = None, model: int | None = None):
        """The :class:`~spotlights.geometry.rig.Rig` whose rays gave model row ``model``'s depths
        under ``name`` (default: the default rig).

        Cap rigs are the same for every model (``model`` may be omitted); a box-targeted rig
        is resolved for that model's box (``spec.for_box(extents[model])``), so ``model``
        is required. ``decode(ground_truth(model, name)["gt_depths"], rig(name, model))``
        gives the model's Spotlights points.
        """
        spec = self.rig_spec(name)
        if not spec.needs_box:
            return spec.for_box(None)
        if model is None:
            raise ParameterError(
                f"{self.path}: rig {spec.name} is aimed at each model's box; give the model row "
                "(ds.rig(name, model)) or use ds.rig_spec(name) with ds.extents"
            )
        if not (0 <= int(model) < self.n_models):
            raise ParameterError(f"model row {model} out of range (the dataset has {self.n_models} models)")
        return spec.for_box(self.extents[int(model)])

    def directions(self, name: str | None, models) -> np.ndarray:
        """(K, N*M, 3) float64 unit ray directions of rig ``name`` for model rows ``models`` (K,),
        unit frame (vectorised; cap rigs: the same rays broadcast). Origins: ``rig_spec(name).origins``."""
        spec = self.rig_spec(name)
        rows = np.asarray(models, dtype=np.int64).reshape(-1)
        if not spec.needs_box:
            return spec.directions_for_boxes(np.zeros((len(rows), 3)))
        return spec.directions_for_boxes(self.extents[rows])

    @property
    def classes(self) -> np.ndarray:
        """(n_models,) str detector class of every model (``car``, ``caravan``, ``truck``, ``bus``,
        ``trailer``, ``other``): ``/models/class`` where the file has it, else the class of each
        model's category (sedan, hatchback, suv: car; files built before classes existed)."""
        if self._classes is None:
            if self.stored_classes is not None:
                self._classes = self.stored_classes
            else:
                self._classes = np.array([class_of_category(c) for c in self.categories])
        return self._classes

    # --- arrays ---------------------------------------------------------------------------
    # Per-model ground truth is shared by all views: keep the most recent models in memory
    # (0.2 MB each at the default sizes).
    GT_CACHE_MODELS = 256

    def ground_truth(self, model: int, rig: str | None = None) -> dict:
        """Ground truth of model row ``model``: ``gt_points`` (2048, 3) f32, ``gt_dense`` (16384, 3) f32,
        ``gt_depths`` (N*M,) f32 of ``rig`` (default rig), all in the unit frame.

        Cached per (model, rig); the returned arrays are read-only (copy before modifying)."""
        name = rig or self.default_rig
        key = (int(model), name)
        hit = self._gt_cache.pop(key, None)
        if hit is None:
            if name not in self.rig_names:
                self.rig(name)  # raises a clear error
            if not (0 <= key[0] < self.n_models):
                raise ParameterError(f"model row {model} out of range (the dataset has {self.n_models} models)")
            k, row = (int(x[0]) for x in self._model_shard(np.array([key[0]])))
            f = self._h5(k)
            hit = {
                "gt_points": f["models/gt_points"][row],
                "gt_dense": f["models/gt_dense"][row],
                "gt_depths": f[f"rigs/{name}/depths"][row],
            }
            for a in hit.values():
                a.setflags(write=False)
            while len(self._gt_cache) >= self.GT_CACHE_MODELS:
                self._gt_cache.pop(next(iter(self._gt_cache)))
        self._gt_cache[key] = hit  # most recent last
        return dict(hit)

    def sample(self, index: int, rig: str | None = None) -> dict:
        """One sample (global index): its partial scan, its model's ground truth and its metadata.

        Returns a dict: ``partial`` (256, 3) f32, ``gt_points`` (2048, 3) f32, ``gt_dense`` (16384, 3) f32,
        ``gt_depths`` (N*M,) f32 (unit frame / depths), ``model`` (name), ``model_index``, ``category``,
        ``class`` (detector class, :attr:`classes`), ``split``, ``view``, ``sensor_to_unit`` (4, 4) f64, ``distance``, ``azimuth``, ``heading``, ``n_raw``,
        ``rig`` (rig name), ``extents`` (3,) f64: the model's box half-extents in the unit frame
        (``size / 2R``; absent for files without /models/size). Decode ``gt_depths`` with
        ``rig(out["rig"], out["model_index"])`` (box-targeted rigs use the model's own box).
        """
        n = self.n_samples
        if not (-n <= int(index) < n):
            raise ParameterError(f"sample index {index} out of range (the dataset has {n} samples)")
        i = int(index) % n
        meta = self.metadata()
        m = int(self.sample_model[i])
        out = {"partial": self.partial(i)}
        out.update(self.ground_truth(m, rig))
        out.update(
            {
                "model": str(self.names[m]),
                "model_index": m,
                "category": str(self.categories[m]),
                "class": str(self.classes[m]),
                "split": str(self.splits[m]),
                "view": int(self.sample_view[i]),
                "sensor_to_unit": meta["sensor_to_unit"][i].copy(),
                "distance": float(meta["distance"][i]),
                "azimuth": float(meta["azimuth"][i]),
                "heading": float(meta["heading"][i]),
                "n_raw": int(meta["n_raw"][i]),
                "rig": rig or self.default_rig,
            }
        )
        if self.size is not None:
            out["extents"] = self.extents[m]
        return out

    def metadata(self) -> dict:
        """Every per-sample field except ``partial`` (``sensor_to_unit`` (n, 4, 4), ``distance``, ...),
        read whole on first use (~150 bytes per sample) so that per-sample access needs no HDF5 read."""
        if self._meta is None:
            parts = [self._h5(k)["samples"] for k in range(len(self.shards))]
            self._meta = {k: np.concatenate([s[k][()] for s in parts]) for k in SAMPLE_FIELDS if k in parts[0]}
            if "model" in self._meta:
                self._meta["model"] = self.sample_model.astype(self._meta["model"].dtype)  # global rows
        return self._meta

    def sensor_origins(self, indices=None) -> np.ndarray:
        """(K, 3) float64 position of the LiDAR's optical centre (the origin of the sensor frame) in the
        unit frame of each of global samples ``indices`` (default: every sample): the translation column
        of ``/samples/sensor_to_unit`` (no field of its own: it is that column, so it cannot disagree with
        it). Every row NaN for a file without ``/samples/sensor_to_unit``."""
        meta = self.metadata()
        idx = np.arange(self.n_samples) if indices is None else np.asarray(indices, dtype=np.int64).reshape(-1)
        if "sensor_to_unit" not in meta:
            return np.full((len(idx), 3), np.nan)
        return np.array(meta["sensor_to_unit"][idx, :3, 3], dtype=np.float64)

    def to_sensor(self, index: int, points: np.ndarray) -> np.ndarray:
        """Map (K, 3) unit-frame points of sample ``index`` (e.g. a completion) back into its LiDAR
        sensor frame (metres): the inverse of ``/samples/sensor_to_unit``. Returns (K, 3) float64."""
        m = np.linalg.inv(self.metadata()["sensor_to_unit"][int(index)])
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return p @ m[:3, :3].T + m[:3, 3]

    def info(self) -> dict:
        """Summary: splits, categories, counts, shapes and dtypes of every dataset (a sharded
        dataset's logical shapes: rows of all shards), build config; for a sharded dataset also
        ``shards`` (their files) and ``file_size_bytes`` of the index and all shards
        (:func:`~spotlights.data.store_summary.dataset_info`)."""
        return dataset_info(self)


def open_dataset(path: str | os.PathLike) -> CompletionDataset:
    """Open a completion dataset for reading: an HDF5 file, or the index (JSON) of a sharded
    dataset (validated; raises InputFileError)."""
    return CompletionDataset(path)
