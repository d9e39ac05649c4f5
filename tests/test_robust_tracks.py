"""A box turned around (a 180-degree yaw flip) inside a track: found, flagged (``yaw_flip``) and left out of the
fusion under ``--fuse --refine-boxes``; before, it passed as ``no_gain`` and its mirrored points were fused into the
later frames."""

from __future__ import annotations

import json
import math

import pytest

from spotlights.data.tracks import FLAGGED, yaw_flips
from spotlights.geometry.boxes import Box

from builders import track_plan, write_drive
from helpers import run_cli


def _boxes(yaws):
    return [Box([10.0 + k, 0.0, 0.0], [4.0, 1.8, 1.5], yaw=y) for k, y in enumerate(yaws)]


def test_yaw_flips_by_hand():
    assert "yaw_flip" in FLAGGED
    assert yaw_flips(_boxes([0.0, 0.05, math.pi, 0.1, 0.12])) == [False, False, True, False, False]
    assert yaw_flips(_boxes([0.0, 0.05, math.pi - 0.05, 0.1])) == [False, False, True, False]
    # a U-turn over many frames is followed, not flagged
    assert yaw_flips(_boxes([0.3 * k for k in range(12)])) == [False] * 12
    # the first box was the odd one: the next disagrees with it, the one after agrees with that one
    assert yaw_flips(_boxes([math.pi, 0.0, 0.02, 0.04])) == [False, True, False, False]
    # 120 degrees between frames is a turn here (below the 135-degree limit); the sign does not matter
    assert yaw_flips(_boxes([0.0, -math.radians(120)])) == [False, False]
    assert yaw_flips([]) == []


def _flip(folder, frame: int, track: str = "a") -> None:
    path = folder / f"f{frame}.json"
    data = json.loads(path.read_text())
    for b in data["boxes"]:
        if b.get("track_id") == track:
            b["yaw"] = math.pi
    path.write_text(json.dumps(data))


def test_a_flipped_frame_is_flagged_and_left_out_of_the_fusion(tmp_path):
    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0, 1.5, 2.0])
    _flip(src, 2)
    plan, keys = track_plan(src, "past:2", worker=False)
    extras = [plan.frame_inputs(key, plan.take(key).boxes)[1] for key in keys]
    plan.finish()
    tr = next(t for t in plan.tracks.values() if t.track_id == "a")
    assert tr.status[2] == "yaw_flip"
    assert "yaw_flip" not in tr.status[:2] + tr.status[3:]
    index = next(i for i, b in enumerate(plan_boxes(src, keys[0])) if b["track_id"] == "a")
    # past:2: frame 2 fuses nothing (its own box is turned around); frame 3's window is [2, 3]: nothing from 2
    assert len(extras[2][index]) == 0 and len(extras[3][index]) == 0
    assert len(extras[1][index]) > 0 and len(extras[4][index]) > 0  # its neighbours fuse as before
    assert tr.n_fused[3] == tr.n_points[3]
    # the given box of the flipped frame is kept (not "refined" by half a turn)
    assert tr.boxes[2].yaw == pytest.approx(math.pi)


def plan_boxes(src, key):
    return json.loads((src / f"{key[1]}.json").read_text())["boxes"]


def test_cli_reports_the_flip_in_tracks_json(tmp_path):
    pytest.importorskip("torch")
    from learning_fixtures import make_checkpoint

    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0, 1.5])
    _flip(src, 2)
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    out = tmp_path / "out"
    proc = run_cli(
        "real", "complete", src, "--format", "generic", "-c", ck, "--out", out, "--fuse", "past:2",
        "--refine-boxes", "-q", "--no-pictures", "--no-track-worker",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    tracks = json.loads((out / "tracks.json").read_text())
    frames = next(t for t in tracks["tracks"] if t["track_id"] == "a")["frames"]
    assert [(f["status"], f["flagged"]) for f in frames][2] == ("yaw_flip", True)
    # the flipped frame and the one after (its window: itself and the flipped one) hold their own points only
    assert [f["n_fused"] == f["n_points"] for f in frames] == [True, False, True, True]
    assert tracks["n_flagged"] == 1
