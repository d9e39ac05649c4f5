"""The summary of an open completion dataset (:meth:`spotlights.data.store.CompletionDataset.info`, ``dataset
info``): counts per split and category, the build's settings, and the shape and dtype of every HDF5 dataset."""

from __future__ import annotations

import numpy as np

from .store_writer import FORMAT, FORMAT_VERSION, SPLITS

__all__ = ["dataset_info"]


def _category_counts(categories) -> dict[str, int]:
    """{category: count} of the (K,) str ``categories``, sorted by name."""
    cats: dict[str, int] = {}
    for c in categories:
        cats[str(c)] = cats.get(str(c), 0) + 1
    return dict(sorted(cats.items()))


def _dataset_shapes(ds, f) -> dict:
    """{"/group/name": {"shape", "dtype"}} of every HDF5 dataset of ``f`` (the first file of ``ds``); a sharded
    dataset's logical shapes (rows of all shards) and only the rigs every shard holds."""
    import h5py

    shapes = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            shapes["/" + name] = {
                "shape": list(obj.shape),
                "dtype": str(obj.dtype) if obj.dtype.kind != "O" else "str",
            }

    f.visititems(visit)
    if ds.sharded:
        for name, d in shapes.items():
            if name.startswith("/samples/"):
                d["shape"][0] = ds.n_samples
            elif name.startswith(("/models/", "/rigs/")) and d["shape"]:
                d["shape"][0] = ds.n_models
        shapes = {k: v for k, v in shapes.items() if not k.startswith("/rigs/") or k.split("/")[2] in ds.rig_names}
    return shapes


def dataset_info(ds) -> dict:
    """JSON-ready summary of the open :class:`~spotlights.data.store.CompletionDataset` ``ds``: path, file size in
    bytes (a sharded dataset: the index and all shards), format, version, seed, counts, categories, classes, per
    split its models, samples and categories, rigs (rays each), skipped meshes, sensor, build config and the
    shapes and dtypes of every dataset (:func:`_dataset_shapes`); a sharded dataset's also ``shards``."""
    f = ds.handle()
    shapes = _dataset_shapes(ds, f)
    splits = {}
    for sp in SPLITS:
        rows = ds.split_models(sp)
        splits[sp] = {
            "models": int(len(rows)),
            "samples": int(len(rows) * ds.views_per_model),
            "categories": _category_counts(ds.categories[rows]),
        }
    size = ds.path.stat().st_size + (sum(p.stat().st_size for p in ds.shards) if ds.sharded else 0)
    out = {
        "path": str(ds.path),
        "file_size_bytes": size,
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "spotlights_version": str(f.attrs.get("spotlights_version", "")),
        "seed": ds.seed,
        "n_models": ds.n_models,
        "n_samples": ds.n_samples,
        "views_per_model": ds.views_per_model,
        "categories": _category_counts(ds.categories),
        "classes": {str(c): int(k) for c, k in zip(*np.unique(ds.classes, return_counts=True))},
        "splits": splits,
        "default_rig": ds.default_rig,
        "rigs": {n: int(f[f"rigs/{n}/depths"].shape[1]) for n in ds.rig_names},
        "skipped": ds.skipped,
        "sensor": ds.sensor,
        "config": ds.config,
        "datasets": shapes,
    }
    if ds.sharded:
        out["shards"] = [str(p) for p in ds.shards]
    return out
