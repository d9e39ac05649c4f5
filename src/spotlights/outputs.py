"""Files written whole or not at all: atomic outputs (a hidden temporary renamed into place), their
sweeping after a crash, HDF5 outputs, checks of destinations before any work, and one-line OS error reasons."""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from .errors import (
    InputFileError,
    OutputFileError,
    ParameterError,
    parameter_names,
    shown,
)

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


def os_error_line(exc: OSError) -> str:
    """``"FILE: reason"`` of an OS error (the reason alone when it names no file): the command line's one line."""
    name = exc.filename if exc.filename is not None else None
    reason = os_error_reason(exc)
    return f"{name}: {reason}" if name is not None else reason


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
