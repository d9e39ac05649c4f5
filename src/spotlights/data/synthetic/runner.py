"""The resumable runner of a dataset build: plan, work units, parts folder, consolidation.

Work units are (model, ground truth) and (model, block of views). Workers write each
finished unit to ``OUT.parts/`` atomically (temporary name, then rename); a unit whose
part exists is never recomputed. ``OUT.parts/plan.json`` records the configuration and
the model list: a later run resumes only the same plan. When all units exist, the HDF5
file is written (streaming, one part at a time) under a temporary name and renamed onto
``OUT``; the parts are then deleted.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm import tqdm

from ..._version import __version__
from ...errors import InputFileError, SpotlightsError
from ...errors import OutputFileError
from ...utils import atomic_output, check_can_start_processes, exclusive_lock, process_map
from ..store import FORMAT, FORMAT_VERSION, open_dataset, write_dataset
from .catalogue import build_catalogue
from .config import PLAN_VERSION, BuildConfig
from .simulate import compute_unit

# ----------------------------------------------------------------------------------------------
# the build: plan, parallel units, shards, consolidation
# ----------------------------------------------------------------------------------------------
@dataclass
class BuildReport:
    """What a build did: counts, timings (seconds) and the output size (bytes)."""

    out: str
    n_models: int
    n_samples: int
    units_total: int
    units_done_before: int
    units_computed: int
    skipped: list
    seconds_units: float = 0.0
    seconds_consolidate: float = 0.0
    seconds_total: float = 0.0
    file_size: int = 0
    already_complete: bool = False


_WORKER: dict = {}


def init_worker(state: dict, quiet_sigint: bool) -> None:
    """Pool initializer: keep the shared state (config, meshes, parts folder); ignore Ctrl-C
    (the parent handles it and terminates the pool)."""
    if quiet_sigint:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # pool.terminate() must end a worker at once
    _WORKER.clear()
    _WORKER.update(state)
    _WORKER["sims"] = {}
    # the process that started this worker (the fork server of process_pool_context, which exits
    # with the build): when it is gone, the build was killed
    _WORKER["parent"] = os.getppid() if quiet_sigint else None


def worker_state() -> dict:
    """The state a worker of :func:`map_units` was initialised with (config, models, ...)."""
    return _WORKER


def _shard_name(unit: tuple) -> str:
    if unit[0] == "gt":
        return f"gt-{unit[1]:05d}.npz"
    return f"obs-{unit[1]:05d}-{unit[2]:07d}-{unit[3]:07d}.npz"


def save_npz_atomic(path: Path, arrays: dict) -> None:
    with atomic_output(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())


def _run_unit(unit: tuple) -> tuple:
    """Compute one unit in a worker and write its part file; returns ``(unit, seconds)``."""
    t0 = time.perf_counter()
    arrays = compute_unit(unit, _WORKER["models"][unit[1]], _WORKER["cfg"], _WORKER["sims"])
    save_npz_atomic(_WORKER["parts"] / _shard_name(unit), arrays)
    if _WORKER.get("parent") is not None and os.getppid() != _WORKER["parent"]:
        os._exit(0)  # the build was killed: the part is saved, leave quietly instead of a broken pipe
    return unit, time.perf_counter() - t0


def _plan_units(n_models: int, views: int, block: int) -> list[tuple]:
    units = [("gt", m) for m in range(n_models)]
    for m in range(n_models):
        for a in range(0, views, block):
            units.append(("obs", m, a, min(views, a + block)))
    return units


def default_log(msg: str) -> None:
    tqdm.write(msg, file=sys.stderr)


def build_dataset(cfg: BuildConfig, out: str | os.PathLike, workers: int | None = None, overwrite: bool = False,
                  resume: bool = False, block: int | None = None, keep_parts: bool = False, progress: bool = True,
                  log: Callable[[str], None] | None = None) -> BuildReport:
    """Build (or finish) a completion dataset file.

    Parameters
    ----------
    cfg : the build configuration (validated here).
    out : the HDF5 file to write; its work folder is ``OUT.parts``.
    workers : processes (default: all cores). Results do not depend on it.
    overwrite : replace an existing ``out`` and discard unfinished parts.
    resume : accept an existing complete ``out`` (nothing to do). Unfinished parts of the same
        plan are always resumed.
    block : views per work unit (default: ~views/8, at most 250); only affects scheduling.
    keep_parts : keep ``OUT.parts`` after the file is written.
    progress : show progress bars.
    log : where warnings go (default: stderr).

    Returns
    -------
    :class:`BuildReport`.
    """
    t_start = time.perf_counter()
    log = log or default_log
    cfg = cfg.validate()
    out = Path(out)
    parts = out.with_name(out.name + ".parts")
    if out.is_dir():
        raise InputFileError(out, "is a folder; give the dataset file to write (e.g. cars.h5)")
    if out.exists() and not overwrite:
        if not resume:
            raise InputFileError(out, "already exists; pass --overwrite to rebuild it (or --resume to accept it)")
        with open_dataset(out) as ds:
            if BuildConfig.from_dict(ds.config).to_dict() != cfg.to_dict():
                raise InputFileError(out, "exists and was built with a different configuration; pass --overwrite")
            return BuildReport(str(out), ds.n_models, ds.n_samples, 0, 0, 0, [], already_complete=True,
                               file_size=out.stat().st_size)
    workers = max(1, int(workers or os.cpu_count() or 1))
    if workers > 1:
        check_can_start_processes()  # an unguarded script fails here, before anything is written

    models, skipped = build_catalogue(cfg, log, progress)
    block = int(block or max(1, min(250, math.ceil(cfg.views / 8))))
    plan = {
        "plan_version": PLAN_VERSION, "config": cfg.to_dict(),
        "models": [m.entry.plan_dict() for m in models], "skipped": skipped,
    }

    # --- the parts folder: new, resumed, or refused --------------------------------------
    if overwrite and parts.exists():
        shutil.rmtree(parts)
    new_parts = not parts.exists()
    parts.mkdir(parents=True, exist_ok=True)
    try:
        return _build_in(parts, out, cfg, models, skipped, plan, block, workers, progress, log, keep_parts, t_start)
    except (OSError, OutputFileError):
        # the disk refused a write (full, read-only): a parts folder this run made is removed, freeing its space
        # (Ctrl-C, SIGTERM and other errors keep it: the next run resumes from it)
        if new_parts:
            shutil.rmtree(parts, ignore_errors=True)
        raise


def _build_in(parts, out, cfg, models, skipped, plan, block, workers, progress, log, keep_parts, t_start) -> BuildReport:
    n_models, views = len(models), cfg.views
    # two builds never write the same shards
    with exclusive_lock(parts / ".lock", f"{parts}: another build is writing this dataset right now"):
        plan_path = parts / "plan.json"
        if plan_path.exists():
            try:
                old = json.loads(plan_path.read_text())
            except (OSError, json.JSONDecodeError):
                raise InputFileError(plan_path, "unreadable build plan; pass --overwrite to start again") from None
            old_block = old.pop("block", block)
            if old != plan:
                diff = sorted(k for k in set(old.get("config", {})) | set(plan["config"])
                              if old.get("config", {}).get(k) != plan["config"].get(k))
                what = f"options differ: {', '.join(diff)}" if diff else "the meshes differ"
                raise InputFileError(parts, f"holds an unfinished build with another plan ({what}); pass --overwrite "
                                            "to discard it, or rerun with the original options")
            block = int(old_block)
        else:
            with atomic_output(plan_path, suffix=".json") as tmp:
                tmp.write_text(json.dumps({**plan, "block": block}, indent=1, sort_keys=True))
        for stale in parts.glob(".*.part*"):  # temporaries of a killed run
            stale.unlink(missing_ok=True)

        units = _plan_units(n_models, views, block)
        pending = [u for u in units if not (parts / _shard_name(u)).exists()]
        done_before = len(units) - len(pending)
        if done_before:
            log(f"resuming {parts}: {done_before} of {len(units)} work units already done")
        state = {"cfg": cfg, "models": models, "parts": parts}
        t_units = time.perf_counter()
        _run_units(pending, state, workers, progress, n_models, views)
        t_cons = time.perf_counter()
        _consolidate(out, parts, cfg, models, skipped, units, state, progress)
        t_end = time.perf_counter()
    if not keep_parts:
        shutil.rmtree(parts, ignore_errors=True)
    return BuildReport(
        out=str(out), n_models=n_models, n_samples=n_models * views, units_total=len(units),
        units_done_before=done_before, units_computed=len(pending), skipped=skipped,
        seconds_units=t_cons - t_units, seconds_consolidate=t_end - t_cons, seconds_total=t_end - t_start,
        file_size=out.stat().st_size)


def _run_units(pending: list, state: dict, workers: int, progress: bool, n_models: int, views: int) -> None:
    """Compute the pending units (in-process for one worker, else a process pool)."""
    n_obs = sum(u[3] - u[2] for u in pending if u[0] == "obs")
    n_gt = sum(1 for u in pending if u[0] == "gt")
    bar = tqdm(total=n_obs, desc="build", unit="sample", disable=not progress, smoothing=0.05, dynamic_ncols=True)
    done_gt = 0

    def advance(unit):
        nonlocal done_gt
        if unit[0] == "gt":
            done_gt += 1
            bar.set_postfix_str(f"ground truth {done_gt}/{n_gt}", refresh=False)
        else:
            bar.update(unit[3] - unit[2])

    try:
        for unit, _ in map_units(_run_unit, pending, state, workers):
            advance(unit)
    finally:
        bar.close()


def map_units(fn, items: list, state: dict, workers: int):
    """Yield ``fn(item)`` for every item: in this process when ``workers == 1`` (or one item),
    else unordered on ``min(workers, len(items))`` processes started from a fork server
    (:func:`spotlights.utils.process_map`), each initialised with ``state``; the pool is stopped
    on any error or when the caller stops early, a dead worker or a pool in which no unit
    finishes within ``utils.POOL_TIMEOUT_S`` is a one-line error, never a hang."""
    if workers == 1 or len(items) <= 1:
        init_worker(state, quiet_sigint=False)
        for item in items:
            yield fn(item)
        return
    yield from process_map(fn, items, workers, initializer=init_worker, initargs=(state, True), ordered=False,
                           what="work unit")


def _load_shard(path: Path, unit: tuple, state: dict) -> dict:
    """Read a shard; a shard that cannot be read (e.g. a damaged disk) is recomputed in-process."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except Exception:
        path.unlink(missing_ok=True)
        if not _WORKER or _WORKER.get("parts") != state["parts"]:
            init_worker(state, quiet_sigint=False)
        _run_unit(unit)
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}


def _consolidate(out: Path, parts: Path, cfg: BuildConfig, models: list, skipped: list, units: list,
                 state: dict, progress: bool) -> None:
    """Stream the shards, in sample order, into ``out`` (written under a temporary name, then renamed)."""
    n = len(models)
    rigs = cfg.rigs
    gts = [_load_shard(parts / _shard_name(("gt", m)), ("gt", m), state) for m in range(n)]
    model_arrays = {
        "name": [m.entry.name for m in models], "file": [m.entry.file for m in models],
        "sha256": [m.entry.sha256 for m in models], "category": [m.entry.category for m in models],
        "split": [m.entry.split for m in models],
        "gt_points": np.stack([g["gt_points"] for g in gts]), "gt_dense": np.stack([g["gt_dense"] for g in gts]),
        "center": np.stack([g["center"] for g in gts]), "radius": np.array([float(g["radius"]) for g in gts]),
        "size": np.stack([g["size"] for g in gts]),
    }
    if cfg.sources:
        model_arrays["source"] = [m.entry.source for m in models]
    if cfg.augment:
        model_arrays["origin"] = [m.entry.origin or m.entry.name for m in models]
        model_arrays["augment"] = [json.dumps(m.entry.augment, sort_keys=True) if m.entry.augment else ""
                                   for m in models]
    rig_arrays = [(r, np.stack([g[f"depths_{i}"] for g in gts])) for i, r in enumerate(rigs)]
    del gts
    obs_units = [u for u in units if u[0] == "obs"]
    attrs = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "spotlights_version": __version__,
        "config_json": json.dumps(cfg.to_dict(), sort_keys=True), "seed": int(cfg.seed),
        "sensor_json": json.dumps(cfg.sensor, sort_keys=True), "default_rig": rigs[0].name,
        "views_per_model": int(cfg.views), "skipped_json": json.dumps(skipped, sort_keys=True),
    }

    def blocks():
        bar = tqdm(total=n * cfg.views, desc="write " + out.name, unit="sample", disable=not progress,
                   dynamic_ncols=True)
        try:
            for u in obs_units:
                a = _load_shard(parts / _shard_name(u), u, state)
                if a["partial"].shape != (u[3] - u[2], cfg.n_points, 3) or np.any(a["model"] != u[1]):
                    raise SpotlightsError(f"{parts / _shard_name(u)}: shard does not match the plan; delete it and rerun")
                a["start"] = u[1] * cfg.views + u[2]
                yield a
                bar.update(u[3] - u[2])
        finally:
            bar.close()

    with atomic_output(out, suffix=".h5") as tmp:
        write_dataset(tmp, attrs=attrs, models=model_arrays, rigs=rig_arrays, n_points=cfg.n_points,
                      views_per_model=cfg.views, sample_blocks=blocks())

