"""Atomic writes, stale temporaries and process pools that fail instead of hanging (spotlights.outputs, spotlights.processes).

Truth: the file system itself (what exists after), exit codes and messages of real processes.
No test here depends on timing: a hang is a function that never returns, and the pool
timeout under test is the only clock.
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from spotlights.errors import OutputFileError, SpotlightsError
from spotlights.outputs import atomic_output, check_writable, output_folder, sweep_temporaries
from spotlights.processes import process_map, unguarded_main_call

from helpers import src_pythonpath


def _dead_pid() -> int:
    """A process id that no longer exists (a child that has exited and been reaped)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_atomic_output_writes_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "a" / "b" / "x.txt"
    with atomic_output(target) as tmp:
        assert tmp.parent == target.parent and tmp.name.startswith(f".x.txt.{os.getpid()}-") and tmp.suffix == ".txt"
        tmp.write_text("hello")
    assert target.read_text() == "hello"
    assert sorted(p.name for p in target.parent.iterdir()) == ["x.txt"]


def test_failed_write_leaves_nothing_not_even_its_folders(tmp_path):
    target = tmp_path / "new" / "deeper" / "x.txt"
    with pytest.raises(ValueError):
        with atomic_output(target) as tmp:
            tmp.write_text("half")
            raise ValueError("the writer failed")
    assert list(tmp_path.iterdir()) == []  # no file, no temporary, no empty folder


def test_os_errors_name_the_target(tmp_path, monkeypatch):
    target = tmp_path / "x.npz"
    with pytest.raises(OutputFileError, match=r"x\.npz: cannot write \(no space left on device\)"):
        with atomic_output(target) as tmp:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp))
    assert list(tmp_path.iterdir()) == []
    other = OSError(errno.ENOENT, "No such file or directory", str(tmp_path / "an-input.ply"))
    with pytest.raises(OSError) as info:  # an error about another file is the caller's, left as it is
        with atomic_output(target):
            raise other
    assert info.value is other
    with pytest.raises(OutputFileError, match="is a folder"):
        with atomic_output(tmp_path):
            pass


def test_stale_temporaries_of_the_same_target_are_swept(tmp_path):
    target = tmp_path / "cars.h5"
    dead = tmp_path / f".cars.h5.{_dead_pid()}-abc123.part.h5"  # a killed write (SIGKILL)
    legacy = tmp_path / ".cars.h5.k2j3h4.part.h5"  # the older name, without a process id
    alive = tmp_path / f".cars.h5.{os.getppid()}-zz9.part.h5"  # a write in progress in a live process
    other = tmp_path / f".other.h5.{_dead_pid()}-abc.part.h5"  # another target's
    for p in (dead, legacy, alive, other):
        p.write_bytes(b"half a file")
    with atomic_output(target) as tmp:
        tmp.write_bytes(b"done")
    assert target.read_bytes() == b"done"
    assert not dead.exists() and not legacy.exists()
    assert alive.exists() and other.exists()
    assert sweep_temporaries(tmp_path / "other.h5") == [other]


def test_check_writable_fails_before_the_work(tmp_path, monkeypatch):
    check_writable(tmp_path / "new" / "x.png", None)
    assert list(tmp_path.iterdir()) == []  # nothing created, not even the folder
    import tempfile

    def refuse(*a, **kw):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(tmp_path))

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(OutputFileError, match=r"x\.png: cannot write \(read-only file system\)"):
        check_writable(tmp_path / "x.png")
    monkeypatch.undo()
    with pytest.raises(OutputFileError, match="is a folder"):
        check_writable(tmp_path)


def test_output_folder_is_removed_when_the_work_fails_before_writing(tmp_path):
    with pytest.raises(RuntimeError):
        with output_folder(tmp_path / "a" / "run"):
            raise RuntimeError("failed")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError):
        with output_folder(tmp_path / "b") as out:
            (out / "log.csv").write_text("epoch\n")
            raise RuntimeError("failed later")
    assert (tmp_path / "b" / "log.csv").exists()  # what was written stays (a run resumes from it)
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputFileError, match="not a folder"):
        with output_folder(tmp_path / "file"):
            pass


# ---------------------------------------------------------------------------- process pools


def _square(x):
    return x * x


def _die(x):
    if x == 3:
        os._exit(7)  # a worker killed mid-unit (OOM killer, kill -9)
    return x


def _hang(x):
    if x == 1:
        threading.Event().wait()  # never returns
    return x


def _bad_input(x):
    raise SpotlightsError(f"unit {x}: bad mesh")


def test_process_map_ordered_and_same_whatever_the_workers():
    assert list(process_map(_square, range(7), 1)) == [x * x for x in range(7)]
    assert list(process_map(_square, range(7), 2)) == [x * x for x in range(7)]
    assert sorted(process_map(_square, range(7), 2, ordered=False)) == sorted(x * x for x in range(7))


def test_a_dead_worker_is_an_error_not_a_hang():
    from spotlights.errors import ProcessFailure

    with pytest.raises(ProcessFailure, match="worker process died") as caught:
        list(process_map(_die, range(6), 2))
    assert caught.value.exit_code == 1  # not the input's fault


@pytest.mark.slow
def test_a_stuck_pool_times_out():
    with pytest.raises(SpotlightsError, match="no work unit finished within 3 s"):
        list(process_map(_hang, [1, 1], 2, timeout=3))


def test_a_stopped_pool_leaves_no_thread_behind():
    """A pool stopped mid-work (Ctrl-C, an error) ends its manager thread before returning: left running, CPython's
    exit hook would write to the manager's wake-up pipe while the manager closes it (an ``OSError: Bad file
    descriptor`` traceback after the one-line interrupt message)."""
    from spotlights.processes import start_process_pool, stop_process_pool

    before = set(threading.enumerate())
    pool = start_process_pool(2)
    futures = [pool.submit(_hang, 1) for _ in range(4)]
    assert set(threading.enumerate()) - before  # the pool's own threads run
    stop_process_pool(pool)
    assert set(threading.enumerate()) <= before
    assert all(f.done() for f in futures)


def test_a_units_own_error_comes_back_as_it_is():
    with pytest.raises(SpotlightsError, match="unit 0: bad mesh|unit 1: bad mesh"):
        list(process_map(_bad_input, [0, 1], 2))


SCRIPT_UNGUARDED = """
from spotlights.processes import process_map
print(list(process_map(abs, [-1, -2, 3], 2)))
"""
SCRIPT_GUARDED = """
from spotlights.processes import process_map

def main():
    print(list(process_map(abs, [-1, -2, 3], 2)))

if __name__ == "__main__":
    main()
"""
SCRIPT_ENCODE_FILES = """
import trimesh
from spotlights.geometry import encode_mesh_files, make_rig
trimesh.creation.box().export("box.ply")
d = encode_mesh_files(["box.ply", "box.ply"], make_rig(4, 8, 60), workers=2)
print(d["cap-4x8-60"].shape)
"""


def _run_script(tmp_path: Path, text: str) -> subprocess.CompletedProcess:
    script = tmp_path / "user_script.py"
    script.write_text(text)
    env = {**os.environ, "PYTHONPATH": src_pythonpath()}
    return subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300
    )


def test_a_script_without_the_main_guard_fails_with_one_clear_line(tmp_path):
    """Workers re-import the main script: without the guard a pool would respawn them without end."""
    proc = _run_script(tmp_path, SCRIPT_UNGUARDED)
    assert proc.returncode == 1
    last = proc.stderr.strip().splitlines()[-1]
    assert "user_script.py:3" in last and 'if __name__ == "__main__":' in last, proc.stderr
    assert "Traceback" in proc.stderr  # a library error: the script's own traceback ends with the one line
    assert "An attempt has been made to start a new process" not in proc.stderr  # no worker ever started


def test_guarded_scripts_and_thread_pools_need_nothing(tmp_path):
    proc = _run_script(tmp_path, SCRIPT_GUARDED)
    assert proc.returncode == 0 and proc.stdout.strip() == "[1, 2, 3]", proc.stderr
    proc = _run_script(tmp_path, SCRIPT_ENCODE_FILES)  # threads over meshes: no guard needed
    assert proc.returncode == 0 and proc.stdout.strip() == "(2, 32)", proc.stderr


def test_unguarded_main_call_is_none_here():
    assert unguarded_main_call() is None  # pytest's __main__ is a package entry point
