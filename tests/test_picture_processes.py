"""``real complete``'s picture processes (``--picture-workers N``): how many, the same bytes as drawing in the frame
loop's process, and a process that dies while drawing ends the run with one line (exit code 1)."""

from __future__ import annotations

import json
import os

import pytest

from spotlights.cli import main
from spotlights.errors import ParameterError, ProcessFailure
from spotlights.experiments import frame_completion
from spotlights.experiments.frame_completion import PICTURE_WORKERS_MAX, PictureProcesses, picture_workers
from test_faults import three_frames

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
    monkeypatch.setattr(frame_completion, "usable_cpus", lambda: cpus)
    assert picture_workers(asked, frames) == want


def test_picture_workers_refuses_a_negative_count():
    with pytest.raises(ParameterError, match="--picture-workers must be >= 0"):
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
    """Three frames drawn by the writer thread (0), by one picture process and by two (two frames in flight): the
    same PNG, PLY and JSON bytes (but timings and paths) - independent truth: the drawing in this process."""
    scans = three_frames(tmp_path / "scans")
    runs = {}
    for n in ("0", "1", "2"):
        out = tmp_path / f"out{n}"
        args = ["real", "complete", str(scans), "--format", "generic", "--out", str(out), "-q", "--picture-workers", n]
        assert main(args) == 0
        runs[n] = _outputs(out)
    frames = {f"scans/f{k}{ext}" for k in range(3) for ext in (".png", ".ply", ".json")}
    assert frames | {"summary.json"} <= set(runs["0"]), sorted(runs["0"])
    assert runs["1"].keys() == runs["0"].keys() == runs["2"].keys()
    for name in runs["0"]:
        assert runs["1"][name] == runs["0"][name], name
        assert runs["2"][name] == runs["0"][name], name


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


def test_picture_workers_on_the_command_line(tmp_path, capsys):
    scans = three_frames(tmp_path / "scans")
    with pytest.raises(SystemExit) as caught:
        main(["real", "complete", str(scans), "-f", "generic", "-o", str(tmp_path / "o"), "--picture-workers", "-1"])
    assert caught.value.code == 2 and "--picture-workers" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
