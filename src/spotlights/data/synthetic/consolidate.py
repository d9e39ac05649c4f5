"""Writing a build's output from its parts folder: one HDF5 file, or HDF5 shards plus an index.

The parts folder holds one ``.npz`` per work unit (:mod:`.runner`). :func:`write_output_file`
streams the parts of a range of models, in sample order, into one ``spotlights-completion``
HDF5 file (memory: one block of views at a time). A single-file dataset is that file over all
models; a sharded dataset (``--shard-size N``) is several such files, each a valid dataset of
its own (whole models, its own ``/models`` rows, ``/samples/model`` local to it), plus an index
(JSON, ``format = "spotlights-completion-shards"``) listing them in order. Readers
(:func:`spotlights.data.store.open_dataset`) see one logical dataset either way, and
:func:`merge_shards` turns shards into the single file a build without ``--shard-size`` writes,
byte for byte.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..._version import __version__
from ...errors import InputFileError, SpotlightsError
from ...geometry.rig import RigSpec
from ...outputs import atomic_output
from ..shard_index import shard_paths, write_index
from ..store import FORMAT, FORMAT_VERSION, OPTIONAL_MODEL_STRINGS, SAMPLE_FIELDS, open_dataset, write_dataset
from .config import BuildConfig, parse_rig


def part_name(unit: tuple) -> str:
    """The file name of a work unit's part: ``gt-MMMMM.npz`` or ``obs-MMMMM-AAAAAAA-BBBBBBB.npz``."""
    if unit[0] == "gt":
        return f"gt-{unit[1]:05d}.npz"
    return f"obs-{unit[1]:05d}-{unit[2]:07d}-{unit[3]:07d}.npz"


def save_npz_atomic(path: Path, arrays: dict) -> None:
    with atomic_output(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())


def read_part(parts: Path, unit: tuple, recompute: Callable[[tuple], None] | None = None) -> dict:
    """The arrays of a unit's part. A part that cannot be read (a damaged disk) is deleted and
    recomputed by ``recompute(unit)`` when given, else reported (rerunning the build redoes it)."""
    path = parts / part_name(unit)
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except Exception:
        path.unlink(missing_ok=True)
        if recompute is None:
            raise SpotlightsError(f"{path}: unreadable part, deleted; run the build again to recompute it") from None
        recompute(unit)
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}


ATTR_ORDER = (
    "format",
    "format_version",
    "spotlights_version",
    "config_json",
    "seed",
    "sensor_json",
    "default_rig",
    "views_per_model",
    "skipped_json",
)


def root_attrs(cfg: BuildConfig, skipped: list) -> dict:
    """The root attributes of a dataset file of this build."""
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "spotlights_version": __version__,
        "config_json": json.dumps(cfg.to_dict(), sort_keys=True),
        "seed": int(cfg.seed),
        "sensor_json": json.dumps(cfg.sensor, sort_keys=True),
        "default_rig": cfg.rigs[0].name,
        "views_per_model": int(cfg.views),
        "skipped_json": json.dumps(skipped, sort_keys=True),
    }


def write_output_file(
    path: Path,
    cfg: BuildConfig,
    entries: list,
    rows: range,
    parts: Path,
    units: list,
    skipped: list,
    extra_attrs: dict | None = None,
    recompute=None,
    progress: bool = False,
) -> None:
    """Write the models ``rows`` (global rows, consecutive) of a build into one dataset file ``path``
    (under a temporary name, renamed when complete).

    entries : the :class:`~spotlights.data.synthetic.catalogue.ModelEntry` of every model (global order).
    units : the build's work units; those of ``rows`` are streamed, in sample order.
    extra_attrs : root attributes added (a shard's position). ``/samples/model`` is local to the
        file (row in its ``/models``).
    """
    sel = [entries[m] for m in rows]
    gts = [read_part(parts, ("gt", m), recompute) for m in rows]
    model_arrays = _model_arrays(cfg, sel, gts)
    rig_arrays = [(r, np.stack([g[f"depths_{i}"] for g in gts])) for i, r in enumerate(cfg.rigs)]
    del gts
    obs_units = [u for u in units if u[0] == "obs" and u[1] in rows]
    attrs = {**root_attrs(cfg, skipped), **(extra_attrs or {})}
    with atomic_output(path, suffix=".h5") as tmp:
        write_dataset(
            tmp,
            attrs=attrs,
            models=model_arrays,
            rigs=rig_arrays,
            n_points=cfg.n_points,
            views_per_model=cfg.views,
            sample_blocks=_sample_blocks(path, cfg, rows, parts, obs_units, recompute, progress),
        )


def _model_arrays(cfg: BuildConfig, sel: list, gts: list[dict]) -> dict:
    """The ``/models`` columns of the entries ``sel`` and their ground-truth parts ``gts``."""
    model_arrays = {
        "name": [e.name for e in sel],
        "file": [e.file for e in sel],
        "sha256": [e.sha256 for e in sel],
        "category": [e.category for e in sel],
        "split": [e.split for e in sel],
        "gt_points": np.stack([g["gt_points"] for g in gts]),
        "gt_dense": np.stack([g["gt_dense"] for g in gts]),
        "center": np.stack([g["center"] for g in gts]),
        "radius": np.array([float(g["radius"]) for g in gts]),
        "size": np.stack([g["size"] for g in gts]),
    }
    model_arrays.update(_optional_model_columns(cfg, sel))
    return model_arrays


def _optional_model_columns(cfg: BuildConfig, sel: list) -> dict:
    """The ``/models`` columns only some builds have: ``source`` (several sources or procedural
    models), ``class`` (procedural models), ``origin`` and ``augment`` (augmented copies)."""
    cols = {}
    if cfg.sources or cfg.procedural:
        cols["source"] = [e.source for e in sel]
    if cfg.procedural:
        cols["class"] = [e.vclass for e in sel]
    if cfg.augment:
        cols["origin"] = [e.origin or e.name for e in sel]
        cols["augment"] = [json.dumps(e.augment, sort_keys=True) if e.augment else "" for e in sel]
    return cols


def _sample_blocks(path: Path, cfg: BuildConfig, rows: range, parts: Path, obs_units: list, recompute, progress: bool):
    """The observation parts of ``rows``, checked against the plan, one block at a time, with
    ``model`` made local to the file and ``start`` (the block's first sample row in it)."""
    lo = rows.start
    bar = tqdm(
        total=len(rows) * cfg.views,
        desc="write " + path.name,
        unit="sample",
        disable=not progress,
        dynamic_ncols=True,
    )
    try:
        for u in obs_units:
            a = read_part(parts, u, recompute)
            if a["partial"].shape != (u[3] - u[2], cfg.n_points, 3) or np.any(a["model"] != u[1]):
                raise SpotlightsError(f"{parts / part_name(u)}: part does not match the plan; delete it and rerun")
            if lo:
                a["model"] = (a["model"] - lo).astype(a["model"].dtype)
            a["start"] = (u[1] - lo) * cfg.views + u[2]
            yield a
            bar.update(u[3] - u[2])
    finally:
        bar.close()


# ----------------------------------------------------------------------------------------------
# shards
# ----------------------------------------------------------------------------------------------
def shard_groups(n_models: int, views: int, shard_size: int) -> list[range]:
    """Consecutive model rows per shard: whole models, at most ``shard_size`` samples per shard
    (a model with more views than that gets a shard of its own)."""
    per = max(1, int(shard_size) // max(1, int(views)))
    return [range(a, min(n_models, a + per)) for a in range(0, n_models, per)]


def check_index_path(out: Path) -> None:
    """A sharded dataset's ``--out`` is its index: a ``.json`` name."""
    if out.suffix.lower() != ".json":
        raise InputFileError(
            out,
            "with --shard-size the output is the shard index: name it NAME.json (the shards "
            "are written beside it as NAME-00000-of-0000N.h5)",
        )


def write_build_index(index: Path, shards: list[Path], counts: list[tuple[int, int]], cfg: BuildConfig) -> None:
    """The index of a sharded build (:func:`spotlights.data.shard_index.write_index`)."""
    write_index(index, shards, counts, cfg.views, cfg.seed, FORMAT, FORMAT_VERSION)


def shard_jobs(index: Path, cfg: BuildConfig, n_models: int, shard_size: int) -> list[dict]:
    """The shards of a build: ``[{"path", "rows", "attrs"}]`` (attrs: the shard's position)."""
    groups = shard_groups(n_models, cfg.views, shard_size)
    paths = shard_paths(index, len(groups))
    return [
        {
            "path": p,
            "rows": g,
            "attrs": {
                "shard_index": k,
                "shard_count": len(groups),
                "shard_model_offset": g.start,
                "shard_sample_offset": g.start * cfg.views,
            },
        }
        for k, (p, g) in enumerate(zip(paths, groups))
    ]


# ----------------------------------------------------------------------------------------------
# merge
# ----------------------------------------------------------------------------------------------
def merge_shards(index: str | Path, out: str | Path, progress: bool = True, overwrite: bool = False) -> dict:
    """Turn a sharded dataset into one HDF5 file: the same bytes as a build of the same
    configuration without ``--shard-size`` (the same arrays, attributes and layout), streamed one
    shard at a time. Written under a temporary name and renamed onto ``out``.

    Returns ``{"out", "n_models", "n_samples", "n_shards", "file_size"}``.
    """
    index, out = Path(index), Path(out)
    if out.exists() and not overwrite:
        raise InputFileError(out, "already exists; pass --overwrite to replace it")
    if out.resolve() == index.resolve():
        raise InputFileError(out, "is the index itself; write the merged file under another name")
    with open_dataset(index) as ds:
        if not ds.sharded:
            raise InputFileError(index, "is a single-file dataset already (nothing to merge)")
        n = ds.n_models
        model_arrays = {}
        for k in ("name", "file", "sha256", "category", "split", *OPTIONAL_MODEL_STRINGS):
            if ds.has(f"models/{k}"):
                model_arrays[k] = [x.decode() if isinstance(x, bytes) else str(x) for x in ds.models_array(k)]
        for k in ("gt_points", "gt_dense", "center", "radius", "size"):
            model_arrays[k] = ds.models_array(k)
        rigs = []
        for name in sorted(ds.rig_names):
            spec = RigSpec.from_dict(ds.rig_dict(name))
            rigs.append((spec if spec.needs_box else spec.for_box(None), ds.rig_depths(name)))
        # the attributes in the order a build writes them (creation order shapes the file's bytes)
        first = [k for k in ATTR_ORDER if k in ds.attrs]
        attrs = {
            k: ds.attrs[k] for k in first + sorted(k for k in ds.attrs if k not in first and not k.startswith("shard_"))
        }
        views = ds.views_per_model
        fields = ["partial", *SAMPLE_FIELDS]

        def blocks():
            bar = tqdm(
                total=ds.n_samples, desc="merge " + out.name, unit="sample", disable=not progress, dynamic_ncols=True
            )
            try:
                for k in range(len(ds.shards)):
                    s = ds.handle(k)["samples"]
                    m0, s0 = int(ds.model_offset[k]), int(ds.sample_offset[k])
                    step = max(1, views)
                    for a in range(0, s["partial"].shape[0], step):
                        b = min(s["partial"].shape[0], a + step)
                        block = {f: s[f][a:b] for f in fields}
                        block["model"] = (block["model"] + m0).astype(block["model"].dtype)
                        block["start"] = s0 + a
                        yield block
                        bar.update(b - a)
            finally:
                bar.close()

        order = _rig_order(ds)
        rigs = [rigs[sorted(ds.rig_names).index(name)] for name in order]
        with atomic_output(out, suffix=".h5") as tmp:
            write_dataset(
                tmp,
                attrs=attrs,
                models=model_arrays,
                rigs=rigs,
                n_points=ds.partial(0).shape[0],
                views_per_model=views,
                sample_blocks=blocks(),
            )
        return {
            "out": str(out),
            "n_models": n,
            "n_samples": ds.n_samples,
            "n_shards": len(ds.shards),
            "file_size": out.stat().st_size,
        }


def _rig_order(ds) -> list[str]:
    """Rig groups in the order a build writes them: the default rig, the config's extra rigs."""
    cfg = ds.config
    wanted = [ds.default_rig] + [r for r in (cfg.get("extra_rigs") or [])]
    names = []
    for r in wanted:
        try:
            name = parse_rig(r).name
        except SpotlightsError:
            name = r
        if name in ds.rig_names and name not in names:
            names.append(name)
    return names + [r for r in sorted(ds.rig_names) if r not in names]
