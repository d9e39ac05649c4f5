import multiprocessing.util
import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
sys.path.insert(0, str(Path(__file__).resolve().parent))


def pytest_configure(config):
    """Ctrl-C reaches the suite's child processes as it reaches a command typed in a terminal. A run started in the
    background by a non-interactive shell (``make test &`` in a script, ``(make test &)``) inherits SIGINT ignored,
    and every process it starts would ignore it too: the tests that send a Ctrl-C to a command would then see it
    run to its end. Here SIGINT gets Python's own handler back (before pytest-xdist starts its workers), so children
    start with it at its default."""
    import signal

    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session", autouse=True)
def _private_tmpdir(tmp_path_factory):
    """Every temporary folder that the suite's own processes make outside pytest's ``tmp_path``
    (multiprocessing's ``pymp-*``, torchrun's ``torchelastic_*``, Ray's session folders, ...) goes
    into one private folder (``TMPDIR`` for child processes, ``tempfile.tempdir`` here), removed
    when this process exits: nothing is left in /tmp, and no other program's folders are touched.
    pytest's own ``tmp_path`` folders stay under its base folder (kept only for failed tests:
    ``tmp_path_retention_policy`` in pyproject.toml)."""
    _BASETEMP.append(tmp_path_factory.getbasetemp())  # fixed before TMPDIR changes; trimmed at the end
    root = tempfile.mkdtemp(prefix="sl-suite-")  # short: Ray's socket paths must stay under 107 bytes
    # Removed at exit after multiprocessing's own clean-up (its temp folder, priority -100, lies in
    # root: removing root at the end of the session would make that clean-up fail with a traceback).
    multiprocessing.util.Finalize(None, shutil.rmtree, args=(root,), kwargs={"ignore_errors": True}, exitpriority=-200)
    old_env, old_tempdir = os.environ.get("TMPDIR"), tempfile.tempdir
    os.environ["TMPDIR"], tempfile.tempdir = root, root
    try:
        yield Path(root)
    finally:
        tempfile.tempdir = old_tempdir
        if old_env is None:
            os.environ.pop("TMPDIR", None)
        else:
            os.environ["TMPDIR"] = old_env


@pytest.fixture(scope="session", autouse=True)
def _one_torch_thread_per_worker():
    """Under pytest-xdist (``-n N``: one process per CPU), each worker computes with one torch thread,
    so that N workers keep N CPUs busy instead of N x CPUs threads fighting over them (the suite's
    models are tiny: one thread is also the fastest for them). A single-process run is left as it is."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        yield
        return
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


#: pytest's base temporary folder of this run (set by _private_tmpdir)
_BASETEMP: list = []


@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session, exitstatus):
    """A run with failures keeps its temporary folders (pytest's ``tmp_path_retention_policy = "failed"``): trimmed
    here to what a failing test is read by (:func:`helpers.trim_kept_files`: no file above 8 MiB, 64 MiB in all), so
    that a failed run no longer leaves hundreds of MB under the system's temporary folder."""
    from helpers import trim_kept_files

    for base in _BASETEMP:
        if Path(base).is_dir():  # pytest removed it already when every test passed
            trim_kept_files(Path(base))
