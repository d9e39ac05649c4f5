"""The frame pictures of a multi-frame run drawn beside the frame loop: a few worker processes at a lower
priority, bounded waits (a hung one ends the run with one line), every picture written before the run ends."""

from __future__ import annotations

import os
from concurrent.futures import Future
from pathlib import Path

from ..errors import ParameterError, ProcessFailure
from ..processes import sigint_held, start_process_pool, stop_process_pool
from .frame_selection import FramesSettings
from .fusion import usable_cpus
from .pictures import bev_scene, bev_scene_png, result_png
from .results import SceneResult

#: The most processes that draw PNGs by default (:func:`picture_workers`); each holds ~140 MB (matplotlib).
PICTURE_WORKERS_MAX = 8


#: Seconds a frame's PNG may take in a picture process before the run stops with one line (a hung process; a
#: frame of scene-0523 takes about 0.5 s, a slow machine a few): the run never waits for ever on a picture.
PICTURE_STALL_S = 120.0


#: Seconds the picture processes get to finish the picture they draw when the run ends (then they are ended).
PICTURE_CLOSE_S = 10.0


def picture_workers(asked: int | None, n_frames: int) -> int:
    """How many processes draw a run's PNGs (:class:`PictureProcesses`): ``asked`` (``--picture-workers``), by
    default one per usable CPU (:func:`~spotlights.completion.fusion.usable_cpus`: drawing a frame costs several
    times its completion, so the frame loop's own CPU is mostly free), at most :data:`PICTURE_WORKERS_MAX`, none on
    one CPU; never more than ``n_frames`` and none for a single frame (0: the writer thread draws them, one frame
    at a time, as before)."""
    if asked is None:
        cpus = min(usable_cpus(), PICTURE_WORKERS_MAX)
        n = cpus if cpus >= 2 else 0
    else:
        n = int(asked)
    if n < 0:
        raise ParameterError(f"`picture_workers` must be >= 0, got {n}", "picture_workers")
    return 0 if n_frames < 2 else min(n, n_frames)


#: Frames whose pictures may wait to be drawn while the frame loop goes on, beyond one per picture process: the
#: pictures are drawn in the loop's idle moments rather than the loop waiting for each (each waiting frame holds its
#: result in memory, a few MB for a nuScenes frame).
PICTURE_BACKLOG = 4


#: How much lower a picture process runs than the frame loop (``os.nice``): a picture waits for a free core, the
#: frame loop does not wait for the picture.
PICTURE_NICE = 5


def _lower_priority() -> None:
    """A picture process's start: :data:`PICTURE_NICE` below its parent (where the system allows it)."""
    try:
        os.nice(PICTURE_NICE)
    except (AttributeError, OSError):  # pragma: no cover - not POSIX, or refused
        pass


def _ready_to_draw(closeups: bool = True) -> None:
    """In a picture process (which imported this module, so the drawing code, to run this): import what draws
    (matplotlib's Agg and 3-D axes for the close-ups; PIL for the raster) while the frame loop's model loads."""
    if closeups:
        import matplotlib.backends.backend_agg  # noqa: F401
        import mpl_toolkits.mplot3d  # noqa: F401
    else:
        import PIL.PngImagePlugin  # noqa: F401


class PictureProcesses:
    """Worker processes (:func:`~spotlights.processes.start_process_pool`: the fork server, Ctrl-C left to this
    process) that draw frames' PNGs (:func:`~spotlights.completion.pictures.result_png`), ``workers`` frames at once,
    while the frame loop completes the next ones. The bytes are those of drawing in this process (the same
    function; matplotlib's defaults in both: rcParams changed in this process do not reach the workers); the
    writer thread writes them in frame order."""

    def __init__(self, workers: int, closeups: bool = False) -> None:
        self.workers = int(workers)
        self.closeups = bool(closeups)  # matplotlib's close-ups too (result_png)
        pool = None
        try:
            # Ctrl-C held back while they start (as the track worker's start): the fork server and the workers
            # inherit the blocked signal (they ignore it), and none lands half-way through the start; one that came
            # meanwhile is raised as the block ends, and stops the processes here
            # the resource tracker started (which unblocks SIGINT) first
            pool = start_process_pool(self.workers, _lower_priority)
            with sigint_held():
                for _ in range(self.workers):  # each task starts a process: their imports overlap the model's load
                    pool.submit(_ready_to_draw, self.closeups)
        except BaseException:
            if pool is not None:
                stop_process_pool(pool)
            raise
        self.pool = pool

    @classmethod
    def start(cls, s: FramesSettings, n_frames: int) -> PictureProcesses | None:
        """The processes of a run of ``s`` over ``n_frames`` frames, started; None when no picture is drawn,
        :func:`picture_workers` says 0, or no process can be started here (an unguarded script, a sandbox: the
        writer thread draws the pictures, as with 0)."""
        # the bird's-eye raster costs a few hundredths of a second: one process draws it (none on one CPU), beside the
        # frame loop and below its priority; the close-ups (matplotlib) get one process per CPU by default
        raster = 1 if usable_cpus() >= 2 else 0
        asked = s.picture_workers if s.closeups or s.picture_workers is not None else raster
        n = 0 if s.no_pictures else picture_workers(asked, n_frames)
        if n == 0:
            return None
        try:
            return cls(n, s.closeups)
        except Exception:
            return None

    def draw(self, result: SceneResult, title: str) -> Future:
        """Start drawing ``result``'s PNG; a future of its bytes (:meth:`png`). When a picture process has died
        already (the pool is broken), the future holds that error: it is reported in frame order, by :meth:`png`."""
        from concurrent.futures.process import BrokenProcessPool

        try:
            if self.closeups:
                return self.pool.submit(result_png, result, title, True)
            return self.pool.submit(bev_scene_png, *bev_scene(result), title)  # what it draws, not the result
        except BrokenProcessPool as exc:
            failed: Future = Future()
            failed.set_exception(exc)
            return failed

    @staticmethod
    def png(drawn: Future, path: Path) -> bytes:
        """The bytes of ``drawn`` (waiting for them, :data:`PICTURE_STALL_S` at most); a one-line
        :class:`~spotlights.errors.ProcessFailure` naming ``path`` when the process drawing it ended first (killed,
        say for memory) or took longer than that (hung)."""
        from concurrent.futures import TimeoutError as FutureTimeout
        from concurrent.futures.process import BrokenProcessPool

        hint = "--picture-workers 0 draws the pictures in this process"
        try:
            return drawn.result(timeout=PICTURE_STALL_S)
        except BrokenProcessPool:
            raise ProcessFailure(
                f"{path}: the process drawing it ended before it was done (killed, or out of memory?); {hint}"
            ) from None
        except FutureTimeout:
            raise ProcessFailure(
                f"{path}: the process drawing it made no progress for {PICTURE_STALL_S:g} s and was stopped; {hint}"
            ) from None

    def close(self) -> None:
        """Stop the processes: what is not being drawn yet is dropped, a picture being drawn gets
        :data:`PICTURE_CLOSE_S` to finish (the run has waited for its frames in flight first anyway), then the
        processes still alive are ended (:func:`~spotlights.processes.stop_process_pool`: workers ended mid-task can
        leave the resource tracker warning of a leaked semaphore at exit, seen after a Ctrl-C during the frames)."""
        stop_process_pool(self.pool, grace=PICTURE_CLOSE_S)
