"""The resumable runner of a dataset build: plan, work units, parts folder, consolidation.

Work units are (model, ground truth) and (model, block of views). Workers write each
finished unit to ``OUT.parts/`` atomically (temporary name, then rename); a unit whose
part exists is never recomputed. ``OUT.parts/plan.json`` records the configuration and
the model list: a later run resumes only the same plan. When all units exist, the HDF5
file is written (streaming, one part at a time) under a temporary name and renamed onto
``OUT``; the parts are then deleted.
"""

from __future__ import annotations

import contextlib
import json
import math
import numbers
import os
import shutil
import signal
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path

from tqdm import tqdm

from ...distributed import DEFAULT_RETRIES, check_backend, import_ray, ray_session
from ...errors import InputFileError, OutputFileError, ParameterError, SpotlightsError
from ...locks import exclusive_lock
from ...options import settings_from_dict
from ...outputs import atomic_output
from ...processes import check_can_start_processes, process_map
from ...timing import StageTimer
from ..store import open_dataset
from .catalogue import build_catalogue
from .config import PLAN_VERSION, BuildConfig
from .consolidate import check_index_path, part_name, save_npz_atomic, shard_jobs, write_build_index, write_output_file
from .ray_backend import RayBuild
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


def _run_unit(unit: tuple) -> tuple:
    """Compute one unit in a worker and write its part file; returns ``(unit, seconds)``."""
    timer = StageTimer()
    with timer("unit"):
        arrays = compute_unit(unit, _WORKER["models"][unit[1]], _WORKER["cfg"], _WORKER["sims"])
        save_npz_atomic(_WORKER["parts"] / part_name(unit), arrays)
    if _WORKER.get("parent") is not None and os.getppid() != _WORKER["parent"]:
        os._exit(0)  # the build was killed: the part is saved, leave quietly instead of a broken pipe
    return unit, timer.total


def _plan_units(n_models: int, views: int, block: int) -> list[tuple]:
    units = [("gt", m) for m in range(n_models)]
    for m in range(n_models):
        for a in range(0, views, block):
            units.append(("obs", m, a, min(views, a + block)))
    return units


def default_log(msg: str) -> None:
    tqdm.write(msg, file=sys.stderr)


@dataclass(frozen=True)
class BuildSettings:
    """How a build runs, never what it builds (that is :class:`BuildConfig`): the same config
    gives the same bytes whatever these are.

    workers : processes (default: all cores); Ray: the CPUs of the local instance it starts
        (with ``ray_address``: at most ``2 x workers`` tasks in flight). Results do not depend on it.
    overwrite : replace an existing ``out`` and discard unfinished parts.
    resume : accept an existing complete ``out`` (nothing to do). Unfinished parts of the same
        plan are always resumed.
    block : views per work unit (default: ~views/8, at most 250); only affects scheduling.
    keep_parts : keep ``OUT.parts`` after the file is written.
    progress : show progress bars.
    log : where warnings go (default: stderr).
    backend : ``"local"`` (a process pool) or ``"ray"`` (tasks on a Ray cluster; needs Ray).
    ray_address : ``"auto"`` / ``"HOST:PORT"``: join that cluster; None: a local instance.
    shard_size : write shards of at most this many samples (whole models) and an index.
    retries : Ray only: retries of a task that fails other than by bad input.
    """

    workers: int | None = None
    overwrite: bool = False
    resume: bool = False
    block: int | None = None
    keep_parts: bool = False
    progress: bool = True
    log: Callable[[str], None] | None = None
    backend: str = "local"
    ray_address: str | None = None
    shard_size: int | None = None
    retries: int = DEFAULT_RETRIES

    @classmethod
    def from_dict(cls, d: Mapping, where: str | os.PathLike | None = None) -> BuildSettings:
        """Read the settings by the one strict policy (:func:`spotlights.options.settings_from_dict`)."""
        return settings_from_dict(cls, d, where)


def build_dataset(
    cfg: BuildConfig, out: str | os.PathLike, settings: BuildSettings | None = None, **options
) -> BuildReport:
    """Build (or finish) a completion dataset: one HDF5 file, or HDF5 shards and their index.

    Parameters
    ----------
    cfg : the build configuration (validated here).
    out : the HDF5 file to write (with ``shard_size``: the shard index, ``NAME.json``); its
        work folder is ``OUT.parts``.
    settings : how the build runs (:class:`BuildSettings`; default: its defaults).
    options : :class:`BuildSettings` fields given one by one (``workers=2``), applied over ``settings``.

    Returns
    -------
    :class:`BuildReport` (its seconds from a :class:`~spotlights.timing.StageTimer`).
    """
    s = replace(settings or BuildSettings(), **options)
    timer = StageTimer()
    with timer("total"):
        log = s.log or default_log
        backend = check_backend(s.backend)
        if backend == "ray":
            import_ray()  # before anything else: one line saying how to install it
        cfg = cfg.validate()
        _check_block(s.block, cfg)
        out = Path(out)
        parts = out.with_name(out.name + ".parts")
        complete = _check_output(out, parts, cfg, s)
        if complete is not None:
            return complete
        workers = _worker_count(s, backend)
        if backend == "local" and workers > 1:
            check_can_start_processes()  # an unguarded script fails here, before anything is written

        with ray_session(s.ray_address, workers) if backend == "ray" else contextlib.nullcontext() as ray:
            runner = RayBuild(ray, workers if s.ray_address else None, s.retries) if backend == "ray" else None
            models, skipped = build_catalogue(cfg, log, s.progress, loader=runner.loader if runner else None)
            units, pending = _build_in_parts(out, parts, cfg, models, skipped, runner, workers, timer, s, log)
    if not s.keep_parts:
        shutil.rmtree(parts, ignore_errors=True)
    with open_dataset(out) as ds:
        size = ds.info()["file_size_bytes"] if s.shard_size is not None else out.stat().st_size
    return BuildReport(
        out=str(out),
        n_models=len(models),
        n_samples=len(models) * cfg.views,
        units_total=len(units),
        units_done_before=len(units) - len(pending),
        units_computed=len(pending),
        skipped=skipped,
        seconds_units=timer.seconds["units"],
        seconds_consolidate=timer.seconds["consolidate"],
        seconds_total=timer.seconds["total"],
        file_size=size,
    )


def _worker_count(s: BuildSettings, backend: str) -> int | None:
    """Processes of a local build (default: all cores); Ray: the CPUs of its local instance, or
    ``s.workers`` as given when joining a cluster."""
    if backend == "local" or not s.ray_address:
        return max(1, int(s.workers or os.cpu_count() or 1))
    return s.workers


def _build_in_parts(
    out: Path, parts: Path, cfg: BuildConfig, models: list, skipped: list, runner, workers, timer, s, log
) -> tuple[list[tuple], list[tuple]]:
    """Plan the work units, compute those without a part in ``parts`` (a new, resumed or refused
    folder), then write the output; returns ``(all units, units computed now)``."""
    n_models, views = len(models), cfg.views
    block = int(s.block or max(1, min(250, math.ceil(views / 8))))
    plan = {
        "plan_version": PLAN_VERSION,
        "config": cfg.to_dict(),
        "models": [m.entry.plan_dict() for m in models],
        "skipped": skipped,
    }

    # --- the parts folder: new, resumed, or refused ----------------------------------
    if s.overwrite and parts.exists():
        shutil.rmtree(parts)
    # two builds never write the same parts
    with (
        _parts_folder(parts),
        exclusive_lock(parts / ".lock", f"{parts}: another build is writing this dataset right now"),
    ):
        block = _check_plan(parts, plan, block)
        for stale in parts.glob(".*.part*"):  # temporaries of a killed run
            stale.unlink(missing_ok=True)
        units = _plan_units(n_models, views, block)
        pending = [u for u in units if not (parts / part_name(u)).exists()]
        done_before = len(units) - len(pending)
        if done_before:
            log(f"resuming {parts}: {done_before} of {len(units)} work units already done")
        state = {"cfg": cfg, "models": models, "parts": parts}
        with timer("units"):
            if runner is not None:
                runner.run_units(pending, models, cfg, parts, s.progress)
            else:
                _run_units(pending, state, workers, s.progress, n_models, views)
        with timer("consolidate"):
            _write_outputs(out, cfg, [m.entry for m in models], parts, units, skipped, state, runner, s)
    return units, pending


def _check_output(out: Path, parts: Path, cfg: BuildConfig, s: BuildSettings) -> BuildReport | None:
    """Refuse an output path that cannot be built (a folder, a bad index name, an existing file
    without ``overwrite``/``resume``); an existing complete file of the same config with
    ``resume`` gives its report (nothing to do), else None (build it)."""
    if out.is_dir():
        raise InputFileError(out, "is a folder; give the dataset file to write (e.g. cars.h5)")
    if s.shard_size is not None:
        if int(s.shard_size) < 1:
            raise ParameterError(f"shard size must be >= 1 samples, got {s.shard_size}")
        check_index_path(out)
    if not out.exists() or s.overwrite:
        return None
    if not s.keep_parts:
        _sweep_finished_parts(parts)
    if not s.resume:
        raise InputFileError(out, "already exists; pass --overwrite to rebuild it (or --resume to accept it)")
    with open_dataset(out) as ds:
        try:
            same = BuildConfig.from_dict(ds.config, out).to_dict() == cfg.to_dict()
        except SpotlightsError:  # not a config of this version's builds (another kind of dataset)
            same = False
        if not same:
            raise InputFileError(out, "exists and was built with a different configuration; pass --overwrite")
        return BuildReport(
            str(out),
            ds.n_models,
            ds.n_samples,
            0,
            0,
            0,
            [],
            already_complete=True,
            file_size=ds.info()["file_size_bytes"],
        )


def _write_outputs(out: Path, cfg, entries, parts: Path, units, skipped, state, runner, s: BuildSettings) -> None:
    """Consolidate the parts into the HDF5 file ``out``, or (``shard_size``) into shards and their index."""
    recompute = (lambda unit: _recompute(unit, state)) if runner is None else None
    n_models = len(entries)
    if s.shard_size is None:
        write_output_file(
            out, cfg, entries, range(n_models), parts, units, skipped, recompute=recompute, progress=s.progress
        )
        return
    jobs = shard_jobs(out, cfg, n_models, int(s.shard_size))
    new = [Path(j["path"]) for j in jobs if not Path(j["path"]).exists()]  # what a failure below must take back
    try:
        if runner is not None:
            runner.write_shards(jobs, cfg, entries, parts, units, skipped, s.progress)
        else:
            for j in jobs:
                write_output_file(
                    j["path"],
                    cfg,
                    entries,
                    j["rows"],
                    parts,
                    units,
                    skipped,
                    j["attrs"],
                    recompute=recompute,
                    progress=s.progress,
                )
        write_build_index(
            out, [j["path"] for j in jobs], [(len(j["rows"]), len(j["rows"]) * cfg.views) for j in jobs], cfg
        )
    except BaseException:
        # a full disk at the second shard left the first one finished beside no index: shards without their index
        # are no dataset, so those this run wrote go (the parts stay, or not, as the build decides: a rerun resumes)
        for p in new:
            with contextlib.suppress(OSError):
                p.unlink(missing_ok=True)
        raise


def _sweep_finished_parts(parts: Path) -> None:
    """A build killed between the final rename and the removal of its parts folder leaves that
    folder beside its finished output: remove it (not while another build holds its lock)."""
    if not parts.is_dir():
        return
    with contextlib.suppress(SpotlightsError, OSError):
        with exclusive_lock(parts / ".lock", "busy"):
            shutil.rmtree(parts)


@contextlib.contextmanager
def _parts_folder(parts: Path):
    """Create the parts folder for the body; if the body fails before any unit was saved (a full
    disk while writing the plan, an interrupt at once), or because of its input (a mesh or an option
    found wrong while simulating), remove the folder this call created: nothing is left behind that
    could not be resumed (a corrected input is another plan)."""
    created = not parts.exists()
    parts.mkdir(parents=True, exist_ok=True)
    try:
        yield parts
    except BaseException as exc:
        # a disk that refused a write (full, read-only): the folder this run made is removed, freeing its
        # space; so is one whose input was found wrong (its units belong to a plan the fix changes: a rerun
        # would be refused as "another plan"); other errors (Ctrl-C, SIGTERM, a worker killed) keep saved
        # units so that the next run resumes from them
        wrong_input = isinstance(exc, (InputFileError, ParameterError))
        if created and (isinstance(exc, (OSError, OutputFileError)) or wrong_input or not any(parts.glob("*.npz"))):
            shutil.rmtree(parts, ignore_errors=True)
        raise


# Partial points one work unit holds (views x points): the default block (at most 250 views) at the most points
# (MAX_PARTIAL_POINTS) fits, 197 MB of float32 per worker; --block 100000 --points 65536 asked for 78 GB.
MAX_UNIT_POINTS = 2**24


def _check_block(block: int | None, cfg: BuildConfig) -> None:
    """``--block``: a whole number >= 1 whose work unit (``min(block, views)`` views of ``cfg.n_points`` points)
    holds at most :data:`MAX_UNIT_POINTS` partial points; checked before anything is read or written."""
    if block is None:
        return
    if not (isinstance(block, numbers.Integral) and not isinstance(block, bool) and block >= 1):
        raise ParameterError(f"`block` must be a whole number >= 1, got {block!r}", "block")
    most = max(1, MAX_UNIT_POINTS // cfg.n_points)
    if min(block, cfg.views) > most:
        raise ParameterError(
            f"`block`: at most {most} views a work unit at {cfg.n_points} points each "
            f"({MAX_UNIT_POINTS:,} partial points a worker holds), got {block}",
            "block",
        )


def _check_plan(parts: Path, plan: dict, block: int) -> int:
    """Write ``parts/plan.json`` for a new build, or check that an unfinished one has the same plan;
    returns the block size to use (the first run's)."""
    plan_path = parts / "plan.json"
    if plan_path.exists():
        try:
            old = json.loads(plan_path.read_text())
        except (OSError, json.JSONDecodeError):
            raise InputFileError(plan_path, "unreadable build plan; pass --overwrite to start again") from None
        old_block = old.pop("block", block)
        if old != plan:
            diff = sorted(
                k
                for k in set(old.get("config", {})) | set(plan["config"])
                if old.get("config", {}).get(k) != plan["config"].get(k)
            )
            what = f"options differ: {', '.join(diff)}" if diff else "the meshes differ"
            raise InputFileError(
                parts,
                f"holds an unfinished build with another plan ({what}); pass --overwrite "
                "to discard it, or rerun with the original options",
            )
        return int(old_block)
    with atomic_output(plan_path, suffix=".json") as tmp:
        tmp.write_text(json.dumps({**plan, "block": block}, indent=1, sort_keys=True))
    return block


def _recompute(unit: tuple, state: dict) -> None:
    """Compute one unit again in this process (its part could not be read)."""
    if not _WORKER or _WORKER.get("parts") != state["parts"]:
        init_worker(state, quiet_sigint=False)
    _run_unit(unit)


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
    (:func:`spotlights.processes.process_map`), each initialised with ``state``; the pool is stopped
    on any error or when the caller stops early, a dead worker or a pool in which no unit
    finishes within ``processes.POOL_TIMEOUT_S`` is a one-line error, never a hang."""
    if workers == 1 or len(items) <= 1:
        init_worker(state, quiet_sigint=False)
        for item in items:
            yield fn(item)
        return
    yield from process_map(
        fn, items, workers, initializer=init_worker, initargs=(state, True), ordered=False, what="work unit"
    )
