"""Ctrl-C at any moment, on an idle or a busy machine, and a Ray build that gives up.

A Ctrl-C sent while the command's own imports run (the package, numpy, ``spotlights.entry``) or while a build loads
its meshes (trimesh caught the interrupt in its optional imports: lost, or a TypeError traceback later) ends the
command with one line and exit 130; never lost, never hung. The delays are counted from the moment the child holds
Ctrl-C (its package import began: read from /proc), so they test our code, not Python's own start-up; assertions
are on outcomes only (exit code, lines), never on how fast anything ran.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers import src_pythonpath

LINUX = sys.platform.startswith("linux")
BUILD = ["dataset", "build", "--procedural", "2", "--classes", "car,bus", "--views", "2000", "--gt-points", "64"]
BUILD += ["--gt-dense", "256", "--workers", "2", "-q"]


def _sigint_blocked(pid: int) -> bool:
    """Whether the main thread of ``pid`` blocks SIGINT (its package import began; /proc/PID/status SigBlk)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith("SigBlk:"):
                    return bool(int(line.split()[1], 16) & (1 << (signal.SIGINT - 1)))
    except OSError:
        pass
    return False


def _interrupt(args, delay: float, cwd: Path, group: bool = True) -> subprocess.CompletedProcess:
    """Run ``python -m spotlights ARGS`` and send SIGINT (to its process group, as a terminal's Ctrl-C does) ``delay``
    seconds after its package import began."""
    env = dict(os.environ, PYTHONPATH=src_pythonpath(), OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    p = subprocess.Popen(
        [sys.executable, "-m", "spotlights", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=cwd,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 120  # generous: a loaded machine starts Python slowly
        while not _sigint_blocked(p.pid) and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.0005)
        time.sleep(delay)
        if p.poll() is None:
            if group:
                os.killpg(p.pid, signal.SIGINT)
            else:
                p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=300)  # a hang is a failure, not a wait without end
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.communicate()
    return subprocess.CompletedProcess(p.args, p.returncode, out, err)


def _one_line_130(proc: subprocess.CompletedProcess, delay: float) -> None:
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    assert proc.returncode == 130, (delay, proc.returncode, proc.stderr[-3000:])
    assert lines == ["spotlights: interrupted"], (delay, proc.stderr[-3000:])


@pytest.fixture
def cpu_hog():
    """Busy loops on every core for the test's length (a loaded CI machine)."""
    hogs = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)
        for _ in range(max(1, os.cpu_count() or 1))
    ]
    yield
    for h in hogs:
        h.kill()
        h.wait()


DELAYS = [0.0, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.8, 1.2, 1.6, 2.0]


@pytest.mark.skipif(not LINUX, reason="reads /proc to know when the child's import began")
@pytest.mark.timeout(1200)
@pytest.mark.parametrize("delay", DELAYS)
def test_ctrl_c_during_the_commands_imports_and_the_build_is_130_and_one_line(tmp_path, delay):
    proc = _interrupt([*BUILD, "--out", tmp_path / "x.h5"], delay, tmp_path)
    _one_line_130(proc, delay)
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.skipif(not LINUX, reason="reads /proc to know when the child's import began")
@pytest.mark.timeout(1800)
def test_ctrl_c_at_many_moments_under_a_cpu_hog(tmp_path, cpu_hog):
    for k, delay in enumerate([0.0, 0.01, 0.05, 0.2, 0.5, 1.0, 2.0]):
        work = tmp_path / str(k)
        work.mkdir()
        proc = _interrupt([*BUILD, "--out", work / "x.h5"], delay, work, group=k % 2 == 0)
        _one_line_130(proc, delay)


#: A child that runs ``python -m spotlights ARGV`` (``sys.orig_argv`` as that command line has it) and sends itself
#: SIGINT, a real signal, the moment the first import of the module named in SPOTLIGHTS_TEST_SIGINT_AT begins.
SIGINT_AT_IMPORT = """
import os, signal, sys, runpy
target = os.environ["SPOTLIGHTS_TEST_SIGINT_AT"]
class Fire:
    fired = False
    def find_spec(self, name, path=None, target_=None):
        if name == target and not Fire.fired:
            Fire.fired = True
            os.kill(os.getpid(), signal.SIGINT)
        return None
    def __getattr__(self, name):
        raise AttributeError(name)
sys.meta_path.insert(0, Fire())
sys.orig_argv = [sys.executable, "-m", "spotlights", *sys.argv[1:]]
sys.argv = ["spotlights", *sys.argv[1:]]
runpy.run_module("spotlights", run_name="__main__", alter_sys=True)
"""


def _interrupt_at_import(module: str, args, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=src_pythonpath(), MPLBACKEND="Agg", SPOTLIGHTS_TEST_SIGINT_AT=module)
    return subprocess.run(
        [sys.executable, "-c", SIGINT_AT_IMPORT, *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=300,
    )


@pytest.mark.parametrize(
    "module", ["logging", "importlib", "spotlights.entry", "spotlights.cli", "numpy", "spotlights.processes"]
)
def test_ctrl_c_while_the_command_itself_is_imported_is_130_and_one_line(tmp_path, module):
    """A Ctrl-C 0.15 s in, while ``spotlights.entry`` was imported, gave a traceback and exit -2."""
    if module == "importlib":
        module = "importlib.abc"  # the first import the package makes after its hold that Python has not made yet
    proc = _interrupt_at_import(module, ["dataset", "build", "--procedural", "1", "--out", tmp_path / "x.h5"], tmp_path)
    _one_line_130(proc, module)
    assert not (tmp_path / "x.h5").exists()


def test_ctrl_c_inside_trimeshs_import_is_not_lost(tmp_path):
    """trimesh imports its optional parts inside ``except BaseException``: a Ctrl-C there was kept as a placeholder
    module (the command then ran to its end, exit 0, or failed later with a TypeError traceback)."""
    import trimesh

    trimesh.creation.box(extents=(4.0, 1.8, 1.5)).export(tmp_path / "box.ply")
    for module in ("trimesh.path", "trimesh.exchange.load"):
        proc = _interrupt_at_import(module, ["show", tmp_path / "box.ply", "--out", tmp_path / "box.png"], tmp_path)
        _one_line_130(proc, module)
        assert not (tmp_path / "box.png").exists()


def test_the_package_holds_ctrl_c_only_for_the_command():
    """Imported as a library the package leaves the signal mask alone."""
    code = "import signal, spotlights; print(signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, set()))"
    env = dict(os.environ, PYTHONPATH=src_pythonpath())
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.stdout.strip() == "False", proc.stderr


def test_trimesh_is_among_the_guarded_imports():
    from spotlights.entry import DEFERRED_IMPORTS

    assert {"trimesh", "scipy", "torch"} <= DEFERRED_IMPORTS


class _FakeRay:
    """Enough of the ``ray`` module for :meth:`RayBuild.stream`: task 0 fails with an input error at once, the others
    are still running; records the calls in order."""

    class exceptions:  # noqa: N801 - as ray names it
        RayError = RuntimeError

    def __init__(self):
        self.calls: list = []

    def wait(self, refs, num_returns=1, timeout=None):
        self.calls.append(("wait", sorted(refs), num_returns, timeout))
        if num_returns == 1:
            return [min(refs)], [r for r in refs if r != min(refs)]
        return list(refs), []

    def get(self, ref):
        from spotlights.errors import InputFileError

        self.calls.append(("get", ref))
        return ("error", InputFileError("tiny.ply", "no pose gives 50 returns"))

    def cancel(self, ref, force=False):
        self.calls.append(("cancel", ref, force))


def test_a_ray_build_that_gives_up_waits_for_its_cancelled_tasks():
    from spotlights.data.synthetic.ray_backend import CANCEL_WAIT_S, RayBuild
    from spotlights.errors import InputFileError

    ray = _FakeRay()
    build = object.__new__(RayBuild)
    build.ray, build.retries, build.in_flight = ray, 0, 4
    with pytest.raises(InputFileError, match="tiny.ply"):
        build.stream(lambda i: i, range(10), str, lambda i, res: None)
    cancels = [c for c in ray.calls if c[0] == "cancel"]
    assert sorted(c[1] for c in cancels) == [1, 2, 3] and all(c[2] for c in cancels)
    # after the cancels, one wait for all three to end, before the error leaves (and the build removes their parts)
    assert ray.calls[-1] == ("wait", [1, 2, 3], 3, CANCEL_WAIT_S)
    assert ray.calls.index(cancels[-1]) < len(ray.calls) - 1


def test_an_interrupted_command_whose_exit_hangs_still_ends_with_130(tmp_path):
    """The interpreter's exit waiting for ever on what a stopped pool left (concurrent.futures joins its manager
    threads at exit): the command's exit code 130 comes anyway, within its stated grace."""
    code = (
        "import sys, threading, time\n"
        "import spotlights.cli, spotlights.entry as entry\n"
        "spotlights.cli.main = lambda: 130\n"  # a command that was interrupted and cleaned up
        "entry.EXIT_GRACE_S = 0.5\n"
        "threading._register_atexit(lambda: time.sleep(3600))\n"  # an exit-time join that never returns
        "sys.exit(entry.main())\n"
    )
    env = dict(os.environ, PYTHONPATH=src_pythonpath())
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 130, proc.stderr


def test_a_normal_exit_is_not_cut_short():
    code = (
        "import sys, threading, time\n"
        "import spotlights.cli, spotlights.entry as entry\n"
        "spotlights.cli.main = lambda: 0\n"
        "entry.EXIT_GRACE_S = 0.01\n"
        "threading._register_atexit(lambda: (time.sleep(0.3), print('joined', flush=True)))\n"
        "sys.exit(entry.main())\n"
    )
    env = dict(os.environ, PYTHONPATH=src_pythonpath())
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert (proc.returncode, proc.stdout.strip()) == (0, "joined"), proc.stderr


def test_ctrl_c_while_the_arguments_are_parsed_is_130_and_one_line(monkeypatch, capsys):
    """Between the commands' imports and the command itself the arguments are parsed: a Ctrl-C there (argparse is
    plain Python, so the interrupt is raised inside it) ends the command with its one line and 130, not a traceback
    and an end by SIGINT itself (seen once in a fused `real complete` interrupted 0.15 s in on a busy machine)."""
    import argparse

    from spotlights.cli import main

    def interrupted(self, *args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", interrupted)
    try:
        code = main(["real", "complete", "--help"])
    except KeyboardInterrupt:  # escaped: the traceback a user would see (caught here so the suite goes on)
        pytest.fail("the Ctrl-C while the arguments were parsed escaped the command")
    assert code == 130
    assert capsys.readouterr().err.strip().splitlines() == ["spotlights: interrupted"]
