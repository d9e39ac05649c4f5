"""Small utilities shared by every layer: atomic writes (and sweeping their stale temporaries),
an exclusive lock, process pools that fail instead of hanging, the one stage timer
(:class:`StageTimer`) and the one strict reader of settings mappings (:func:`settings_from_dict`)."""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import difflib
import os
import re
import sys
import tempfile
import threading
import time
import types
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TypeVar

from .errors import (
    InputFileError,
    OutputFileError,
    ParameterError,
    ProcessFailure,
    SpotlightsError,
    parameter_names,
    shown,
)

_T = TypeVar("_T")

# ---------------------------------------------------------------------------- atomic writes

# Temporaries are named ".NAME.PID-RANDOM.partSUFFIX" beside NAME: the PID tells a stale one
# (its writer is gone) from one that a live process is writing right now.
_TEMP_RE = re.compile(r"^\.(?P<name>.+)\.(?:(?P<pid>\d+)-)?[A-Za-z0-9_]+\.part(?:\.[^/]*)?$")


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def sweep_temporaries(path: str | os.PathLike) -> list[Path]:
    """Remove the stale temporaries that an interrupted write of ``path`` left beside it.

    A temporary of :func:`atomic_output` is ``.NAME.PID-RANDOM.partSUFFIX`` in ``path``'s
    folder; it is stale when the process ``PID`` no longer exists (killed, crashed, power
    loss), or when it has no PID (written by spotlights < 0.x). Temporaries of a live process
    (a concurrent write of the same target) are left alone. Returns the removed paths.
    """
    path = Path(path)
    removed: list[Path] = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    prefix = f".{path.name}."
    for entry in entries:
        if not entry.name.startswith(prefix):
            continue
        m = _TEMP_RE.match(entry.name)
        if m is None or m.group("name") != path.name:
            continue
        pid = m.group("pid")
        if pid is not None and _pid_alive(int(pid)):
            continue
        with contextlib.suppress(OSError):
            if entry.is_dir(follow_symlinks=False):
                continue
            os.unlink(entry.path)
            removed.append(Path(entry.path))
    return removed


def sweep_folder_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Remove the stale temporaries of :func:`atomic_output` anywhere under ``folder``: files named
    ``.NAME.PID-RANDOM.partSUFFIX`` whose process ``PID`` no longer exists (a killed run's
    half-written outputs, whatever their target). Only names with a PID are touched, never
    another program's files. Returns the removed paths."""
    removed: list[Path] = []
    for root, _dirs, files in os.walk(os.fspath(folder)):
        for name in files:
            m = _TEMP_RE.match(name)
            if m is None or m.group("pid") is None or _pid_alive(int(m.group("pid"))):
                continue
            path = Path(root) / name
            with contextlib.suppress(OSError):
                path.unlink()
                removed.append(path)
    return removed


def _missing_parents(folder: Path) -> list[Path]:
    """The folders ``mkdir(parents=True)`` would create for ``folder``, outermost first."""
    missing = []
    p = folder
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    return missing[::-1]


def _remove_empty(folders: list[Path]) -> None:
    for d in reversed(folders):
        with contextlib.suppress(OSError):
            d.rmdir()  # only when empty


def os_error_reason(exc: OSError) -> str:
    """The reason of an OS error in a few words (``strerror``, else the first line of the message)."""
    if exc.errno is not None and exc.strerror:
        return exc.strerror[0].lower() + exc.strerror[1:]
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    m = re.search(r"errno = (\d+)", text)  # h5py: "Can't write data (file write failed: ..., errno = 28, ...)"
    if m:
        return os.strerror(int(m.group(1))).lower()
    return text[:160]


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    Nothing half-written is ever left under ``path``: if the body raises, the temporary file
    is removed, ``path`` is untouched and folders created for it are removed again. Stale
    temporaries of earlier, killed writes of the same ``path`` are swept first
    (:func:`sweep_temporaries`). The temporary name keeps the target's suffix (or ``suffix``)
    so that writers choosing a format from the extension (trimesh, matplotlib) still work.

    Raises
    ------
    OutputFileError : the folder cannot be created, or the file cannot be written or renamed
        (read-only folder, no permission, full disk, ...): one line naming ``path`` and the reason.
    """
    path = Path(path)
    sfx = suffix if suffix is not None else "".join(path.suffixes[-1:])
    created = _missing_parents(path.parent)
    tmp_path = None
    try:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            if path.is_dir():
                raise OutputFileError(path, "is a folder, expected a file name")
            sweep_temporaries(path)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}-", suffix=f".part{sfx}", dir=path.parent)
            os.close(fd)
            tmp_path = Path(tmp)
            # mkstemp creates the file 0600; give it the permissions a plain open() would (0666 & ~umask)
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp_path, 0o666 & ~umask)
            yield tmp_path
            os.replace(tmp_path, path)
        except OSError as exc:
            name = getattr(exc, "filename", None)
            ours = name in (None, str(tmp_path), str(path), str(path.parent), *map(str, created)) or (
                # the temporary mkstemp could not create (an unwritable folder): named by the file it stands for
                Path(str(name)).parent == path.parent and Path(str(name)).name.startswith(f".{path.name}.")
            )
            if not ours:
                raise  # about another file: the caller's own error
            raise OutputFileError(path, f"cannot write ({os_error_reason(exc)})") from exc
    except BaseException:
        if tmp_path is not None:
            with contextlib.suppress(OSError):
                tmp_path.unlink()
        _remove_empty(created)
        raise


class _WriteGuard:
    """A file for h5py's ``fileobj`` driver that never lets a failed write reach HDF5.

    HDF5 (2.0, sec2 driver) does not survive a write error: the file's close fails as well,
    and freeing its objects later crashes the interpreter (a segmentation fault after the
    traceback, on a full disk). Here the first failed write is recorded (``error``) and that
    write and every later one are kept in memory instead, so HDF5 sees a working file, closes
    it cleanly, and the caller raises the recorded error. Reads see the bytes on disk with the
    kept ones over them.
    """

    def __init__(self, path: Path, mode: str):
        flags = os.O_RDWR | (0 if mode == "r+" else os.O_CREAT | os.O_TRUNC)
        self.fd = os.open(path, flags | getattr(os, "O_CLOEXEC", 0), 0o666)
        self.pos = 0
        self.error: OSError | None = None
        self.kept: list[tuple[int, bytes]] = []  # (offset, bytes) not written since the error

    def seek(self, offset: int, whence: int = 0) -> int:
        self.pos = offset if whence == 0 else self.pos + offset if whence == 1 else self._size() + offset
        return self.pos

    def tell(self) -> int:
        return self.pos

    def _size(self) -> int:
        return max([os.fstat(self.fd).st_size] + [a + len(b) for a, b in self.kept])

    def read(self, size: int = -1) -> bytes:
        size = self._size() - self.pos if size < 0 else size
        data = bytearray(os.pread(self.fd, size, self.pos))
        if self.kept:
            data.extend(bytes(max(0, min(size, self._size() - self.pos) - len(data))))
            for a, b in self.kept:
                lo, hi = max(a, self.pos), min(a + len(b), self.pos + len(data))
                if lo < hi:
                    data[lo - self.pos : hi - self.pos] = b[lo - a : hi - a]
        self.pos += len(data)
        return bytes(data)

    def write(self, data) -> int:
        data = memoryview(data).cast("B")
        done = 0
        while self.error is None and done < len(data):
            try:
                done += os.pwrite(self.fd, data[done:], self.pos + done)
            except OSError as exc:
                self.error = exc
        if done < len(data):
            self.kept.append((self.pos + done, bytes(data[done:])))
        self.pos += len(data)
        return len(data)

    def truncate(self, size: int | None = None) -> int:
        size = self.pos if size is None else size
        if self.error is None:
            try:
                os.ftruncate(self.fd, size)
            except OSError as exc:
                self.error = exc
        return size

    def flush(self) -> None:
        pass

    def check(self) -> None:
        """Raise the recorded write error, if any (a long write stops at once)."""
        if self.error is not None:
            raise self.error


@contextlib.contextmanager
def hdf5_output(path: str | os.PathLike, mode: str = "w", **kwargs) -> Iterator[tuple]:
    """Open ``path`` (a temporary of :func:`atomic_output`) for writing with h5py; yields
    ``(file, check)``. A write that fails (a full disk) never crashes the interpreter: the
    file is closed cleanly and :class:`OSError` naming ``path`` is raised when the body ends,
    or at once from ``check()``, which a long write calls after each step.

    mode : ``"w"`` (create or truncate) or ``"r+"`` (an existing file); kwargs go to ``h5py.File``.
    """
    import h5py

    guard = _WriteGuard(Path(path), mode)
    try:
        with h5py.File(guard, mode, **kwargs) as f:
            yield f, guard.check
    except OSError:
        if guard.error is None:
            raise
    finally:
        os.close(guard.fd)
    if guard.error is not None:
        exc = guard.error
        raise OSError(exc.errno, exc.strerror, os.fspath(path)) from None


def check_writable(*paths: str | os.PathLike | None) -> None:
    """Fail now, before the work, when an output cannot be written: for each path (None is
    skipped) create and remove a temporary file in its folder, or in the nearest folder that
    exists (nothing is created for folders that do not exist yet).

    Raises :class:`OutputFileError` naming the path and the reason (read-only, no permission).
    """
    for path in paths:
        if path is None:
            continue
        p = Path(path)
        if p.is_dir():
            raise OutputFileError(p, "is a folder, expected a file name")
        folder = p.parent
        while not folder.exists() and folder != folder.parent:
            folder = folder.parent
        if not folder.is_dir():
            raise OutputFileError(p, f"{folder} is not a folder")
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.{os.getpid()}-", suffix=".part", dir=folder)
            os.close(fd)
            os.unlink(tmp)
        except OSError as exc:
            raise OutputFileError(p, f"cannot write ({os_error_reason(exc)})") from None


def check_suffix(path: str | os.PathLike | None, suffixes: tuple[str, ...], what: str, option: str = "out") -> None:
    """Refuse an output whose extension would not match what is written: a :class:`ParameterError` naming
    ``option`` and ``path`` (None is skipped). ``suffixes``: the accepted lower-case extensions, e.g.
    ``(".h5", ".hdf5")``; ``what``: the kind of file, e.g. ``"the picture"``."""
    if path is None:
        return
    suffix = Path(path).suffix.lower()
    if suffix not in suffixes:
        kinds = " or ".join(suffixes)
        raise ParameterError(
            f"{shown(option)} {path}: {what} is written as {kinds}; name it {Path(path).stem or 'FILE'}{suffixes[0]}",
            *parameter_names(option),
        )


@contextlib.contextmanager
def exclusive_lock(lock_file: str | os.PathLike, busy: str, remove: bool = False) -> Iterator[None]:
    """Hold an exclusive, non-blocking lock on ``lock_file`` (created if missing) for the body.

    The one file lock of the project: two processes that must not write the same output
    (two dataset builds into one parts folder, two ``add-rig`` runs on one file, two
    reproductions in one folder) take the same lock file; the second fails at once with
    :class:`~spotlights.errors.SpotlightsError` ``busy`` (a one-line message naming the path)
    instead of waiting. The lock is released when the body ends or the process dies (``flock``).
    ``remove``: the lock file is deleted when the body ends (still holding the lock; a process that
    locked the deleted file finds another file at the path and tries again), so nothing stays beside a
    user's file; else the small lock file stays. Not POSIX (no ``fcntl``): no lock.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: no lock
        yield
        return
    while True:
        fh = open(lock_file, "a")
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            raise SpotlightsError(busy) from None
        try:
            same = os.stat(lock_file).st_ino == os.fstat(fh.fileno()).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        fh.close()  # the holder before us removed the file we locked: lock the one at the path now
    try:
        yield
    finally:
        try:
            if remove:
                Path(lock_file).unlink(missing_ok=True)
        finally:
            fh.close()


@contextlib.contextmanager
def output_folder(folder: str | os.PathLike) -> Iterator[Path]:
    """Create ``folder`` (and its parents) for the body's outputs; if the body fails, remove
    the folders this call created as long as they are empty (nothing left behind)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputFileError(folder, "exists and is not a folder")
    created = _missing_parents(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _remove_empty(created)
        raise OutputFileError(folder, f"cannot create the folder ({os_error_reason(exc)})") from exc
    try:
        yield folder
    except BaseException:
        _remove_empty(created)
        raise


# ---------------------------------------------------------------------------- process pools

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


# ---------------------------------------------------------------------------- stage timing


class StageTimer:
    """The one stage timer: wall seconds spent in named stages, summed over repeated entries.

    ``with timer("read"): ...`` adds the block's wall time (``time.perf_counter``, seconds) to
    ``timer.seconds["read"]``; stages keep the order of their first entry. ``timer.add(name, s)``
    adds a time measured elsewhere; ``timer.lap(name)`` adds the time since the previous lap (or since
    the timer was made) to ``name``, for consecutive stages of straight-line code (early returns, no
    block to indent); ``timer.total`` is the sum. Latency of repeated calls (medians,
    round-robin) is :func:`spotlights.learning.bench.time_calls`'s job, not this one's.

    >>> t = StageTimer()
    >>> with t("a"):
    ...     pass
    >>> list(t.seconds), t.seconds["a"] >= 0.0
    (['a'], True)
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        self._mark = time.perf_counter()  # where the next lap starts

    @contextlib.contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - t0)

    def add(self, name: str, seconds: float) -> None:
        """Add ``seconds`` (float, wall seconds) to stage ``name`` and count one entry."""
        self.seconds[name] = self.seconds.get(name, 0.0) + float(seconds)
        self.counts[name] = self.counts.get(name, 0) + 1

    def lap(self, name: str) -> float:
        """Add the wall seconds since the previous :meth:`lap` (or since this timer was made) to stage
        ``name`` and return them (float, seconds). Laps ignore ``with`` blocks and :meth:`add`."""
        t = time.perf_counter()
        seconds, self._mark = t - self._mark, t
        self.add(name, seconds)
        return seconds

    @property
    def total(self) -> float:
        """Sum of every stage's seconds."""
        return float(sum(self.seconds.values()))

    def rounded(self, digits: int = 3) -> dict[str, float]:
        """``{stage: seconds}`` rounded to ``digits`` (for JSON reports)."""
        return {k: round(v, digits) for k, v in self.seconds.items()}


# ---------------------------------------------------------------------------- thread pools


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


# ---------------------------------------------------------------------------- settings


def did_you_mean(key: object, known: Iterable[str]) -> str:
    """``" (did you mean 'x'?)"`` for the closest known name to ``key``, or ``""``."""
    close = difflib.get_close_matches(str(key), list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def settings_from_dict(cls: type, d: object, where: str | os.PathLike | None = None, **fixed: object):
    """The one policy for reading a settings dataclass from a mapping (a YAML file, a JSON
    record, a dataset's attributes): every key must be a field of ``cls``; an unknown key is an
    error naming ``where`` and suggesting the closest field; a non-mapping is an error too.

    Parameters
    ----------
    cls : a dataclass type.
    d : the mapping (None reads as empty).
    where : a file path (the error is an :class:`InputFileError` naming it) or a label such as
        ``"sensor"`` (a :class:`ParameterError` prefixed with it).
    fixed : values passed to ``cls`` beside ``d``'s (not checked against ``d``).

    Returns ``cls(**d, **fixed)``; a wrong value that ``cls`` itself rejects keeps its own error.
    """

    def fail(msg: str) -> SpotlightsError:
        if where is not None and Path(os.fspath(where)).suffix.lower() in (".yaml", ".yml", ".json", ".h5", ".hdf5"):
            return InputFileError(where, msg)
        return ParameterError(f"{where}: {msg}" if where else msg)

    if d is None:
        d = {}
    if not isinstance(d, Mapping):
        raise fail(f"expected a mapping of {cls.__name__} settings, got {type(d).__name__}")
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    for key in d:
        if key not in names:
            raise fail(f"unknown setting {key!r}{did_you_mean(key, names)} (known: {', '.join(names)})")
    return cls(**dict(d), **fixed)


def settings_from_namespace(cls: type[_T], namespace: object, **values: object) -> _T:
    """The settings dataclass ``cls`` of an object with one attribute per field (an ``argparse.Namespace``):
    each field the namespace has is taken from the attribute of its name (or from ``values``, for fields
    named otherwise), the others keep their defaults; attributes that are no field are ignored (the
    command-line options map one to one onto the fields)."""
    names = [f.name for f in dataclasses.fields(cls) if f.init and f.name not in values]  # type: ignore[arg-type]
    return cls(**{n: getattr(namespace, n) for n in names if hasattr(namespace, n)}, **values)


# ---------------------------------------------------------------------------- inputs and outputs that collide


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether the paths ``a`` and ``b`` name one file: :func:`os.path.samefile` where both exist (hard links,
    symbolic links, ``./x`` and ``x``), else their resolved absolute paths are equal."""
    try:
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
        return Path(a).resolve() == Path(b).resolve()
    except (OSError, RuntimeError):  # a symlink loop, a name too long: not the same as anything
        return False


def check_distinct_paths(
    inputs: Iterable[tuple[str, str | os.PathLike | None]], outputs: Iterable[tuple[str, str | os.PathLike | None]]
) -> None:
    """Refuse, before any work, an output that is one of the inputs (it would be overwritten) or two outputs that
    are one file (one would replace the other): a one-line :class:`ParameterError` naming both options.

    inputs, outputs : ``(option, path)`` pairs, e.g. ``("--box", "box.json")`` (the command's positional argument
    named as its metavar, e.g. ``"SCAN"``); a None path (option not given) is skipped."""
    ins = [(o, p) for o, p in inputs if p is not None]
    outs = [(o, p) for o, p in outputs if p is not None]
    for i, (option, path) in enumerate(outs):
        for in_option, in_path in ins:
            if same_file(path, in_path):
                raise ParameterError(
                    f"{option} {path} is the input {in_option} {in_path}: it would be overwritten; write elsewhere"
                )
        for other_option, other in outs[:i]:
            if same_file(path, other):
                raise ParameterError(
                    f"{other_option} {other} and {option} {path} are the same file: one would replace the other"
                )


def check_regular_file(path: str | os.PathLike, what: str = "file") -> Path:
    """``path`` as a :class:`Path` when it is a regular file (or a link to one), else a one-line
    :class:`InputFileError`: missing, a folder, or not a regular file (a FIFO, socket or device, which reading
    would block on or never end)."""
    p = Path(path)
    if not p.exists():
        raise InputFileError(p, "no such file")
    if p.is_dir():
        raise InputFileError(p, f"is a folder, expected a {what}")
    if not p.is_file():
        raise InputFileError(p, f"not a regular file (a FIFO, socket or device), expected a {what}")
    return p
