"""Track completion that fails well: a live but hung track worker ends the run with one line after STALL_S (a slow
one that shows signs of life does not), and Ctrl-C gives exit code 130 and one line whenever it comes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from spotlights.completion import track_windows, track_worker
from spotlights.completion.fusion import TrackWorkerStalled, usable_cpus

from builders import track_inputs as _inputs
from builders import track_plan as _plan
from builders import write_drive
from helpers import REPO, wait_until_command_started

needs_two_cpus = pytest.mark.skipif(usable_cpus() < 2, reason="a worker process is started with 2+ usable CPUs only")

#: the worker process's real entry (the tests below run it under a wrapper in the worker process; the worker is
#: started by a fork server, a fresh interpreter: a monkeypatch of this process reaches it only through the target
#: it is given, which it imports from this module by name)
WORKER_MAIN = track_worker.worker_main


class _StuckAfterOneFrame:
    """The worker's result queue, but the worker hangs (sleeps, alive, silent) when it has a second frame to send."""

    def __init__(self, queue):
        self.queue, self.frames = queue, 0

    def put(self, msg) -> None:
        self.frames += msg[0] == "frame"
        if self.frames > 1:
            time.sleep(3600)
        self.queue.put(msg)


def hanging_worker(jobs, results) -> None:
    """The track worker, hanging after its first frame (in the worker process)."""
    WORKER_MAIN(jobs, _StuckAfterOneFrame(results))


class _DiesAfterOneFrame(_StuckAfterOneFrame):
    """The worker's result queue, but the worker process ends at once (as if killed) when it has a second frame."""

    def put(self, msg) -> None:
        self.frames += msg[0] == "frame"
        if self.frames > 1:
            time.sleep(0.2)  # the first frame's message leaves the queue's feeder thread
            os._exit(9)
        self.queue.put(msg)


def dying_worker(jobs, results) -> None:
    """The track worker, its process ending without a word after its first frame (in the worker process)."""
    WORKER_MAIN(jobs, _DiesAfterOneFrame(results))


#: seconds a fused window takes in :func:`slow_worker`, and the stall limit of the test that runs it: a frame of two
#: cars (~4 windows) lasts longer than the limit, while the worker's silence between signs of life (a window) stays
#: far below it even on a loaded machine (load 30 on 2 cores delays a sleeping process by well under a second)
SLOW_WINDOW_S, SLOW_STALL_S = 1.5, 6.0


def slow_worker(jobs, results) -> None:
    """The track worker, fusing slowly (:data:`SLOW_WINDOW_S` a fused window: ~4 times that a frame of two cars) with
    a sign of life every 0.1 s at most between windows (in the worker process)."""
    real = track_windows.fuse_track

    def slow(*args, **kwargs):
        time.sleep(SLOW_WINDOW_S)
        return real(*args, **kwargs)

    track_windows.fuse_track = slow
    track_worker.BEAT_S = 0.1
    WORKER_MAIN(jobs, results)


def _stale(folder) -> list:
    return [p for p in folder.rglob("*") if ".part" in p.name] if folder.exists() else []


@needs_two_cpus
@pytest.mark.timeout(120)
def test_a_hung_worker_ends_the_run_with_one_line_after_the_stall_limit(tmp_path, monkeypatch):
    """``real complete --fuse past:2``, the worker hanging after its first frame (STALL_S 2 s here, 120 s by default):
    exit code 1 (not the input's fault: a ProcessFailure) within seconds, one line naming the stall and
    --no-track-worker, no traceback, no temporaries, no summary or tracks files, the worker process ended. Before,
    the run waited forever."""
    import multiprocessing

    pytest.importorskip("torch")
    from helpers import run_cli
    from learning_fixtures import make_checkpoint

    monkeypatch.setattr(track_worker, "worker_main", hanging_worker)
    monkeypatch.setattr(track_worker, "STALL_S", 2.0)
    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0, 1.5])
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    out = tmp_path / "out"
    t0 = time.monotonic()
    proc = run_cli(
        "real", "complete", src, "--format", "generic", "-c", ck, "--out", out, "--fuse", "past:2", "-q",
        "--no-pictures",
    )  # fmt: skip
    took = time.monotonic() - t0
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 1, proc.stderr
    assert len(err) == 1 and "Traceback" not in proc.stderr, err
    assert "track worker process made no progress for 2 s" in err[0] and "--no-track-worker" in err[0], err
    assert 2.0 <= took < 60.0
    assert not _stale(out)
    assert not (out / "summary.json").exists() and not (out / "tracks.json").exists()
    assert not [p for p in multiprocessing.active_children() if p.name == "spotlights-tracks"]


@needs_two_cpus
@pytest.mark.timeout(120)
def test_a_worker_that_dies_ends_the_run_with_one_line_and_exit_code_1(tmp_path, monkeypatch):
    """``real complete --fuse past:2``, the worker process ending without a word after its first frame (killed, say
    for memory): exit code 1 at once (before: a RuntimeError's traceback), one line with the worker's exit code and
    --no-track-worker, no temporaries, no summary or tracks files."""
    pytest.importorskip("torch")
    from helpers import run_cli
    from learning_fixtures import make_checkpoint

    monkeypatch.setattr(track_worker, "worker_main", dying_worker)
    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0, 1.5])
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    out = tmp_path / "out"
    proc = run_cli(
        "real", "complete", src, "--format", "generic", "-c", ck, "--out", out, "--fuse", "past:2", "-q",
        "--no-pictures",
    )  # fmt: skip
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 1, proc.stderr
    assert len(err) == 1 and "Traceback" not in proc.stderr, err
    assert "track worker process ended (exit code 9) before its results" in err[0], err
    assert "--no-track-worker" in err[0], err
    assert not _stale(out)
    assert not (out / "summary.json").exists() and not (out / "tracks.json").exists()


@needs_two_cpus
@pytest.mark.timeout(600)
def test_a_slow_worker_that_shows_signs_of_life_is_not_taken_for_hung(tmp_path, monkeypatch):
    """A worker taking ~4 x SLOW_WINDOW_S a frame under a stall limit of SLOW_STALL_S: its signs of life (between
    fused windows) keep the run going, and the frames get the inputs of the plan working alone. The limit is lowered
    only once the first frame came: the worker's start (an interpreter, seconds on a loaded machine) is under the
    default limit (120 s). No bound on speed: the sleeps make the frames at least that long."""
    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0])
    alone, keys = _plan(src, "past:2", worker=False)
    want = _inputs(alone, keys)
    monkeypatch.setattr(track_worker, "worker_main", slow_worker)
    plan, _ = _plan(src, "past:2", worker=False)
    assert plan.start_worker(keys)
    got = _inputs(plan, keys[:1])
    monkeypatch.setattr(track_worker, "STALL_S", SLOW_STALL_S)
    t0 = time.monotonic()
    got += _inputs(plan, keys[1:])
    plan.finish()
    assert got == want
    # the worker was slow: the frames after the first outlast the stall limit (each fused window sleeps)
    assert time.monotonic() - t0 > SLOW_STALL_S


@needs_two_cpus
@pytest.mark.timeout(60)
def test_a_stalled_plan_raises_and_ends_its_worker(tmp_path, monkeypatch):
    """Library use: the plan's frame_inputs raises TrackWorkerStalled (a SpotlightsError: one line) once the worker
    was silent for STALL_S, and the worker process has ended."""
    from spotlights.errors import SpotlightsError

    monkeypatch.setattr(track_worker, "worker_main", hanging_worker)
    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0])
    plan, keys = _plan(src, "past:2", worker=False)
    assert plan.start_worker(keys)
    proc = plan.worker_process
    plan.frame_inputs(keys[0], plan.take(keys[0]).boxes)  # the first frame comes (the worker started)
    monkeypatch.setattr(track_worker, "STALL_S", 1.0)
    with pytest.raises(TrackWorkerStalled, match="made no progress for 1 s") as caught:
        plan.frame_inputs(keys[1], plan.take(keys[1]).boxes)
    assert isinstance(caught.value, SpotlightsError)
    proc.join(10)
    assert not proc.is_alive()
    plan.close()


SUSPENDED = """
import pathlib
import sys

from spotlights.completion import track_worker
from test_track_reliability import SLOW_STALL_S, slow_worker
from builders import track_plan as _plan
from builders import write_drive

if __name__ == "__main__":
    track_worker.worker_main = slow_worker
    src = write_drive(pathlib.Path(sys.argv[1]), [0.0, 0.5, 1.0])
    plan, keys = _plan(src, "past:2", worker=False)
    assert plan.start_worker(keys)
    plan.frame_inputs(keys[0], plan.take(keys[0]).boxes)  # the worker started (its start is not timed here)
    track_worker.STALL_S = SLOW_STALL_S
    print("ready", flush=True)
    for key in keys[1:]:
        plan.frame_inputs(key, plan.take(key).boxes)
    plan.finish()
    print("done", flush=True)
"""


@needs_two_cpus
@pytest.mark.timeout(600)
def test_a_suspended_run_is_not_taken_for_a_hung_worker(tmp_path):
    """Ctrl-Z (SIGSTOP to the run's process group: it and its worker) for longer than the stall limit, then ``fg``
    (SIGCONT), while the run waits for a slow worker that shows signs of life (stall limit SLOW_STALL_S here): the run
    goes on and finishes. Before, the pause counted as silence: the first poll after SIGCONT found the limit passed
    and stopped the worker."""
    (tmp_path / "suspended_probe.py").write_text(SUSPENDED)
    env = _env()
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), str(REPO / "tests"), env["PYTHONPATH"]])
    proc = subprocess.Popen(
        [sys.executable, str(tmp_path / "suspended_probe.py"), str(tmp_path / "drive")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,
    )
    try:
        assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
        time.sleep(0.3)  # the run waits for frame 1 (the slow worker fuses it for several seconds)
        os.killpg(proc.pid, signal.SIGSTOP)
        time.sleep(SLOW_STALL_S + 2.0)
        os.killpg(proc.pid, signal.SIGCONT)
        out, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0 and out.strip() == "done", err


def test_the_stall_limit_is_generous():
    """The default stall limit leaves a slow machine 100 times the measured slowest step of the worker (0.6 s: the
    longest track's whole refinement of scene-0523 with ``all``), and signs of life come far more often than it."""
    assert track_worker.STALL_S >= 100 * 0.6
    assert track_worker.BEAT_S * 10 <= track_worker.STALL_S


# --- Ctrl-C --------------------------------------------------------------------------------------------------------

PROBE = """
import argparse
import sys

from spotlights.cli import main

real_parse = argparse.ArgumentParser.parse_args


def parse_args(self, *args, **kwargs):
    ns = real_parse(self, *args, **kwargs)
    if getattr(ns, "func", None) is not None:
        # Ctrl-C arriving in code run by exec of a string (as dataclasses build their methods while modules import)
        ns.func = lambda _: exec("raise KeyboardInterrupt")
    return ns


argparse.ArgumentParser.parse_args = parse_args
raise SystemExit(main(["encode", "in.ply", "--out", "out.npz"]))
"""


def _env() -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    env["PYTHONPATH"] = str(REPO / "src") + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.mark.timeout(60)
def test_ctrl_c_inside_exec_run_code_still_exits_130(tmp_path):
    """``python -m``: a KeyboardInterrupt that left code run by ``exec`` of a string, then handled by the CLI, ends the
    process with exit code 130 and one line; before, CPython's note of an unhandled Ctrl-C made it end by SIGINT
    itself (return code -2) after printing the line."""
    (tmp_path / "ki_probe.py").write_text(PROBE)
    proc = subprocess.run(
        [sys.executable, "-m", "ki_probe"], cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=50
    )
    assert proc.returncode == 130, (proc.returncode, proc.stderr)
    assert proc.stderr.strip().splitlines() == ["spotlights: interrupted"]


@needs_two_cpus
@pytest.mark.timeout(900)
def test_ctrl_c_at_any_moment_of_a_fused_run_is_130_and_one_line(tmp_path):
    """``python -m spotlights real complete --fuse past:2`` (worker on, and off), SIGINT to the process group (as a
    terminal's Ctrl-C: the worker, the fork server and the resource tracker get it too), counted from the package's
    first line (:func:`helpers.wait_until_command_started`), while the modules import,
    while the worker and its fork server start, while torch imports and during the frames: every time exit code 130,
    the one line "spotlights: interrupted", no traceback (of the run or of a child), no temporaries left. Before:
    now and then a traceback of the fork server or of the worker starting, or an end by SIGINT itself (-2)."""
    pytest.importorskip("torch")
    from learning_fixtures import make_checkpoint

    src = write_drive(tmp_path / "drive", [0.5 * k for k in range(16)])
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    outcomes = []
    for k, delay in enumerate((0.0, 0.05, 0.15, 0.45, 0.6, 0.9, 1.3, 1.8)):
        out = tmp_path / f"out{k}"
        argv = ["real", "complete", str(src), "--format", "generic", "-c", str(ck), "--out", str(out)]
        argv += ["--fuse", "past:2", "--refine-boxes", "-q"] + (["--no-track-worker"] if k % 2 else [])
        proc = subprocess.Popen(
            [sys.executable, "-m", "spotlights", *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=_env(),
            start_new_session=True,
        )
        wait_until_command_started(proc.pid)  # delays count from the package's first line, not Python's start-up
        time.sleep(delay)
        try:
            os.killpg(proc.pid, signal.SIGINT)
        except ProcessLookupError:  # already done (a fast machine): nothing to check at this delay
            pass
        try:
            _, err = proc.communicate(timeout=300)  # generous: a hang is a failure, a loaded machine is not
        finally:  # a run that hangs is not left behind (nor its worker, fork server and resource tracker)
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        if (out / "summary.json").exists() and not err:  # done before the Ctrl-C (0), or in the interpreter's exit
            continue  # (handlers back to the default: ended by the signal): nothing to check at this delay
        outcomes.append((delay, proc.returncode, err.strip().splitlines(), _stale(out)))
    assert outcomes, "every run finished before its Ctrl-C"
    for delay, code, err, stale in outcomes:
        assert (code, err, stale) == (130, ["spotlights: interrupted"], []), (
            f"Ctrl-C {delay} s in: exit {code}, left behind {stale}, stderr:\n" + "\n".join(err)
        )


# --- --threads -----------------------------------------------------------------------------------------------------


@needs_two_cpus
@pytest.mark.timeout(120)
def test_threads_option_wins_over_the_core_left_to_the_worker(tmp_path, monkeypatch):
    """``real complete --fuse past:2``: torch completes on the usable CPUs less one beside the worker, on N with
    ``--threads N`` (N = the usable CPUs here: more than the default), and on N without the worker too; the
    caller's count is restored after; ``--threads 0`` is a usage error."""
    torch = pytest.importorskip("torch")
    from spotlights.completion import frames as frame_completion

    from helpers import run_cli
    from learning_fixtures import make_checkpoint

    seen: list[int] = []
    real = frame_completion.complete_scene

    def counting(*args, **kwargs):
        seen.append(torch.get_num_threads())
        return real(*args, **kwargs)

    monkeypatch.setattr(frame_completion, "complete_scene", counting)
    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0])
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    n = usable_cpus()
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(n)
        got = {}
        for name, extra in (("default", []), ("given", ["--threads", str(n)]), ("alone", ["--threads", "1"])):
            seen.clear()
            argv = ["real", "complete", src, "--format", "generic", "-c", ck, "--out", tmp_path / name, "-q"]
            proc = run_cli(*argv, "--fuse", "past:2", "--no-pictures", *extra)
            assert proc.returncode == 0, proc.stderr
            got[name] = sorted(set(seen))
            assert torch.get_num_threads() == n  # restored
        assert got == {"default": [n - 1], "given": [n], "alone": [1]}
        seen.clear()
        argv = ["real", "complete", src, "--format", "generic", "-c", ck, "--out", tmp_path / "one", "-q"]
        assert run_cli(*argv, "--fuse", "past:2", "--no-track-worker", "--threads", str(n)).returncode == 0
        assert sorted(set(seen)) == [n]
    finally:
        torch.set_num_threads(before)
    proc = run_cli("real", "complete", src, "--format", "generic", "--out", tmp_path / "bad", "--threads", "0")
    assert proc.returncode == 2 and "--threads" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "bad").exists()


# --- --resume with --fuse ------------------------------------------------------------------------------------------

CLOCKS = ("timings", "wall_seconds", "completion_seconds")


def _same(a, b, root_a: str, root_b: str) -> None:
    """JSON ``a`` equals ``b`` but for clock readings, the output folder in paths and the count of resumed frames."""

    def strip(x, root):
        if isinstance(x, dict):
            return {k: strip(v, root) for k, v in x.items() if k not in CLOCKS and k != "resumed"}
        if isinstance(x, list):
            return [strip(v, root) for v in x]
        return x.replace(root, "OUT") if isinstance(x, str) else x

    assert strip(a, root_a) == strip(b, root_b)


@pytest.mark.timeout(180)
@pytest.mark.parametrize("gone,worker", [((1, 2), True), ((3, 4), False)])
def test_a_resumed_fused_run_writes_what_one_run_writes(tmp_path, gone, worker):
    """``real complete --fuse past:2 --refine-boxes``, run once; run again into a second folder, frames ``gone``
    removed (as a run stopped before them; (1, 2): the last frames, which hold the tracks' latest completions, are
    the resumed ones), then ``--resume``: every PLY the same bytes as the one run (scenes, tracks/<track>.ply: the
    latest completion, completed again in memory), every JSON the same but clocks (tracks.json: every frame's points
    counted, resumed or not), the resumed frames counted; a folder done without --fuse is not reused by a fused run."""
    import json

    pytest.importorskip("torch")
    from helpers import run_cli
    from learning_fixtures import make_checkpoint

    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0, 1.5, 2.0])
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    common = ["--format", "generic", "-c", ck, "--no-clip", "-q", "--no-pictures", "--fuse", "past:2", "--refine-boxes"]
    common += [] if worker else ["--no-track-worker"]
    one, two = tmp_path / "one", tmp_path / "two"
    for out in (one, two):
        assert run_cli("real", "complete", src, "--out", out, *common).returncode == 0
    files = sorted(p.relative_to(one) for p in one.rglob("*") if p.is_file())
    for k in gone:
        for suffix in (".json", ".ply"):
            (two / "drive" / f"f{k}{suffix}").unlink()
    (two / "summary.json").unlink()
    (two / "tracks.json").unlink()
    for p in (two / "drive" / "tracks").iterdir():
        p.unlink()
    proc = run_cli("real", "complete", src, "--out", two, *common, "--resume")
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.relative_to(two) for p in two.rglob("*") if p.is_file()) == files
    assert sum(f.suffix == ".ply" for f in files) == 7  # five frames and two tracks
    for f in files:
        a, b = (one / f).read_bytes(), (two / f).read_bytes()
        if f.suffix == ".json":
            _same(json.loads(a), json.loads(b), str(one), str(two))
        else:
            assert a == b, f
    summary = json.loads((two / "summary.json").read_text())
    assert summary["totals"]["resumed"] == 5 - len(gone)
    counted = [f["n_points"] for t in json.loads((two / "tracks.json").read_text())["tracks"] for f in t["frames"]]
    assert counted == [300] * 10  # every frame of both cars counted (300 points each), resumed or not
    # frames completed without fusion are not reused by a fused run (their inputs differ)
    plain = tmp_path / "plain"
    assert run_cli("real", "complete", src, "--out", plain, *common[:7]).returncode == 0
    assert run_cli("real", "complete", src, "--out", plain, *common, "--resume").returncode == 0
    assert json.loads((plain / "summary.json").read_text())["totals"]["resumed"] == 0


@pytest.mark.timeout(180)
def test_resume_does_not_reuse_frames_fused_over_another_selection(tmp_path):
    """Frames done by a fused run over another selection (``--frames 2:5``: frame 2's past window then lacked frame 1)
    are not reused by ``--resume`` over every frame: the files are those of one run over every frame. Before, the
    fusion settings matched and frames 2-4 kept their inputs of the smaller selection."""
    pytest.importorskip("torch")
    from helpers import run_cli
    from learning_fixtures import make_checkpoint

    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0, 1.5, 2.0])
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    common = ["--format", "generic", "-c", ck, "--no-clip", "-q", "--no-pictures", "--fuse", "past:2"]
    common += ["--no-track-worker"]
    one, two = tmp_path / "one", tmp_path / "two"
    assert run_cli("real", "complete", src, "--out", one, *common).returncode == 0
    assert run_cli("real", "complete", src, "--out", two, *common, "--frames", "2:5").returncode == 0
    proc = run_cli("real", "complete", src, "--out", two, *common, "--resume")
    assert proc.returncode == 0, proc.stderr
    for k in range(5):
        f = f"drive/f{k}.ply"
        assert (one / f).read_bytes() == (two / f).read_bytes(), f
