"""The Ray backend of ``dataset build`` and ``dataset add-rig`` (``--backend ray``).

The work is the local backend's, cut the same way; only where it runs changes:

* **meshes**: one Ray task per mesh file loads it (:func:`~.catalogue.load_model`) on the
  cluster; the loaded mesh stays in the object store (one copy per model, shared by every
  unit of that model and by its augmented copies, which are derived inside the unit tasks),
  and only its hash and box size come back to the driver, which needs them for the plan,
  the splits and the augmentation draws;
* **units**: one Ray task per work unit (the ground truth of a model, a block of its views)
  runs :func:`~.simulate.compute_unit` and writes its part into ``OUT.parts/`` (a folder every
  node must see: a shared filesystem), atomically, exactly as a local worker does; a unit
  whose part exists is never submitted again, so a killed driver resumes;
* **shards**: with ``--shard-size``, one task per shard file writes it from the parts.

Same config, same bytes: the tasks run the same functions on the same inputs, whatever the
number of nodes or workers. A task that raises a :class:`SpotlightsError` (bad input: a mesh
that never gives enough returns) stops the build with that line at once; any other failure
(a crashed worker, a lost node) is retried ``retries`` times by Ray, then the build stops with
one line naming the mesh, the unit and the reason.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from ..._version import __version__
from ...distributed import DEFAULT_RETRIES, cluster_cpus, error_reason
from ...errors import InputFileError, ProcessFailure, SpotlightsError
from ...geometry.rig import RigSpec
from ...timing import StageTimer
from .catalogue import LoadedModel, ModelEntry, apply_augment, load_model, source_root, source_scale
from .config import BuildConfig
from .consolidate import part_name, save_npz_atomic, write_output_file
from .simulate import compute_unit, model_depths


@dataclass
class RemoteModel:
    """A model whose mesh lives in the Ray object store: ``entry``, ``ref`` (ObjectRef of the
    origin mesh's :class:`LoadedModel`), ``size`` (3,) box in metres."""

    entry: ModelEntry
    ref: object
    size: np.ndarray

    def derive(self, entry: ModelEntry) -> RemoteModel:
        """An augmented copy: the same mesh in the store, transformed inside the unit tasks."""
        return RemoteModel(entry, self.ref, self.size * np.asarray(entry.augment["scale"], dtype=np.float64))


def describe_unit(unit: tuple) -> str:
    """``ground truth`` or ``views A-B`` (for messages)."""
    return "ground truth" if unit[0] == "gt" else f"views {unit[2]}-{unit[3] - 1}"


# ----------------------------------------------------------------------------------------------
# task bodies (plain functions: Ray wraps them on first use, so importing this needs no Ray)
# ----------------------------------------------------------------------------------------------
_SIMS: dict = {}  # per worker process: the simulator (BVH) of the model it last worked on
_CFG: dict = {}


def _cfg(cfg_dict: dict) -> BuildConfig:
    key = repr(sorted(cfg_dict.items()))
    if key not in _CFG:
        _CFG.clear()
        _CFG[key] = BuildConfig.from_dict(cfg_dict)
    return _CFG[key]


def _check_version(version: str) -> None:
    if version != __version__:
        raise SpotlightsError(
            f"spotlights {__version__} on Ray node {os.uname().nodename}, the driver runs {version}: "
            "install the same version on every node (the bytes of a dataset depend on it)"
        )


def _load_task(entry: ModelEntry, root: str, scale: float, version: str):
    """Load one mesh on a worker: returns ``(meta, model)``, ``meta`` = ``{"sha256", "size"}`` or
    ``{"problem"}`` (``model`` None)."""
    _check_version(version)
    try:
        m = load_model(Path(root), entry, scale)
    except InputFileError as exc:
        return {"problem": exc.problem}, None
    return {"sha256": m.entry.sha256, "size": m.size}, m


def _unit_task(unit: tuple, origin: LoadedModel, entry: ModelEntry, cfg_dict: dict, parts: str, version: str):
    """Compute one work unit on a worker and write its part; returns ``("ok", unit, seconds, node)``
    or ``("error", exc)`` for a SpotlightsError (bad input, or a node set up wrong: not retried)."""
    timer = StageTimer()
    try:
        _check_version(version)
        parts_dir = Path(parts)
        if not parts_dir.is_dir():
            raise SpotlightsError(
                f"{parts}: the build's parts folder is not visible on Ray node {os.uname().nodename}; "
                "the output must be on a filesystem every node mounts at the same path"
            )
        model = apply_augment(origin, entry) if entry.augment else LoadedModel(entry, origin.vertices, origin.faces)
        arrays = compute_unit(unit, model, _cfg(cfg_dict), _SIMS)
        save_npz_atomic(parts_dir / part_name(unit), arrays)
    except SpotlightsError as exc:
        return ("error", exc)
    return ("ok", unit, timer.lap("unit"), os.uname().nodename)


def _shard_task(
    path: str,
    cfg_dict: dict,
    entries: list,
    rows: tuple,
    parts: str,
    units: list,
    skipped: list,
    attrs: dict,
    version: str,
):
    """Write one shard file from the parts (no recomputation: an unreadable part is reported)."""
    try:
        _check_version(version)
        write_output_file(Path(path), _cfg(cfg_dict), entries, range(*rows), Path(parts), units, skipped, attrs)
    except SpotlightsError as exc:
        return ("error", exc)
    return ("ok", path)


def _add_rig_task(m: int, entry: ModelEntry, cfg_dict: dict, stored: dict, rig_dict: dict, version: str):
    """Model row ``m``'s depths for ``dataset add-rig`` (see :func:`.addrig.model_depths`)."""
    try:
        _check_version(version)
        spec = RigSpec.from_dict(rig_dict)
        rig = spec if spec.needs_box else spec.for_box(None)
        return ("ok", model_depths(_cfg(cfg_dict), entry, stored, m, rig))
    except SpotlightsError as exc:
        return ("error", exc)


# ----------------------------------------------------------------------------------------------
# the driver side
# ----------------------------------------------------------------------------------------------
#: Seconds a build that gives up waits for its cancelled Ray tasks to end before it removes their parts (a forced
#: cancel kills the task's worker; ending one takes well under a second on an idle cluster).
CANCEL_WAIT_S = 60.0


class RayBuild:
    """Runs a build's loading, units and shard writing on a connected Ray cluster.

    ray : the ``ray`` module (connected, :func:`spotlights.distributed.ray_session`).
    workers : at most this many tasks running at once (``--workers`` with ``--ray-address``);
        default: twice the cluster's CPUs in flight (Ray runs as many as there are CPUs, the
        rest wait in its queue so that no CPU idles between tasks).
    retries : Ray retries of a task that fails other than by a SpotlightsError.
    """

    def __init__(self, ray, workers: int | None = None, retries: int = DEFAULT_RETRIES):
        self.ray = ray
        self.retries = int(retries)
        self.cpus = cluster_cpus(ray)
        self.in_flight = max(1, int(workers)) if workers else self.cpus * 2
        opts = dict(num_cpus=1, max_retries=self.retries, retry_exceptions=True)
        self._load = ray.remote(num_returns=2, **opts)(_load_task)
        self._unit = ray.remote(**opts)(_unit_task)
        self._shard = ray.remote(**opts)(_shard_task)
        self._add_rig = ray.remote(**opts)(_add_rig_task)

    def _fail(self, what: str, exc: BaseException):
        raise ProcessFailure(
            f"{what} failed on the Ray cluster after {self.retries + 1} attempts: {error_reason(exc)}"
        ) from None

    def stream(
        self,
        submit: Callable[[Any], Any],
        items: Iterable,
        describe: Callable[[Any], str],
        on_done: Callable[[Any, Any], None],
        bar=None,
    ) -> None:
        """Submit ``submit(item)`` (returns a Ray object ref) for every item with at most ``in_flight``
        pending; call ``on_done(item, result)`` as results arrive (any order); stop at the first failure.

        A task that fails after its ``retries`` is a one-line :class:`SpotlightsError` starting with
        ``describe(item)`` and saying the attempts and the reason; a task result ``("error", exc)``
        raises the task's own SpotlightsError ``exc`` (its type kept: an input error lets the build
        remove its parts; a node that cannot run the build, a plain SpotlightsError, keeps them). The
        other pending tasks are cancelled (not on Ctrl-C)."""
        ray = self.ray
        pending: dict = {}
        it = iter(items)
        exhausted = False
        try:
            while pending or not exhausted:
                while not exhausted and len(pending) < self.in_flight:
                    try:
                        item = next(it)
                    except StopIteration:
                        exhausted = True
                        break
                    pending[submit(item)] = item
                if not pending:
                    break
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    item = pending.pop(ref)
                    try:
                        res = ray.get(ref)
                    except ray.exceptions.RayError as exc:
                        self._fail(describe(item), exc)
                    if isinstance(res, tuple) and res and res[0] == "error":
                        raise res[1]  # the task's own error (its type says whether the input was wrong)
                    on_done(item, res)
        except BaseException as exc:
            # on Ctrl-C / SIGTERM no cancel: cancelling races with replies on their way and Ray 2.60's
            # driver then dies in a failed check ("Tried to complete task that was not pending", exit 1,
            # 1 run in 3); the driver's exit ends its job's tasks (ray.shutdown, or the cluster on a
            # driver gone)
            if not isinstance(exc, KeyboardInterrupt):
                for ref in pending:
                    ray.cancel(ref, force=True)
                self._wait_ended(list(pending))
            raise

    def _wait_ended(self, refs: list) -> None:
        """Wait (at most :data:`CANCEL_WAIT_S`) until cancelled tasks have ended: a cancel only asks, and a task
        still running went on writing its part after the build had removed the parts folder (a finished part
        and a ``.part.npz`` were found in a folder the build had removed). Their errors are theirs, not news."""
        if not refs:
            return
        try:
            self.ray.wait(refs, num_returns=len(refs), timeout=CANCEL_WAIT_S)
        except Exception:  # noqa: BLE001 - a cluster going away while we wait: nothing more to wait for
            pass

    # --- loading --------------------------------------------------------------------------
    def loader(self, cfg: BuildConfig, entries: list, progress: bool = False) -> list[tuple]:
        """A :func:`~.catalogue.build_catalogue` loader: meshes loaded by Ray tasks, kept in the
        object store; ``[(RemoteModel or None, problem or None)]`` in entry order."""
        out: list = [(None, "not loaded")] * len(entries)
        model_refs: dict = {}
        bar = tqdm(
            total=len(entries), desc="load meshes", unit="mesh", disable=not progress or len(entries) < 20, leave=False
        )

        def submit(i):
            e = entries[i]
            meta_ref, model_refs[i] = self._load.remote(e, str(source_root(cfg, e)), source_scale(cfg, e), __version__)
            return meta_ref

        def done(i, meta):
            ref = model_refs.pop(i)
            if "problem" in meta:
                out[i] = (None, meta["problem"])
            else:
                entries[i].sha256 = meta["sha256"]
                out[i] = (RemoteModel(entries[i], ref, np.asarray(meta["size"], dtype=np.float64)), None)
            bar.update(1)

        try:
            self.stream(submit, range(len(entries)), lambda i: f"{entries[i].file}: loading", done)
        finally:
            bar.close()
        return out

    # --- units ----------------------------------------------------------------------------
    def run_units(self, pending: list, models: list, cfg: BuildConfig, parts: Path, progress: bool = True) -> None:
        """Compute the pending units as Ray tasks; each writes its part. A model's mesh is released
        from the object store once its last pending unit is done."""
        cfg_ref = self.ray.put(cfg.to_dict())
        left = {}
        for u in pending:
            left[u[1]] = left.get(u[1], 0) + 1
        n_obs = sum(u[3] - u[2] for u in pending if u[0] == "obs")
        n_gt = sum(1 for u in pending if u[0] == "gt")
        bar = tqdm(
            total=n_obs, desc="build (ray)", unit="sample", disable=not progress, smoothing=0.05, dynamic_ncols=True
        )
        done_gt = 0

        def submit(u):
            m = models[u[1]]
            return self._unit.remote(u, m.ref, m.entry, cfg_ref, str(parts), __version__)

        def done(u, res):
            nonlocal done_gt
            left[u[1]] -= 1
            if left[u[1]] == 0:
                models[u[1]].ref = None  # no unit needs this mesh any more: the store may free it
            if u[0] == "gt":
                done_gt += 1
                bar.set_postfix_str(f"ground truth {done_gt}/{n_gt}", refresh=False)
            else:
                bar.update(u[3] - u[2])

        try:
            self.stream(
                submit,
                pending,
                lambda u: f"{models[u[1]].entry.file}: {describe_unit(u)} of model {models[u[1]].entry.name}",
                done,
            )
        finally:
            bar.close()

    # --- shards ---------------------------------------------------------------------------
    def write_shards(
        self,
        jobs: list[dict],
        cfg: BuildConfig,
        entries: list,
        parts: Path,
        units: list,
        skipped: list,
        progress: bool = True,
    ) -> None:
        """Write the shard files of a sharded dataset, one Ray task each."""
        cfg_ref = self.ray.put(cfg.to_dict())
        entries_ref = self.ray.put(entries)
        units_ref = self.ray.put(units)
        bar = tqdm(total=len(jobs), desc="write shards (ray)", unit="shard", disable=not progress, dynamic_ncols=True)
        try:
            self.stream(
                lambda j: self._shard.remote(
                    str(j["path"]),
                    cfg_ref,
                    entries_ref,
                    (j["rows"].start, j["rows"].stop),
                    str(parts),
                    units_ref,
                    skipped,
                    j["attrs"],
                    __version__,
                ),
                jobs,
                lambda j: f"{j['path']}: writing the shard",
                lambda j, r: bar.update(1),
            )
        finally:
            bar.close()

    # --- add-rig --------------------------------------------------------------------------
    def add_rig_depths(self, cfg: BuildConfig, entries: list, stored: dict, rig, depths: np.ndarray, bar) -> None:
        """Fill ``depths`` (n, N*M) with each model's depths for ``rig``, one Ray task per model."""
        cfg_ref = self.ray.put(cfg.to_dict())
        stored_ref = self.ray.put(stored)
        rig_dict = rig.to_dict()

        def done(m, res):
            depths[m] = res[1]
            bar.update(1)

        self.stream(
            lambda m: self._add_rig.remote(m, entries[m], cfg_ref, stored_ref, rig_dict, __version__),
            range(len(entries)),
            lambda m: f"{entries[m].file}: depths of model {stored['names'][m]}",
            done,
        )
