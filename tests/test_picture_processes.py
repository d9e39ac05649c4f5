"""``real complete``'s picture processes (``--picture-workers N``): how many, the same bytes as drawing in the frame
loop's process, and a process that dies while drawing ends the run with one line (exit code 1)."""

from __future__ import annotations

import json
import multiprocessing
import os
import time

import numpy as np
import pytest

from spotlights.cli import main
from spotlights.completion import picture_processes
from spotlights.completion.picture_processes import PICTURE_WORKERS_MAX, PictureProcesses, picture_workers
from spotlights.completion.results import SceneResult
from spotlights.completion.scene_config import SceneConfig
from spotlights.errors import ParameterError, ProcessFailure

from builders import three_frames, write_drive

Image = pytest.importorskip("PIL.Image")

pytestmark = pytest.mark.timeout(300)


@pytest.mark.parametrize(
    "asked, cpus, frames, want",
    [
        (None, 2, 40, 2),  # default: one per usable CPU
        (None, 16, 40, PICTURE_WORKERS_MAX),  # at most PICTURE_WORKERS_MAX
        (None, 1, 40, 0),  # one CPU: drawn on the writer thread
        (None, 4, 3, 3),  # never more than the frames
        (None, 4, 1, 0),  # one frame: no process to start
        (0, 8, 40, 0),  # asked for none
        (3, 1, 40, 3),  # asked for: as asked (the frames permitting)
        (12, 2, 5, 5),
    ],
)
def test_picture_workers(monkeypatch, asked, cpus, frames, want):
    monkeypatch.setattr(picture_processes, "usable_cpus", lambda: cpus)
    assert picture_workers(asked, frames) == want


def test_picture_workers_refuses_a_negative_count():
    with pytest.raises(ParameterError, match="`picture_workers` must be >= 0"):
        picture_workers(-1, 10)


def _outputs(out) -> dict:
    """Every file of a run folder: bytes, JSON without its timings and the output paths it names."""
    files = {}
    for p in sorted(out.rglob("*")):
        if not p.is_file():
            continue
        if p.suffix == ".json":
            d = json.loads(p.read_text())
            for k in ("timings", "ply", "wall_seconds", "completion_seconds"):
                d.pop(k, None)
            for f in d.get("frames", []):  # summary.json: each frame's PLY path
                f.pop("ply", None)
            files[p.relative_to(out).as_posix()] = json.dumps(d, sort_keys=True)
        else:
            files[p.relative_to(out).as_posix()] = p.read_bytes()
    return files


def test_the_same_files_whatever_the_picture_processes(tmp_path):
    """Three different frames drawn by the writer thread (0), by one picture process and by two (two frames in
    flight): the same PNG, PLY and JSON bytes (but timings and paths) - independent truth: the drawing in this
    process - so no picture went to another frame's file."""
    scans = three_frames(tmp_path / "scans")
    rng = np.random.default_rng(1)
    for k in (1, 2):  # frames of their own: the car's points moved a little, the clutter redrawn
        pts = np.load(scans / f"f{k}.npy")
        pts[:600] += rng.normal(0, 0.02, (600, 3)).astype(np.float32)
        pts[600:] = rng.uniform(-30, 30, pts[600:].shape).astype(np.float32) + [0, 0, 40]
        np.save(scans / f"f{k}.npy", pts)
    runs = {}
    for n in ("0", "1", "2"):
        out = tmp_path / f"out{n}"
        args = ["real", "complete", str(scans), "--format", "generic", "--out", str(out), "-q", "--picture-workers", n]
        assert main(args) == 0
        runs[n] = _outputs(out)
    frames = {f"scans/f{k}{ext}" for k in range(3) for ext in (".png", ".ply", ".json")}
    assert frames | {"summary.json"} <= set(runs["0"]), sorted(runs["0"])
    assert runs["1"].keys() == runs["0"].keys() == runs["2"].keys()
    assert len({runs["0"][f"scans/f{k}.png"] for k in range(3)}) == 3  # three different pictures
    for name in runs["0"]:
        assert runs["1"][name] == runs["0"][name], name
        assert runs["2"][name] == runs["0"][name], name


@pytest.mark.parametrize("workers", ["0", "1"])
def test_a_box_completed_from_fused_points_alone_is_drawn(tmp_path, workers):
    """Car "a" has no point of its own in the third frame: --fuse completes it from the frames before, and its
    picture is drawn (an empty input), by the writer thread and by a picture process alike."""
    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0])
    pts = np.load(src / "f2.npy")
    np.save(src / "f2.npy", np.concatenate([pts[:300], pts[600:]]))  # ground, then car "b": car "a"'s 300 points gone
    out = tmp_path / "out"
    args = ["real", "complete", str(src), "--format", "generic", "--out", str(out), "-q", "--fuse", "past:2"]
    assert main([*args, "--picture-workers", workers]) == 0
    frame = json.loads((out / "drive" / "f2.json").read_text())
    done = {o["track_id"]: o for o in frame["objects"] if o["status"] == "completed"}
    assert done["a"]["n_points"] == 0 and done["a"]["n_fused"] > 0
    assert Image.open(out / "drive" / "f2.png").size[0] > 0


def _die() -> None:  # in a picture process: ended as the system ends a process out of memory
    os._exit(9)


def test_a_picture_process_that_dies_is_one_line_naming_the_picture(tmp_path):
    pictures = PictureProcesses(1)
    try:
        drawn = pictures.pool.submit(_die)
        with pytest.raises(ProcessFailure, match=r"f7\.png: the process drawing it ended before it was done") as caught:
            PictureProcesses.png(drawn, tmp_path / "f7.png")
        assert caught.value.exit_code == 1 and "--picture-workers 0" in str(caught.value)
    finally:
        pictures.close()


def test_a_broken_pool_is_reported_in_frame_order_not_at_the_next_frame(tmp_path):
    """A picture process died: the next frame's draw() does not raise (a traceback in the frame loop, before), its
    future holds the error, which png() reports as one line when the writer reaches that frame."""
    pictures = PictureProcesses(1)
    try:
        dead = pictures.pool.submit(_die)
        with pytest.raises(ProcessFailure):
            PictureProcesses.png(dead, tmp_path / "f0.png")
        empty = SceneResult(np.zeros((3, 3)), [], "model", None, SceneConfig())
        later = pictures.draw(empty, "not drawn")  # the pool is broken: submit would raise here
        with pytest.raises(ProcessFailure, match=r"f1\.png: the process drawing it ended"):
            PictureProcesses.png(later, tmp_path / "f1.png")
    finally:
        pictures.close()


def _hang() -> None:  # in a picture process: never ends
    time.sleep(3600)


def test_a_hung_picture_process_stops_the_run_and_is_ended(tmp_path, monkeypatch):
    """A picture that never comes: png() gives up after PICTURE_STALL_S with one line (the run waited for ever,
    Ctrl-C included, before), and close() ends the hung process after PICTURE_CLOSE_S."""
    monkeypatch.setattr(picture_processes, "PICTURE_STALL_S", 1.0)
    monkeypatch.setattr(picture_processes, "PICTURE_CLOSE_S", 1.0)
    before = set(multiprocessing.active_children())
    pictures = PictureProcesses(1)
    processes = []
    try:
        hung = pictures.pool.submit(_hang)
        processes = [p for p in multiprocessing.active_children() if p not in before]
        t0 = time.monotonic()
        with pytest.raises(ProcessFailure, match=r"f3\.png: the process drawing it made no progress for 1 s") as e:
            PictureProcesses.png(hung, tmp_path / "f3.png")
        assert e.value.exit_code == 1 and time.monotonic() - t0 < 30
    finally:
        t0 = time.monotonic()
        pictures.close()
        assert time.monotonic() - t0 < 30
    assert processes and not any(p.is_alive() for p in processes)


def test_picture_workers_on_the_command_line(tmp_path, capsys):
    scans = three_frames(tmp_path / "scans")
    with pytest.raises(SystemExit) as caught:
        main(["real", "complete", str(scans), "-f", "generic", "-o", str(tmp_path / "o"), "--picture-workers", "-1"])
    assert caught.value.code == 2 and "--picture-workers" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
