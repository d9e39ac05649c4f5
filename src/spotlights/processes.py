"""Processes and thread pools: process pools that end with their parent and say when a script cannot start them,
Ctrl-C held while modules import, the work units of a pool mapped in order, named shared thread pools."""

from __future__ import annotations

import ast
import contextlib
import os
import sys
import threading
import time
import types
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from .errors import (
    ProcessFailure,
    SpotlightsError,
)

# A pool in which no work unit finishes for this long is considered hung (seconds).
POOL_TIMEOUT_S = 1800.0


def _is_main_guard(test: ast.expr) -> bool:
    """``__name__ == "__main__"`` (either order)."""
    if not (isinstance(test, ast.Compare) and len(test.ops) == 1 and isinstance(test.ops[0], ast.Eq)):
        return False
    sides = [test.left, test.comparators[0]]
    return any(isinstance(s, ast.Name) and s.id == "__name__" for s in sides) and any(
        isinstance(s, ast.Constant) and s.value == "__main__" for s in sides
    )


def unguarded_main_call() -> tuple[str, int] | None:
    """Where the main script starts worker processes outside ``if __name__ == "__main__":``.

    Worker processes started with ``spawn`` or ``forkserver`` re-import the main script; code
    at its top level that starts a pool then runs again in every worker, which dies, and a
    ``multiprocessing.Pool`` replaces it without end. Returns ``(script, line)`` when the
    calling stack runs the main script's top-level code outside such a guard, else None
    (``python -m package``, interactive sessions, code under the guard, code not called
    from the main script's top level).
    """
    main = sys.modules.get("__main__")
    spec = getattr(main, "__spec__", None)
    if main is None or (spec is not None and (spec.name == "__main__" or spec.name.endswith(".__main__"))):
        return None
    script = getattr(main, "__file__", None)
    if not script:
        return None
    frame: types.FrameType | None = sys._getframe(1)
    while frame is not None and not (frame.f_globals is main.__dict__ and frame.f_code.co_name == "<module>"):
        frame = frame.f_back
    if frame is None:
        return None
    line = frame.f_lineno
    try:
        tree = ast.parse(Path(script).read_text(encoding="utf-8", errors="replace"))
    except (OSError, SyntaxError, ValueError):
        return None
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and _is_main_guard(node.test) and node.lineno <= line <= (node.end_lineno or line):
            return None
    return script, line


def check_can_start_processes(what: str = "worker processes") -> None:
    """Raise a one-line :class:`SpotlightsError` where starting ``what`` would respawn without end.

    In a worker that is still importing the main script (the unguarded script case, seen from
    inside), and in a main script whose top-level code starts them without the guard.
    """
    import multiprocessing as mp

    if getattr(mp.current_process(), "_inheriting", False):
        raise SpotlightsError(
            f"cannot start {what} from a worker that is importing the main script; "
            'put the script\'s code under `if __name__ == "__main__":`'
        )
    where = unguarded_main_call()
    if where is not None:
        script, line = where
        raise SpotlightsError(
            f"{script}:{line}: this call starts {what}, which re-import the script; put the "
            'script\'s code under `if __name__ == "__main__":` (or use workers=1)'
        )


def process_pool_context(check: bool = True):
    """The multiprocessing context for pools of workers that build Embree scenes.

    ``forkserver`` where available (Linux), else ``spawn``; never a plain ``fork`` of the
    caller. Embree builds its BVHs on TBB worker threads, and TBB is not fork-safe: a
    process forked while the parent's TBB threads are active inherits a thread pool that
    does not exist, and its first BVH build can wait forever. The fork server is a fresh
    interpreter that has never run Embree (or torch), so its children start clean. Results
    do not depend on the start method. As with ``spawn`` (and Python 3.14's default), a
    script that asks for ``workers > 1`` needs the usual ``if __name__ == "__main__":`` guard;
    without it (``check``) this raises a one-line :class:`SpotlightsError` instead of letting
    the pool respawn its workers without end (:func:`check_can_start_processes`).
    """
    import multiprocessing as mp
    import threading

    if check:
        check_can_start_processes()
    if "forkserver" not in mp.get_all_start_methods():
        return mp.get_context("spawn")
    ctx = mp.get_context("forkserver")
    if threading.current_thread() is threading.main_thread():
        # the fork server dies with this process (a parent-death signal follows the thread that
        # started it: only the main thread lives as long as the process); see _parent_death
        ctx.set_forkserver_preload(["__main__", "spotlights._parent_death"])
    return ctx


@contextlib.contextmanager
def sigint_held() -> Iterator[None]:
    """Ctrl-C (SIGINT) blocked in this thread for the body, delivered when it ends (POSIX; elsewhere nothing).

    For what a Ctrl-C must not land in the middle of: processes started meanwhile inherit the signal blocked (the
    fork server of :func:`process_pool_context` and its workers, which ignore it: no traceback of theirs; CPython's
    resource tracker starts the same way), and imports of C extensions that turn a KeyboardInterrupt into an
    ImportError (numpy). The interrupt then comes as a KeyboardInterrupt where the body ends."""
    import signal

    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    before = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def die_with_parent() -> None:
    """Linux: have this process killed (SIGKILL) when its parent dies (``PR_SET_PDEATHSIG``),
    so that pool workers never outlive a killed build; elsewhere nothing. A process whose
    parent is already gone exits at once."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    try:
        if ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL), 0, 0, 0) != 0:  # PR_SET_PDEATHSIG
            return
    except (OSError, AttributeError):
        return
    if os.getppid() == 1:  # the parent died before the call: the signal will not come
        os._exit(1)


def _quiet_worker(initializer, initargs) -> None:
    """Pool workers leave Ctrl-C to the parent (which stops the pool), die with their parent,
    then run ``initializer``."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    die_with_parent()  # the fork server, which dies with the pool's owner (process_pool_context)
    if initializer is not None:
        initializer(*initargs)


def process_map(
    fn: Callable,
    items: Iterable,
    workers: int,
    *,
    initializer: Callable | None = None,
    initargs: tuple = (),
    ordered: bool = True,
    timeout: float | None = POOL_TIMEOUT_S,
    what: str = "work unit",
) -> Iterator:
    """Yield ``fn(item)`` for every item, on ``workers`` processes (in this process for one).

    For independent work units only (many meshes, dataset units, studies): results are the
    same whatever ``workers``; ``ordered`` yields them in input order, else as they finish.
    Never hangs and never respawns without end: a worker that dies (killed, out of memory)
    or a pool in which no unit finishes within ``timeout`` seconds raises a one-line
    :class:`SpotlightsError`; an exception raised by ``fn`` is re-raised here as it is
    (a :class:`SpotlightsError` keeps its message). The pool is stopped on any error, on
    Ctrl-C, and when the caller stops iterating early.
    """
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        if initializer is not None:
            initializer(*initargs)
        for item in items:
            yield fn(item)
        return
    from concurrent.futures import FIRST_COMPLETED, wait
    from concurrent.futures.process import BrokenProcessPool

    pool = start_process_pool(min(workers, len(items)), initializer, initargs)
    ok = False
    try:
        with sigint_held():  # the fork server and the workers start as these are submitted: with Ctrl-C held back
            futures = {pool.submit(fn, item): i for i, item in enumerate(items)}
        pending = set(futures)
        ready: dict = {}
        nxt = 0
        while pending:
            done, pending = wait(pending, timeout=timeout, return_when=FIRST_COMPLETED)
            if not done:
                raise ProcessFailure(
                    f"no {what} finished within {timeout:.0f} s on {min(workers, len(items))} "
                    "worker processes: stopped (a worker hangs?)"
                )
            for fut in done:
                try:
                    res = fut.result()
                except BrokenProcessPool:
                    raise ProcessFailure(
                        f"a worker process died while computing a {what} (killed, or out of "
                        "memory?); run again to resume, or with fewer workers"
                    ) from None
                if ordered:
                    ready[futures[fut]] = res
                else:
                    yield res
            while ordered and nxt in ready:
                yield ready.pop(nxt)
                nxt += 1
        ok = True
    finally:
        if not ok:
            stop_process_pool(pool)
        else:
            pool.shutdown(wait=True)


def start_process_pool(workers: int, initializer: Callable | None = None, initargs: tuple = ()):
    """A ``ProcessPoolExecutor`` of ``workers`` processes as every pool of the package starts one: from the fork
    server of :func:`process_pool_context` (refusing where processes cannot start), its workers ignoring Ctrl-C
    (the owner stops the pool: :func:`stop_process_pool`) and dying with their parent, then running
    ``initializer(*initargs)``. Workers start as tasks come (the executor's rule): submit the first tasks inside
    :func:`sigint_held` so that the fork server and the workers start with Ctrl-C blocked. The resource tracker is
    started here, before any such block: its start unblocks SIGINT in the calling thread, which would let the fork
    server start with Ctrl-C live (a KeyboardInterrupt traceback of its own)."""
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    return ProcessPoolExecutor(
        workers, mp_context=process_pool_context(), initializer=_quiet_worker, initargs=(initializer, initargs)
    )


def stop_process_pool(pool, grace: float = 0.0) -> None:
    """Stop a ProcessPoolExecutor: cancel what has not started; with ``grace`` > 0 seconds, let the tasks that are
    running finish for up to that long (workers that end on their own leave no half-cleaned queue: terminated
    mid-task, the resource tracker may warn of a leaked semaphore at exit); then end the workers still alive."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    if grace > 0:
        deadline = time.monotonic() + grace
        for p in processes:
            p.join(max(0.0, deadline - time.monotonic()))
        if manager is not None:
            manager.join(max(0.0, deadline - time.monotonic()))
    for p in processes:
        with contextlib.suppress(Exception):
            p.terminate()
    for p in processes:
        with contextlib.suppress(Exception):
            p.join(5)
            if p.is_alive():
                p.kill()
    _end_manager_thread(pool, manager)


def _end_manager_thread(pool, manager, timeout: float = 5.0) -> None:
    """Let the pool's manager thread see its workers gone and close its wake-up pipe, then forget it.

    At interpreter exit CPython 3.11 wakes every pool's manager thread through that pipe without the pool's lock:
    if the manager closes the pipe in the same instant (it does once its workers have ended), the exit prints an
    ``OSError: Bad file descriptor`` traceback after our one line. Joined here (bounded), the pipe is closed
    before exit and the exit hook skips it; a manager still alive after ``timeout`` seconds is taken out of the
    exit hook's list under the pool's lock, so that nothing writes to its pipe while it closes it."""
    if manager is None:
        return
    with contextlib.suppress(Exception):
        manager.join(timeout)
    with contextlib.suppress(Exception):
        from concurrent.futures import process as futures_process

        lock = getattr(pool, "_shutdown_lock", None) or contextlib.nullcontext()
        with lock:
            futures_process._threads_wakeups.pop(manager, None)


_THREAD_POOLS: dict[str, tuple] = {}  # name -> (owner pid, executor, threads)


_THREAD_POOLS_LOCK = threading.Lock()


def _forget_thread_pools_after_fork() -> None:
    """In a forked child: the parent's pool threads do not exist here, and the lock may have been held by one of
    them at the fork; start from nothing (a pool that kept them would take jobs and never run them)."""
    global _THREAD_POOLS_LOCK
    _THREAD_POOLS_LOCK = threading.Lock()
    _THREAD_POOLS.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_thread_pools_after_fork)


def shared_thread_pool(name: str, threads: int, initializer: Callable[[], object] | None = None) -> ThreadPoolExecutor:
    """The process-wide pool of threads called ``spotlights-NAME...`` with at least ``threads`` workers (one per
    name, made on first use; a larger request replaces it), each thread starting with ``initializer()``. A process
    forked after the pool exists builds its own. For work that runs without the GIL (Embree's ray casts, scipy's
    KD-trees, torch): the callers wait for their futures; the idle threads cost nothing and end with the
    interpreter."""
    with _THREAD_POOLS_LOCK:
        pool = _THREAD_POOLS.get(name)
        if pool is None or pool[0] != os.getpid() or pool[2] < threads:
            if pool is not None and pool[0] == os.getpid():
                pool[1].shutdown(wait=False)
            executor = ThreadPoolExecutor(threads, thread_name_prefix=f"spotlights-{name}", initializer=initializer)
            pool = (os.getpid(), executor, threads)
            _THREAD_POOLS[name] = pool
        return pool[1]


def forget_interrupt() -> None:
    """Clear CPython's note of an unhandled Ctrl-C after handling it, so that the exit code stays ours.

    CPython (3.11-3.13) notes a KeyboardInterrupt as unhandled whenever one leaves code run by ``exec`` or ``eval``
    of a string (``dataclasses`` and ``namedtuple`` build their methods that way, at import), even when a caller
    handles it later; ``python -m spotlights`` then ends by the signal itself (killed by SIGINT) instead of exit
    code 130 (Ctrl-C about 1.2 s into ``real complete``, while modules were imported). Each ``exec`` of a string
    resets that note first: one that finishes clears it."""
    exec("pass")  # noqa: S102 - a constant string: resets the interpreter's unhandled-interrupt note


def in_main_thread() -> bool:
    """Signal handlers can only be installed from the main thread."""
    import threading

    return threading.current_thread() is threading.main_thread()
