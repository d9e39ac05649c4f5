"""The track worker process: a :class:`~spotlights.completion.fusion.TrackPlan`'s boxes refined and windows fused in
a process of their own, ahead of the frame loop that completes the frames (``real complete --fuse``, two cores).

:class:`TrackWorker` starts the process (:func:`worker_main`) from the fork server of
:func:`spotlights.processes.process_pool_context`, hands it the plan's crops and tracks, and takes back each frame's
inputs (:meth:`spotlights.completion.track_windows.TrackWindows._inputs`: the same functions on the same inputs, the
same numbers) and the tracks' final boxes. A worker that dies or goes silent for :data:`STALL_S` ends the run with one
line (:class:`TrackWorkerDied`, :class:`TrackWorkerStalled`). :func:`usable_cpus` decides whether a second process
helps; :func:`threads_beside_worker` leaves it a core.
"""

from __future__ import annotations

import contextlib
import math
import os
import pickle
import sys
import time
import traceback
import weakref
from collections.abc import Hashable
from pathlib import Path
from queue import Empty
from typing import TYPE_CHECKING

import numpy as np

from ..data.tracks import TrackFrame, fuse_track
from ..errors import ProcessFailure
from ..geometry.boxes import Box
from ..options import check_threads
from ..processes import _quiet_worker, process_pool_context, sigint_held
from .frame import scene_crops
from .track_windows import TrackWindows, _crops

if TYPE_CHECKING:
    from multiprocessing.process import BaseProcess
    from multiprocessing.queues import Queue

    from .fusion import TrackPlan

#: Seconds :class:`TrackWorker` waits between checks that its process is still alive.
POLL_S = 0.5

#: Seconds the worker process may go without a message before it is taken for hung: the run then stops it and fails
#: with one line (:class:`TrackWorkerStalled`). The worker sends a sign of life at least every :data:`BEAT_S` while it
#: works (after each frame it registers and each box it fuses), so this bounds one such step, not a whole frame:
#: scene-0523 (nuScenes, 40 keyframes, 91 tracks, 2-core machine under load) took at most 0.07 s a frame with
#: ``past:5 --refine-boxes`` and 0.6 s for its longest track's whole refinement with ``all`` (one step: ~5 ms); the
#: worker's start to its first frame (fork server and worker: fresh interpreters importing numpy and scipy) 0.45 s.
#: A pause of the whole run (Ctrl-Z, then ``fg``) is not counted. 120 s is over 100 times the longest of these:
#: a slow or busy machine gets no false alarm, a hung worker costs two minutes instead of a run that never ends.
STALL_S = 120.0

#: Seconds between the worker's signs of life (``("beat",)`` messages) while it works without another message.
BEAT_S = 1.0


class TrackWorkerStalled(ProcessFailure):
    """The track worker process sent nothing for :data:`STALL_S` seconds while alive: it was stopped (exit code 1)."""


class TrackWorkerDied(ProcessFailure):
    """The track worker process ended without sending its results (killed, say for memory): exit code 1."""


#: Linux cgroup v2 file of this process's CPU quota ("QUOTA PERIOD" in microseconds, or "max PERIOD").
CGROUP_CPU_MAX = "/sys/fs/cgroup/cpu.max"


def cgroup_cpu_limit(path: str | Path = CGROUP_CPU_MAX) -> int | None:
    """The whole CPUs a cgroup v2 quota allows (``ceil(quota / period)``, at least 1; ``docker --cpus=1`` writes
    ``100000 100000``), or None without a quota (``max``) or without a readable file (other systems)."""
    try:
        quota, period = Path(path).read_text().split()[:2]
        return None if quota == "max" else max(1, math.ceil(int(quota) / int(period)))
    except (OSError, ValueError, ZeroDivisionError):
        return None


def usable_cpus() -> int:
    """The CPUs this process may run on: its affinity where the platform tells it (else ``os.cpu_count()``), no
    more than its container's CPU quota (:func:`cgroup_cpu_limit`)."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        n = os.cpu_count() or 1
    limit = cgroup_cpu_limit()
    return n if limit is None else min(n, limit)


@contextlib.contextmanager
def threads_beside_worker(plan: TrackPlan | None, threads: int | None = None):
    """While ``plan`` has a worker process, run torch on at most the usable CPUs less one (restored on exit); with
    ``threads`` (``--threads``), on that many, worker or not (the user's count wins; restored on exit too).

    The worker takes one core for the whole run; torch's OpenMP threads spin for every core it was given, so on
    two cores a second torch thread only competes with the worker (scene-0523, ``past:5 --refine-boxes``, bf16, a
    quiet 2-core machine: 14.4 frames/s with one torch thread against 11.0 with two; docs/real-data.md). A lower
    thread count set by the caller is kept; without a worker (and ``threads``) nothing changes."""
    torch = sys.modules.get("torch")  # not imported: onnxruntime runs the model (its threads are its session's)
    if torch is None or (not threads and (plan is None or plan.worker_process is None)):
        yield
        return

    before = torch.get_num_threads()
    torch.set_num_threads(check_threads(threads) if threads else max(1, min(before, usable_cpus() - 1)))
    try:
        yield
    finally:
        torch.set_num_threads(before)


def worker_main(jobs: Queue, results: Queue) -> None:
    """What the :class:`TrackWorker` process runs: receive a plan (:meth:`TrackWorker.send`), then for each frame key
    in order put ``("frame", key, repl, extra, scene)`` (:meth:`TrackWindows._inputs`), then ``("done", state, timer
    seconds)``; ``("error", exception)`` instead when something fails; ``("beat",)`` at most every :data:`BEAT_S`
    seconds while it works without another message (read by :data:`STALL_S`)."""
    _quiet_worker(None, ())  # as a pool worker: Ctrl-C is the parent's (which stops this one); dies with it
    import scipy.spatial  # noqa: F401 - imported now, while the parent opens and reads (0.25 s), not at the first crop

    last = [time.monotonic()]

    def put(msg) -> None:
        results.put(msg)
        last[0] = time.monotonic()

    def beat() -> None:
        if time.monotonic() - last[0] >= BEAT_S:
            put(("beat",))

    try:
        crops: dict = {}  # frame key -> {box index: its crop}
        scans: dict = {}  # frame key -> (its scan, its boxes): for the scene's crops of the frames the loop takes
        cpu0 = time.process_time()
        while True:
            msg = jobs.get()
            if msg is None:  # stopped before a plan came
                return
            if msg[0] == "plan":
                job = msg[1]
                break
            _, key, points, todo, boxes, grow, clearance, keep = msg
            crops[key] = dict(zip(todo, _crops(points, [boxes[i] for i in todo], grow, clearance)))
            if keep:
                scans[key] = (points, boxes)
            beat()
        plan = TrackWindows(job["policy"], job["config"], job["refine"], job["max_translation"], job["max_yaw"])
        plan.progress = beat
        plan.tracks, plan.where = job["tracks"], job["where"]
        for tr in plan.tracks.values():  # the crops made here go where the plan left None
            for pos, (key, i, f) in enumerate(zip(tr.keys, tr.box_index, tr.frames)):
                if f.points is None:
                    tr.frames[pos] = TrackFrame(crops[key][i], f.box, f.origin, f.timestamp)
            if tr.refiner is not None:
                tr.refiner.frames = tr.frames
        del crops
        for key in job["keys"]:
            repl, extra = plan._inputs(key)
            scene = None
            if key in scans and plan.config.crop:  # complete_scene's crops, of the boxes the loop will use
                points, boxes = scans.pop(key)
                scene = scene_crops(points, [repl.get(i, b) for i, b in enumerate(boxes)], plan.config)
            put(("frame", key, repl, extra, scene))
        plan.finish()
        cfg = plan.config
        state = {}
        for k, tr in plan.tracks.items():
            fused = fuse_track(
                tr.frames, plan._kept(tr), boxes=tr.boxes, margin=cfg.margin, ground_clearance=cfg.ground_clearance
            )
            state[k] = (tr.boxes, tr.status, tr.n_points, tr.n_fused, fused)
            beat()
        put(("done", state, dict(plan.timer.seconds) | {"worker_cpu_s": time.process_time() - cpu0}))
    except BaseException as exc:  # noqa: BLE001 - handed to the parent, which raises it
        exc.add_note("in the track worker process:\n" + traceback.format_exc().rstrip())  # its frames are lost else
        try:
            pickle.dumps(exc)  # the queue pickles in a thread of its own, where a failure would be lost
        except Exception:  # an exception that does not pickle
            exc = RuntimeError(f"the track worker failed: {exc!r}")
        results.put(("error", exc))


class TrackWorker:
    """One worker process that refines the boxes and fuses the windows of a :class:`~spotlights.completion.fusion.TrackPlan` frame by frame,
    ahead of the process that completes the frames (a two-stage pipeline on two cores: the frame loop completes
    frame ``t`` while the worker prepares frame ``t + 1``). It computes what :meth:`~spotlights.completion.fusion.TrackPlan.frame_inputs` would
    (the same functions on the same inputs: the same numbers); the plan's frames (the crops of its tracked
    boxes) are sent to it once, after :meth:`~spotlights.completion.fusion.TrackPlan.build` has read them. Started from the fork server of
    :func:`spotlights.processes.process_pool_context` (never a fork of a process holding a model), it ends with its
    parent."""

    def __init__(self, proc: BaseProcess, jobs: Queue, results: Queue):
        self.proc, self.jobs, self.results = proc, jobs, results
        self.pending: dict = {}  # frame key -> (repl, extra) received before it was asked for
        self.done = False
        # a plan used from Python and dropped without finish()/close(): its worker (and the scans it holds) ends
        # when this object is collected, not only with the parent process
        self._finalizer = weakref.finalize(self, _end_worker, proc, jobs, results)

    @classmethod
    def start(cls) -> TrackWorker | None:
        """A started worker process, or None where none can be started or this process may use one CPU only
        (:func:`usable_cpus`: a second process would only take turns with it; the caller then works alone)."""
        if usable_cpus() < 2:
            return None
        try:
            ctx = process_pool_context()
            # the queues first: they start the resource tracker, whose start unblocks SIGINT
            jobs, results = ctx.Queue(), ctx.Queue()
            # Ctrl-C held back while the processes start: the fork server (a fresh interpreter, started with the first
            # worker) and the worker inherit the blocked signal (they ignore it), so a Ctrl-C in their first
            # milliseconds prints no traceback of theirs, and none lands half-way through the start; this process gets
            # it when unblocked (CPython's resource tracker starts the same way)
            with sigint_held():
                proc = ctx.Process(target=worker_main, args=(jobs, results), daemon=True, name="spotlights-tracks")
                proc.start()
                worker = cls(proc, jobs, results)
        except Exception:  # no processes here (an unguarded script, a sandbox): the plan works in this process
            return None
        return worker

    def crop(
        self,
        key,
        points: np.ndarray,
        todo: list[int],
        boxes: list[Box],
        grow: float,
        ground_clearance: float,
        keep: bool = False,
    ) -> None:
        """Have the worker crop the tracked boxes ``todo`` (indices into the frame's ``boxes``) of frame ``key`` from
        its scan ``points`` (N, 3): the plan's crops (:meth:`~spotlights.completion.fusion.TrackPlan.build` leaves their points None), made while
        the frames are still being read. ``keep``: the worker keeps the scan and, when it prepares the frame,
        makes its scene's crops too (:func:`spotlights.completion.frame.scene_crops`, :meth:`~spotlights.completion.fusion.TrackPlan.frame_crops`)."""
        self.jobs.put(("scan", key, points, todo, boxes, grow, ground_clearance, keep))

    def send(self, plan: TrackPlan, keys: list) -> None:
        """Hand the worker the built ``plan`` (its tracks, their frames and refiners) and the frame order."""
        self.jobs.put(
            (
                "plan",
                dict(
                    policy=plan.policy,
                    config=plan.config,
                    refine=plan.refine,
                    max_translation=plan.max_translation,
                    max_yaw=plan.max_yaw,
                    tracks=plan.tracks,
                    where=plan.where,
                    keys=keys,
                ),
            )
        )

    def _next(self, plan: TrackPlan):
        """The worker's next message (waiting for it: ``wait_s``); raises what the worker raised,
        :class:`TrackWorkerDied` (one line) when its process ended without a word, or :class:`TrackWorkerStalled` (one line; the process stopped) when it
        sent nothing, not even a sign of life, for :data:`STALL_S` seconds."""
        with plan.timer("wait_s"):
            # seconds of silence, each poll counted for at most 2 POLL_S: a pause of this process (Ctrl-Z then fg, a
            # debugger; its worker paused with it) is not the worker's silence
            silent, before = 0.0, time.monotonic()
            while True:
                try:
                    msg = self.results.get(timeout=POLL_S)
                except Empty:
                    if not self.proc.is_alive():
                        raise TrackWorkerDied(
                            f"the track worker process ended (exit code {self.proc.exitcode}) before its results; "
                            "--no-track-worker refines and fuses the tracks in this process instead"
                        ) from None
                    now = time.monotonic()
                    silent, before = silent + min(now - before, 2 * POLL_S), now
                    if silent > STALL_S:
                        self.stop()
                        raise TrackWorkerStalled(
                            f"the track worker process made no progress for {STALL_S:g} s and was stopped; "
                            "--no-track-worker refines and fuses the tracks in this process instead"
                        ) from None
                    continue
                if msg[0] != "beat":
                    break
                silent, before = 0.0, time.monotonic()
        if msg[0] == "error":
            self.stop()
            raise msg[1]
        return msg

    def _apply(self, plan: TrackPlan, key, repl: dict) -> None:
        for i, box in repl.items():  # the frame's refined boxes (record() maps its completions with them)
            tr, pos = plan.where[key][i]
            tr.boxes[pos] = box

    def inputs(self, plan: TrackPlan, key: Hashable) -> tuple[dict[int, Box], dict[int, np.ndarray]]:
        """``(repl, extra)`` of frame ``key`` as :meth:`TrackWindows._inputs` gives them (the frames come in the order
        sent; those the frame loop skips are passed over). RuntimeError for a frame the worker was not sent."""
        while key not in self.pending and not self.done:
            msg = self._next(plan)
            if msg[0] == "done":
                self._final(plan, msg)
                break
            _, k, repl, extra, scene = msg
            self._apply(plan, k, repl)
            self.pending = {k: (repl, extra)}  # only the latest: the loop asks in order
            plan.scene_crops = {k: scene} if scene is not None else {}
        if key not in self.pending:
            raise RuntimeError(f"frame {key} was not planned, or asked for out of the order given to build()")
        return self.pending.pop(key)

    def _final(self, plan: TrackPlan, msg) -> None:
        _, state, seconds = msg
        for k, (boxes, status, n_points, n_fused, fused) in state.items():
            tr = plan.tracks[k]
            tr.boxes, tr.status, tr.fused = boxes, status, fused
            # the worker prepared every frame; the counts are those of the frames the loop asked for, as in one process
            asked = [key in plan.asked for key in tr.keys]
            tr.n_points = [c if a else 0 for c, a in zip(n_points, asked)]
            tr.n_fused = [c if a else 0 for c, a in zip(n_fused, asked)]
            tr.refiner = None  # the worker refined every frame
        for name, sec in seconds.items():
            plan.timer.add(name, sec)
        self.done = True
        self.pending.clear()
        self.stop()

    def finish(self, plan: TrackPlan) -> None:
        """Take the worker's remaining messages and its final state into ``plan``; end the process."""
        while not self.done:
            msg = self._next(plan)
            if msg[0] == "done":
                self._final(plan, msg)
            else:
                self._apply(plan, msg[1], msg[2])

    def stop(self) -> None:
        """End the process (now, when it has not finished). Idempotent."""
        self._finalizer()


def _end_worker(proc, jobs, results) -> None:
    """End a :class:`TrackWorker`'s process ``proc`` and close its queues (its ``stop``, and its finalizer)."""
    try:
        jobs.put(None)  # a worker still waiting for its plan returns
    except Exception:  # noqa: S110 - a closed queue: the process is ending anyway
        pass
    proc.join(timeout=POLL_S)
    if proc.is_alive():
        proc.terminate()
        proc.join(timeout=5)
    if proc.is_alive():  # stuck where SIGTERM does not reach it
        proc.kill()
        proc.join(timeout=5)
    for q in (jobs, results):
        q.cancel_join_thread()
        q.close()


__all__ = [
    "BEAT_S",
    "CGROUP_CPU_MAX",
    "POLL_S",
    "STALL_S",
    "TrackWorker",
    "TrackWorkerDied",
    "TrackWorkerStalled",
    "cgroup_cpu_limit",
    "threads_beside_worker",
    "usable_cpus",
    "worker_main",
]
