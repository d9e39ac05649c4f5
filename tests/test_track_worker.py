"""Track completion on two cores: the box refinement made frame by frame (``TrackRefiner``) and the worker process
that refines and fuses a frame ahead of the completion (``TrackWorker``) give the answers of the one-process path,
and a failing or dying worker ends the run with its error instead of hanging."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from spotlights.completion.fusion import TrackWorker, usable_cpus
from spotlights.data.tracks import TrackFrame, TrackRefiner, refine_track

from builders import drive_past, track_inputs, track_plan, write_drive


def test_frame_by_frame_causal_refinement_sees_no_later_frame_and_recovers_the_perturbation():
    """past:3, frame 5 given 0.2 m / 4 degrees off: each frame's box is final once the loop reaches it, equals
    the box the frames up to it alone give (a later frame changes nothing), and frame 5 lands on its true box."""
    frames, truth = drive_past({5: (0.2, 0.1, math.radians(-4.0))})
    kw = dict(margin=0.8, ground_clearance=0.1)
    ref = TrackRefiner(frames, "past:3", **kw)
    for t in range(len(frames)):
        ref.upto(t)
        assert ref.done == t
        alone = refine_track(frames[: t + 1], "past:3", **kw) if t else None  # the frames up to t only
        box = ref.box(t)
        if alone is not None:
            np.testing.assert_array_equal(box.center, alone.boxes[t].center)
            np.testing.assert_array_equal(box.rotation, alone.boxes[t].rotation)
            assert ref.status[t] == alone.status[t]
    assert ref.status[0] == "no_reference" and ref.status[5] == "refined"
    assert np.linalg.norm(ref.box(5).center - truth[5].center) < 0.03
    assert abs(math.degrees(math.remainder(ref.box(5).yaw - truth[5].yaw, 2 * math.pi))) < 0.5
    whole = refine_track(frames, "past:3", **kw)
    assert [b.center.tolist() for b in ref.result().boxes] == [b.center.tolist() for b in whole.boxes]


def test_a_window_that_looks_ahead_refines_the_whole_track_at_the_first_frame():
    """all: frame 0's box needs every frame, so the first upto(0) refines the track (every round); frame 1, given
    0.3 m and 5 degrees off, is recovered within 2 cm / 0.5 degree."""
    d = 0.3 / math.sqrt(2)
    frames, truth = drive_past({1: (d, -d, math.radians(5.0))})
    ref = TrackRefiner(frames, "all", margin=0.8, ground_clearance=0.1)
    ref.upto(0)
    assert ref.done == len(frames) - 1 and ref.status[1] == "refined"
    assert np.linalg.norm(ref.box(1).center - truth[1].center) < 0.02
    assert abs(math.degrees(math.remainder(ref.box(1).yaw - truth[1].yaw, 2 * math.pi))) < 0.5


needs_two_cpus = pytest.mark.skipif(usable_cpus() < 2, reason="a worker process is started with 2+ usable CPUs only")


@needs_two_cpus
@pytest.mark.timeout(120)
@pytest.mark.parametrize("window", ["past:2", "centered:3"])
def test_worker_gives_the_inputs_boxes_and_statuses_of_one_process(tmp_path, window):
    """Two tracked cars over four frames, one of them given turned by 0.08 rad in frame 2: the worker process hands the
    frame loop the same boxes and fused points, and the plan ends with the same refined boxes and statuses, as
    the plan working alone; the worker did the refinement (its CPU seconds are counted)."""
    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0, 1.5])
    boxes = json.loads((src / "f2.json").read_text())
    boxes["boxes"][0]["yaw"] = 0.08
    (src / "f2.json").write_text(json.dumps(boxes))
    alone, keys = track_plan(src, window, worker=False)
    paired, _ = track_plan(src, window, worker=True)
    assert paired.worker_process is not None  # a worker process started
    assert track_inputs(paired, keys) == track_inputs(alone, keys)
    sa, sp = alone.summary(), paired.summary()
    assert sa["timings"]["worker_cpu_s"] == 0.0 and sp["timings"]["worker_cpu_s"] > 0.0
    for s in (sa, sp):
        s.pop("timings")
    assert sp == sa
    assert sa["n_refined"] >= 1  # the turned box was corrected
    assert paired.worker_process is None  # ended


@needs_two_cpus
@pytest.mark.timeout(60)
def test_torch_leaves_a_core_to_the_worker_while_it_runs(tmp_path):
    """With a worker, torch runs on the usable CPUs less one (not fewer than the caller's count), restored after."""
    torch = pytest.importorskip("torch")
    from spotlights.completion.fusion import threads_beside_worker

    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0])
    plan, keys = track_plan(src, "past:2", worker=False)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(usable_cpus())
        with threads_beside_worker(plan):  # no worker yet: nothing changes
            assert torch.get_num_threads() == usable_cpus()
        assert plan.start_worker(keys)
        with threads_beside_worker(plan):
            assert torch.get_num_threads() == usable_cpus() - 1
        assert torch.get_num_threads() == usable_cpus()
        torch.set_num_threads(1)
        with threads_beside_worker(plan):  # a lower count set by the caller is kept
            assert torch.get_num_threads() == 1
    finally:
        plan.close()
        torch.set_num_threads(before)


@needs_two_cpus
@pytest.mark.timeout(60)
def test_a_plan_dropped_without_finishing_ends_its_worker(tmp_path):
    """Library use: a plan with a worker, dropped half-way (no finish, no close): collecting it ends the process."""
    import gc

    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0])
    plan, keys = track_plan(src, "past:2", worker=False)
    assert plan.start_worker(keys)
    proc = plan.worker_process
    plan.frame_inputs(keys[0], plan.take(keys[0]).boxes)
    assert proc.is_alive()
    del plan
    gc.collect()
    proc.join(10)
    assert not proc.is_alive()


@needs_two_cpus
@pytest.mark.timeout(60)
def test_a_dying_worker_ends_the_run_with_an_error(tmp_path):
    """A worker process killed before its first result: the frame loop raises at once (no wait forever) a
    TrackWorkerDied (a ProcessFailure: one line, exit code 1 on the command line)."""
    from spotlights.completion.fusion import TrackWorkerDied

    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0])
    plan, keys = track_plan(src, "past:2", worker=False)
    w = TrackWorker.start()
    assert w is not None
    w.proc.kill()
    w.proc.join(10)
    assert plan.start_worker(keys, w)
    with pytest.raises(TrackWorkerDied, match="track worker process ended") as caught:
        plan.frame_inputs(keys[0], plan.take(keys[0]).boxes)
    assert caught.value.exit_code == 1
    plan.close()
    assert plan.worker_process is None


@needs_two_cpus
@pytest.mark.timeout(60)
def test_an_error_in_the_worker_is_raised_in_the_run(tmp_path):
    """A track whose frame holds points of the wrong shape: the worker's ValueError is raised by the frame loop,
    and the worker has ended."""
    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0])
    plan, keys = track_plan(src, "past:2", worker=False)
    tr = next(iter(plan.tracks.values()))
    f = tr.frames[1]
    tr.frames[1] = TrackFrame(np.zeros((7, 2)), f.box, f.origin, f.timestamp)  # 14 numbers: not (N, 3)
    assert plan.start_worker(keys)
    proc = plan.worker_process
    with pytest.raises(ValueError) as caught:
        for key in keys:
            plan.frame_inputs(key, plan.take(key).boxes)
        plan.finish()
    # the worker's own traceback travels with the error (else only its message would be left)
    (note,) = getattr(caught.value, "__notes__", [None])
    assert note.startswith("in the track worker process:\nTraceback") and "worker_main" in note
    plan.close()
    proc.join(10)
    assert not proc.is_alive()


@needs_two_cpus
@pytest.mark.timeout(60)
def test_a_refused_run_leaves_no_worker_behind(tmp_path):
    """complete_frames starts the worker while it opens the dataset; a refusal (a vehicle box without a track id)
    is the usual one line, and the worker process has ended."""
    import multiprocessing

    from spotlights.completion.frame_selection import FramesSettings
    from spotlights.completion.frames import complete_frames
    from spotlights.errors import ParameterError

    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0], ("a", ""))
    s = FramesSettings(source=[str(src)], format="generic", out=str(tmp_path / "out"), fuse="past:2", quiet=True)
    with pytest.raises(ParameterError, match="without a track id"):
        complete_frames(s)
    assert not [p for p in multiprocessing.active_children() if p.name == "spotlights-tracks"]
    assert not (tmp_path / "out").exists()


def test_docs_quote_the_measured_worker_speed():
    """docs/studies/frame-speed.md's "Two cores" table quotes the medians of ``benchmarks/track_fusion.py --compare-worker``
    (docs/results/real/track_fusion_speed_worker_1thread_bf16.json): the frame loop's and the worker's CPU a frame
    and the wall rate, in one process and with the worker."""
    import re

    from helpers import REPO

    med = json.loads((REPO / "docs/results/real/track_fusion_speed_worker_1thread_bf16.json").read_text())
    one, two = (med["worker_and_one_process"]["median"][k] for k in ("one_process", "worker"))
    doc = re.sub(r"\s+", " ", (REPO / "docs/studies/frame-speed.md").read_text())
    assert f"| one process, 1 torch thread | {one['cpu_ms_per_frame']:.0f} | - | {one['fps_wall']:.2f}" in doc
    want = (
        f"| with the worker, 1 torch thread | **{two['cpu_ms_per_frame']:.0f}** | {two['worker_cpu_ms_per_frame']:.0f} "
        f"| **{two['fps_wall']:.2f}**"
    )
    assert want in doc


@needs_two_cpus
@pytest.mark.timeout(120)
def test_real_complete_with_and_without_the_worker_writes_the_same_files(tmp_path):
    """``real complete --fuse past:2 --refine-boxes``: the worker does the track work (its CPU is counted in
    tracks.json) unless ``--no-track-worker``; every PLY is the same bytes, the JSON the same but clock readings."""
    pytest.importorskip("torch")
    from spotlights.cli import main

    from learning_fixtures import make_checkpoint

    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0, 1.5])
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    common = ["--format", "generic", "-c", str(ck), "--no-clip", "-q", "--no-pictures", "--fuse", "past:2"]
    for name, extra in (("two", []), ("one", ["--no-track-worker"])):
        argv = ["real", "complete", str(src), "--out", str(tmp_path / name), *common, "--refine-boxes", *extra]
        assert main(argv) == 0
    t = {n: json.loads((tmp_path / n / "tracks.json").read_text()) for n in ("two", "one")}
    assert t["two"]["timings"]["worker_cpu_s"] > 0.0 and t["one"]["timings"]["worker_cpu_s"] == 0.0
    files = sorted(p.relative_to(tmp_path / "one") for p in (tmp_path / "one").rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(tmp_path / "two") for p in (tmp_path / "two").rglob("*") if p.is_file())
    assert sum(f.suffix == ".ply" for f in files) >= 6  # four frames and two tracks
    clocks = ("timings", "wall_seconds", "completion_seconds")

    def strip(x, out):
        if isinstance(x, dict):
            return {k: strip(v, out) for k, v in x.items() if k not in clocks}
        if isinstance(x, list):
            return [strip(v, out) for v in x]
        return x.replace(out, "OUT") if isinstance(x, str) else x

    for f in files:
        a, b = (tmp_path / "one" / f).read_bytes(), (tmp_path / "two" / f).read_bytes()
        if f.suffix == ".json":
            assert strip(json.loads(a), str(tmp_path / "one")) == strip(json.loads(b), str(tmp_path / "two")), f
        else:
            assert a == b, f


@needs_two_cpus
@pytest.mark.timeout(60)
def test_the_worker_crops_each_scene_as_complete_scene_would(tmp_path):
    """With a worker, each frame's scene crops come from it: for every valid box (the refined ones in place) the
    indices of the scan points inside the box grown by 0.15 m with its bottom raised by 0.10 m, by hand."""
    from builders import brute_force_crop

    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0])
    plan, keys = track_plan(src, "past:2", worker=True)
    for key in keys:
        frame = plan.take(key)
        boxes, _ = plan.frame_inputs(key, frame.boxes)
        crops = plan.frame_crops(key)
        assert crops is not None and sorted(crops) == [i for i, b in enumerate(boxes) if b.is_valid()]
        pts = np.asarray(frame.points, dtype=np.float64)
        for i, idx in crops.items():
            np.testing.assert_array_equal(idx, brute_force_crop(pts, boxes[i], 0.15, 0.10))
        assert sum(len(c) for c in crops.values()) > 0
        assert plan.frame_crops(key) is None  # handed out once
    plan.finish()


@needs_two_cpus
@pytest.mark.timeout(60)
def test_a_frame_the_loop_passes_over_counts_no_points_with_the_worker_either(tmp_path):
    """The frame loop passes over a frame (a scan of fewer than ``min_points`` points is not completed): with or
    without the worker, tracks.json counts none of its points (n_points, n_fused 0), the other frames' counts the
    same; the worker prepared the frame all the same."""
    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0, 1.5])
    counts = {}
    for worker in (False, True):
        plan, keys = track_plan(src, "past:2", worker=worker)
        assert (plan.worker_process is not None) == worker
        for key in keys[:2] + keys[3:]:  # frame 2 passed over
            plan.frame_inputs(key, plan.take(key).boxes)
        rows = [f for tr in plan.summary()["tracks"] for f in tr["frames"]]
        counts[worker] = [(f["frame_id"], f["n_points"], f["n_fused"]) for f in rows]
    assert [c for c in counts[False] if c[0] == "f2"] == [("f2", 0, 0)] * 2  # two cars, nothing counted
    assert all(c[1] == 300 for c in counts[False] if c[0] != "f2")  # each car: 300 points of its own a frame
    assert counts[True] == counts[False]


def _ignores_sigint(pid: int) -> bool:
    """Whether process ``pid`` ignores SIGINT (Linux: the SigIgn mask of /proc/PID/status, bit 1)."""
    for line in open(f"/proc/{pid}/status", encoding="ascii"):
        if line.startswith("SigIgn:"):
            return bool(int(line.split()[1], 16) >> 1 & 1)
    return False


@needs_two_cpus
@pytest.mark.timeout(60)
def test_the_worker_leaves_ctrl_c_to_the_run(tmp_path):
    """Ctrl-C reaches every process of the terminal's group: the worker ignores it, as the pool workers do (the run
    stops it; before, it printed its own traceback beside the run's one line, or failed the run's next frame with
    a KeyboardInterrupt of its own). A SIGINT sent to it alone changes nothing: the frames come as without. (Under a
    parent that ignores SIGINT itself, e.g. a background job, the worker inherits that and this passes either way.)"""
    import os
    import signal
    import sys
    import time

    if not sys.platform.startswith("linux"):
        pytest.skip("reads the signal mask in /proc (Linux)")
    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0])
    alone, keys = track_plan(src, "past:2", worker=False)
    want = track_inputs(alone, keys)
    plan, _ = track_plan(src, "past:2", worker=False)
    w = TrackWorker.start()
    assert w is not None
    # a process just forked by the fork server ignores SIGINT for a moment, then gets its parent's handlers back:
    # the worker, waiting for its plan, must ignore it for half a second in a row
    end, streak = time.monotonic() + 10, 0
    while streak < 10 and time.monotonic() < end:
        streak = streak + 1 if _ignores_sigint(w.proc.pid) else 0
        time.sleep(0.05)
    assert streak == 10
    os.kill(w.proc.pid, signal.SIGINT)
    assert plan.start_worker(keys, w)
    assert track_inputs(plan, keys) == want
    plan.finish()


@pytest.mark.timeout(30)
def test_a_container_cpu_quota_bounds_the_usable_cpus(tmp_path):
    """cgroup v2 cpu.max: "100000 100000" (docker --cpus=1) is 1 CPU, "150000 100000" 2, "max 100000" no limit;
    an unreadable or malformed file is no limit."""
    from spotlights.completion.fusion import cgroup_cpu_limit

    f = tmp_path / "cpu.max"
    for text, expected in (("100000 100000\n", 1), ("150000 100000\n", 2), ("50000 100000", 1), ("max 100000", None)):
        f.write_text(text)
        assert cgroup_cpu_limit(f) == expected, text
    f.write_text("garbage")
    assert cgroup_cpu_limit(f) is None
    assert cgroup_cpu_limit(tmp_path / "absent") is None
    assert 1 <= usable_cpus() <= (os.cpu_count() or 1)
