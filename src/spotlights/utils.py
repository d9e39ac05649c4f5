"""Small utilities shared by every layer (atomic writes, an exclusive lock, process pools)."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    Nothing half-written is ever left under ``path``: if the body raises, the
    temporary file is removed and ``path`` is untouched. The temporary name keeps
    the target's suffix (or ``suffix``) so that writers choosing a format from the
    extension (trimesh, matplotlib) still work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sfx = suffix if suffix is not None else "".join(path.suffixes[-1:])
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".part{sfx}", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    # mkstemp creates the file 0600; give it the permissions a plain open() would (0666 & ~umask)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp_path, 0o666 & ~umask)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


@contextlib.contextmanager
def exclusive_lock(lock_file: str | os.PathLike, busy: str) -> Iterator[None]:
    """Hold an exclusive, non-blocking lock on ``lock_file`` (created if missing) for the body.

    The one file lock of the project: two processes that must not write the same output
    (two dataset builds into one parts folder, two ``add-rig`` runs on one file, two
    reproductions in one folder) take the same lock file; the second fails at once with
    :class:`~spotlights.errors.SpotlightsError` ``busy`` (a one-line message naming the path)
    instead of waiting. The lock is released when the body ends or the process dies (``flock``);
    the small lock file stays. Not POSIX (no ``fcntl``): no lock.
    """
    from .errors import SpotlightsError

    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: no lock
        yield
        return
    with open(lock_file, "w") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise SpotlightsError(busy) from None
        yield


def process_pool_context():
    """The multiprocessing context for pools of workers that build Embree scenes.

    ``forkserver`` where available (Linux), else ``spawn``; never a plain ``fork`` of the
    caller. Embree builds its BVHs on TBB worker threads, and TBB is not fork-safe: a
    process forked while the parent's TBB threads are active inherits a thread pool that
    does not exist, and its first BVH build can wait forever. The fork server is a fresh
    interpreter that has never run Embree (or torch), so its children start clean. Results
    do not depend on the start method. As with ``spawn`` (and Python 3.14's default), a
    script that asks for ``workers > 1`` needs the usual ``if __name__ == "__main__":`` guard.
    """
    import multiprocessing as mp

    methods = mp.get_all_start_methods()
    return mp.get_context("forkserver" if "forkserver" in methods else "spawn")
