"""``dataset add-rig``: one more rig's ground-truth depths for every model of an existing file."""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ...distributed import DEFAULT_RETRIES, check_backend, import_ray, ray_session
from ...errors import InputFileError, ParameterError
from ...geometry.rig import Rig, RigSpec
from ...locks import exclusive_lock
from ...outputs import atomic_output, hdf5_output
from ...timing import StageTimer
from ..store import json_attribute, open_dataset, write_rig_group
from .catalogue import discover_sources
from .config import BuildConfig, parse_rig
from .ray_backend import RayBuild
from .runner import default_log, map_units, worker_state
from .simulate import model_depths


# ----------------------------------------------------------------------------------------------
# adding a rig to an existing dataset file
# ----------------------------------------------------------------------------------------------
@dataclass
class AddRigReport:
    """What :func:`add_rig` did: the rig added, counts, seconds, the file size (bytes)."""

    out: str
    rig: str
    n_models: int
    n_rays: int
    hit_ratio: float
    seconds_depths: float = 0.0
    seconds_write: float = 0.0
    file_size: int = 0
    already_present: bool = False


def _add_rig_unit(m: int) -> tuple[int, np.ndarray]:
    """Worker: one model's depths for the rig being added (:func:`worker_state` holds the job)."""
    job = worker_state()
    return m, model_depths(job["cfg"], job["entries"][m], job["stored"], m, job["rig"])


def add_rig(
    path: str | os.PathLike,
    rig: str | Rig | RigSpec,
    meshes: str | os.PathLike | None = None,
    workers: int | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    backend: str = "local",
    ray_address: str | None = None,
    retries: int = DEFAULT_RETRIES,
) -> AddRigReport:
    """Add the ground-truth depths of one more rig to an existing dataset file, without rebuilding it.

    The depths are exactly those a build with ``--rig RIG`` would have stored: every model's
    mesh is loaded again (``config_json`` records the meshes folder(s), manifest, axes and scale;
    an augmented copy is made again from ``/models/origin`` and ``/models/augment``;
    each file must still have the SHA-256 in ``/models/sha256``), normalised by its box
    (checked against ``/models/center`` and ``/models/radius``) and encoded with
    ``MeshProbe(mesh, norm).encode(rig)``; box-targeted specs use each model's own box. The
    group ``/rigs/<rig.name>`` is written with ``rig_json`` and ``config_json``'s
    ``extra_rigs`` gains the rig's name (so the file's config rebuilds it identically).

    Atomic: the file is copied beside itself, the group added to the copy, and the copy renamed
    onto ``path``; an interrupted run leaves ``path`` untouched (rerun it). The bytes do not
    depend on ``workers``.

    Parameters
    ----------
    path : dataset file (``spotlights-completion``).
    rig : rig name or shorthand (see :func:`parse_rig`), a Rig or a RigSpec.
    meshes : the meshes folder (default: the one ``config_json`` records); for a dataset built
        from several sources, a list with one folder per source, in the build's order.
    workers : processes (default: all cores); Ray: CPUs of the local instance it starts.
    backend : ``"local"`` (process pool) or ``"ray"`` (one task per model on a Ray cluster).
    ray_address : ``"auto"`` / ``"HOST:PORT"``: join that cluster; None: a local instance.
    retries : Ray only: retries of a task that fails other than by bad input.

    A sharded dataset (``path`` its index) gets the group in every shard (each rewritten
    atomically; a rerun after an interruption completes the shards still without it).

    Returns
    -------
    :class:`AddRigReport` (``already_present`` when the file holds the identical rig already).

    A second ``add_rig`` on the same file while one runs raises SpotlightsError (a lock file
    ``.NAME.lock`` beside it while it runs), instead of silently losing one of the two rigs.
    """
    path = Path(path)
    rig = parse_rig(rig)
    if check_backend(backend) == "ray":
        import_ray()  # before anything else: one line saying how to install it
    open_dataset(path).close()  # a missing or foreign file fails before a lock file is made beside it
    # Two add-rig runs on one file would each copy it and rename their copy onto it: the last
    # rename would drop the other's rig. A lock beside the file makes the second one fail.
    with exclusive_lock(
        path.with_name(f".{path.name}.lock"),
        f"{path}: another 'dataset add-rig' is rewriting this file right now",
        remove=True,  # nothing stays beside the user's dataset
    ):
        return _add_rig_locked(path, rig, meshes, workers, progress, log or default_log, backend, ray_address, retries)


def _add_rig_locked(
    path: Path, rig, meshes, workers, progress, log, backend="local", ray_address=None, retries=DEFAULT_RETRIES
) -> AddRigReport:
    """:func:`add_rig` once the file's lock is held."""
    timer = StageTimer()
    with open_dataset(path) as ds:
        cfg_dict = dict(ds.config)
        shards = list(ds.shards)
        offsets = [int(x) for x in ds.model_offset]
        present = _rig_presence(ds, shards, rig)
        if all(present):
            return AddRigReport(
                str(path),
                rig.name,
                ds.n_models,
                rig.n_rays,
                float("nan"),
                already_present=True,
                file_size=ds.info()["file_size_bytes"],
            )
        stored = _stored_models(ds)
    cfg = _build_config(path, cfg_dict, meshes)
    entries = _model_entries(cfg, stored)
    depths = _rig_depths(cfg, entries, stored, rig, workers, progress, backend, ray_address, retries)
    timer.lap("depths")
    cfg_dict["extra_rigs"] = [r for r in (cfg_dict.get("extra_rigs") or []) if r != rig.name] + [rig.name]
    _write_rig_to_shards(shards, present, offsets, rig, depths, cfg_dict)
    hit = float(np.mean(depths > 0))
    with open_dataset(path) as ds:
        size = ds.info()["file_size_bytes"]
    return AddRigReport(
        str(path),
        rig.name,
        len(stored["names"]),
        rig.n_rays,
        hit,
        seconds_depths=timer.seconds["depths"],
        seconds_write=timer.lap("write"),
        file_size=size,
    )


def _rig_presence(ds, shards: list, rig) -> list[bool]:
    """Per shard: whether it holds ``/rigs/<rig.name>`` already (an InputFileError if that one differs)."""
    want_json = json.loads(json.dumps(rig.to_dict()))
    present = [f"rigs/{rig.name}" in ds.handle(k) for k in range(len(shards))]
    for k in range(len(shards)):
        stored = ds.handle(k)[f"rigs/{rig.name}"].attrs if present[k] else None
        if (
            stored is not None
            and json_attribute(shards[k], stored, "rig_json", dict, where=f"/rigs/{rig.name} ") != want_json
        ):
            raise InputFileError(shards[k], f"holds a different rig under the name {rig.name}")
    return present


def _stored_models(ds) -> dict:
    """The per-model records a worker needs: names, SHA-256, boxes (float64), origins and augments."""
    return {
        "names": [str(x) for x in ds.names],
        "sha256": [x.decode() if isinstance(x, bytes) else str(x) for x in ds.models_array("sha256")]
        if ds.has("models/sha256")
        else [""] * ds.n_models,
        "center": np.asarray(ds.center, dtype=np.float64),
        "radius": np.asarray(ds.radius, dtype=np.float64),
        "origin": [str(x) for x in ds.origins] if ds.origins is not None else [""] * ds.n_models,
        "augment": [str(x) for x in ds.augments] if ds.augments is not None else [""] * ds.n_models,
    }


def _build_config(path: Path, cfg_dict: dict, meshes) -> BuildConfig:
    """The file's build config, with its mesh folder(s) replaced by ``meshes`` when given."""
    if not cfg_dict.get("meshes") and not meshes and not cfg_dict.get("procedural"):
        raise InputFileError(path, "config_json records no meshes folder; pass --meshes DIR")
    cfg = BuildConfig.from_dict(cfg_dict, path)
    if meshes:
        meshes = [meshes] if isinstance(meshes, (str, os.PathLike)) else list(meshes)
        if cfg.sources:
            if len(meshes) != len(cfg.sources):
                raise ParameterError(
                    f"{path} was built from {len(cfg.sources)} mesh folders "
                    f"({', '.join(s['name'] for s in cfg.sources)}): give `meshes` once for each, in order",
                    "meshes",
                )
            cfg.sources = [{**s, "path": str(p)} for s, p in zip(cfg.sources, meshes)]
        elif len(meshes) != 1:
            raise ParameterError(f"{path} was built from one mesh folder: give `meshes` once", "meshes")
        else:
            cfg.meshes = str(meshes[0])
    if not cfg.sources and cfg.manifest and not Path(cfg.manifest).exists():
        cfg.manifest = None
    return cfg


def _model_entries(cfg: BuildConfig, stored: dict) -> list:
    """The catalogue entry of every stored model, in the file's order (an augmented copy: its origin's)."""
    entries, _ = discover_sources(cfg)
    by_name = {e.name: e for e in entries}
    wanted = [o or n for n, o in zip(stored["names"], stored["origin"])]
    missing = [n for n in wanted if n not in by_name]
    if missing:
        where = ", ".join(s.path for s in cfg.mesh_sources())
        raise InputFileError(
            where,
            f"has no mesh for {len(missing)} of the dataset's models (first: {missing[0]}); "
            "pass the meshes folder the dataset was built from (--meshes)",
        )
    return [by_name[n] for n in wanted]


def _rig_depths(cfg, entries, stored, rig, workers, progress, backend, ray_address, retries) -> np.ndarray:
    """Every model's depths for ``rig``: float32 (n_models, rig.n_rays), computed locally or on Ray."""
    n = len(stored["names"])
    depths = np.zeros((n, rig.n_rays), dtype=np.float32)
    bar = tqdm(total=n, desc=f"depths {rig.name}", unit="model", disable=not progress, dynamic_ncols=True)
    try:
        if check_backend(backend) == "ray":
            with ray_session(ray_address, workers) as ray:
                RayBuild(ray, workers if ray_address else None, retries).add_rig_depths(
                    cfg, entries, stored, rig, depths, bar
                )
        else:
            state = {"entries": entries, "stored": stored, "cfg": cfg, "rig": rig}
            workers = max(1, min(int(workers or os.cpu_count() or 1), n))
            for m, d in map_units(_add_rig_unit, list(range(n)), state, workers):
                depths[m] = d
                bar.update(1)
    finally:
        bar.close()
    return depths


def _write_rig_to_shards(shards, present, offsets, rig, depths, cfg_dict) -> None:
    """Add the rig group (and the new ``config_json``) to every shard still without it."""
    # shard by shard (a single file is one shard), each copied, completed and renamed: an
    # interruption leaves every file whole; a rerun completes the shards still without the rig
    for k, shard in enumerate(shards):
        if present[k]:
            continue
        with atomic_output(shard, suffix=".h5") as tmp:
            shutil.copyfile(shard, tmp)
            with hdf5_output(tmp, "r+") as (f, _):
                write_rig_group(f.require_group("rigs"), rig, depths[offsets[k] : offsets[k + 1]])
                f.attrs["config_json"] = json.dumps(cfg_dict, sort_keys=True)
