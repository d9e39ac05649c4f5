"""The one writer of the completion dataset file and the constants of its schema (the schema itself:
:mod:`spotlights.data.store`, which reads the file and re-exports all of this)."""

from __future__ import annotations

import json

import numpy as np

from ..outputs import hdf5_output

FORMAT = "spotlights-completion"
FORMAT_VERSION = 1
SPLITS = ("train", "val", "test")
# HDF5 compression of every array dataset (portable: gzip is in every HDF5 build).
COMPRESSION = dict(compression="gzip", compression_opts=4, shuffle=True)
# The per-sample arrays (/samples/*: one small chunk per partial scan, most of a build's writes): uncompressed. On
# 7,900 samples of the cars that took 7.1x less CPU to write than gzip and 4.4x less to read all, for a file
# 24% larger, the arrays read back the same (docs/studies/speed.md, benchmarks/dataset_compression.py). lzf
# measured faster than gzip too, but its output is not a function of its input alone (h5py's liblzf leaves its
# hash table uninitialised: the same arrays gave different bytes), and a build's bytes must not depend on anything
# but its seed and config.
SAMPLE_COMPRESSION: dict = {}

# Per-model string columns written only by builds that use them (multi-source, augmentation,
# procedural vehicles: the detector class of every model).
OPTIONAL_MODEL_STRINGS = ("source", "origin", "augment", "class")

SAMPLE_FIELDS = {  # name -> (dtype, per-sample shape or None for scalars)
    "model": ("int32", ()),
    "view": ("int32", ()),
    "sensor_to_unit": ("float64", (4, 4)),
    "distance": ("float32", ()),
    "azimuth": ("float32", ()),
    "heading": ("float32", ()),
    "n_raw": ("int32", ()),
    "n_draws": ("int16", ()),
    "n_rays": ("int32", ()),
}


def write_dataset(
    path, *, attrs: dict, models: dict, rigs: list, n_points: int, views_per_model: int, sample_blocks
) -> None:
    """Write a complete dataset file at ``path`` (use a temporary name; the caller renames it).

    Parameters
    ----------
    attrs : root attributes (str / int values).
    models : ``name, file, sha256, category, split`` (lists of str, one per model), optionally
        :data:`OPTIONAL_MODEL_STRINGS` (``source``, ``origin``, ``augment``, ``class``), and
        ``gt_points`` (n, G, 3) f32, ``gt_dense`` (n, D, 3) f32, ``center`` (n, 3), ``radius`` (n,),
        ``size`` (n, 3) arrays.
    rigs : list of ``(Rig, depths (n_models, N*M) float32)``.
    n_points : points per partial observation.
    views_per_model : views per model; n_samples = n_models * views_per_model.
    sample_blocks : iterable of dicts, in sample order, each with ``start`` (first sample index)
        and arrays ``partial`` (B, n_points, 3) and every key of :data:`SAMPLE_FIELDS` (B, ...);
        consumed one block at a time (streaming: memory stays one block).
    """
    import h5py

    n_models = len(models["name"])
    n_samples = n_models * views_per_model
    strt = h5py.string_dtype("utf-8")
    with hdf5_output(path, "w", libver=("earliest", "v110")) as (f, check):
        for k, v in attrs.items():
            f.attrs[k] = v
        g = f.create_group("models", track_order=False)
        for k in ("name", "file", "sha256", "category", "split") + OPTIONAL_MODEL_STRINGS:
            if k in models:
                g.create_dataset(k, data=np.array(models[k], dtype=object), dtype=strt, track_times=False)
        for k, dt in (("gt_points", "float32"), ("gt_dense", "float32")):
            a = np.asarray(models[k], dtype=dt)
            g.create_dataset(k, data=a, chunks=(1,) + a.shape[1:], track_times=False, **COMPRESSION)
        for k in ("center", "radius", "size"):
            g.create_dataset(k, data=np.asarray(models[k], dtype=np.float64), track_times=False)
        rg = f.create_group("rigs")
        for rig, depths in rigs:
            write_rig_group(rg, rig, depths)
        s = f.create_group("samples")
        ds = {
            "partial": s.create_dataset(
                "partial",
                shape=(n_samples, n_points, 3),
                dtype="float32",
                chunks=(1, n_points, 3),
                track_times=False,
                **SAMPLE_COMPRESSION,
            )
        }
        for k, (dt, shp) in SAMPLE_FIELDS.items():
            rows = max(1, min(n_samples, 4096 if not shp else 256))
            ds[k] = s.create_dataset(
                k, shape=(n_samples,) + shp, dtype=dt, chunks=(rows,) + shp, track_times=False, **SAMPLE_COMPRESSION
            )
        written = 0
        for block in sample_blocks:
            a = int(block["start"])
            b = a + len(block["partial"])
            if a != written or b > n_samples:
                raise RuntimeError(f"sample blocks out of order: got [{a}, {b}) after {written}")
            for k, d in ds.items():
                d[a:b] = block[k]
            check()  # a full disk stops the write here
            written = b
        if written != n_samples:
            raise RuntimeError(f"only {written} of {n_samples} samples were written")


def write_rig_group(rigs_group, rig, depths) -> None:
    """Create ``/rigs/<rig.name>`` in an open HDF5 ``/rigs`` group: attr ``rig_json`` and ``depths``.

    rig : a cap :class:`~spotlights.geometry.rig.Rig` or a :class:`~spotlights.geometry.rig.RigSpec`
        (box-targeted: ``rig_json`` holds the spec, without a box; each model's box is in /models).
    depths : (n_models, N*M) float32.
    """
    sub = rigs_group.create_group(rig.name)
    sub.attrs["rig_json"] = json.dumps(rig.to_dict(), sort_keys=True)
    d = np.asarray(depths, dtype=np.float32)
    sub.create_dataset("depths", data=d, chunks=(1, d.shape[1]), track_times=False, **COMPRESSION)
