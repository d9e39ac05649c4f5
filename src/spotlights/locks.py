"""An exclusive, non-blocking lock on a file (``fcntl.flock``) for the body of a ``with``."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

from .errors import (
    SpotlightsError,
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
