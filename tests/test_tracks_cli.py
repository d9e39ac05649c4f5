"""``real complete --fuse ... [--refine-boxes]``: track-level completion through the CLI, and its refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spotlights.cli import main

from builders import write_drive
from helpers import LIDAR, need

SIZE = [4.2, 1.8, 1.5]


@pytest.mark.parametrize(
    "times,ids,extra,message",
    [
        ([0.0, 0.5, 1.0], ("a", ""), [], "1 vehicle box(es) without a track id; --fuse needs a track id"),
        ([0.0, 0.5, 5.0], ("a", "b"), [], "track a of drive has a gap of 4.5 s between its frames 1 and 2 (limit 2 s"),
        ([0.0, 0.5, 1.0], ("a", "b"), ["--frames", "0:1"], "--fuse needs a sequence of at least 2 frames"),
        ([0.0, 0.5, 1.0], ("a", "b"), ["--fuse", "none", "--refine-boxes"], "--refine-boxes needs --fuse"),
    ],
)
def test_fuse_refusals_are_one_line_and_write_nothing(tmp_path, capsys, times, ids, extra, message):
    src = write_drive(tmp_path / "drive", times, ids)
    out = tmp_path / "out"
    argv = ["real", "complete", str(src), "--format", "generic", "--out", str(out), "--fuse", "past:2", *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert "Traceback" not in err[0] and not out.exists()


def test_bad_window_is_an_argument_error(tmp_path, capsys):
    src = write_drive(tmp_path / "drive", [0.0, 0.5])
    with pytest.raises(SystemExit) as exc:
        main(["real", "complete", str(src), "--format", "generic", "--out", str(tmp_path / "o"), "--fuse", "past:0"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "argument --fuse: unknown window 'past:0'" in err[-1] and not (tmp_path / "o").exists()


def test_fuse_on_a_generic_drive(tmp_path):
    """Two tracked cars over three frames: with past:1 (a window of one frame) the scene files are those of
    today's single-frame path, byte for byte; with all, every frame's input holds every frame's points."""
    pytest.importorskip("torch")
    from spotlights.geometry.io import load_ply_fields

    from learning_fixtures import make_checkpoint

    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.0])
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    common = ["--format", "generic", "-c", str(ck), "--no-clip", "-q", "--no-pictures"]
    assert main(["real", "complete", str(src), "--out", str(tmp_path / "none"), *common]) == 0
    assert main(["real", "complete", str(src), "--out", str(tmp_path / "p1"), "--fuse", "past:1", *common]) == 0
    for k in range(3):
        assert (tmp_path / "none" / "drive" / f"f{k}.ply").read_bytes() == (
            tmp_path / "p1" / "drive" / f"f{k}.ply"
        ).read_bytes()
    assert not (tmp_path / "none" / "tracks.json").exists()
    assert main(["real", "complete", str(src), "--out", str(tmp_path / "all"), "--fuse", "all", *common]) == 0
    tracks = json.loads((tmp_path / "all" / "tracks.json").read_text())
    assert tracks["fuse"] == "all" and tracks["n_tracks"] == 2
    for tr in tracks["tracks"]:
        own = [r["n_points"] for r in tr["frames"]]
        assert own == [300, 300, 300]  # every car point is inside its box; ground is cut
        assert [r["n_fused"] for r in tr["frames"]] == [900, 900, 900]
        f = load_ply_fields(tmp_path / "all" / "drive" / "tracks" / f"{tr['track_id']}.ply")
        inp = f["source"] == 1
        assert inp.sum() == 900 and sorted(set(f["frame"][inp])) == [0, 1, 2]
        assert (f["source"] == 2).sum() > 0 and set(f["frame"][f["source"] == 2]) == {-1}
        # box frame: the fused input lies on the front and back faces, |x| = l/2
        np.testing.assert_allclose(np.abs(f["x"][inp]), SIZE[0] / 2, atol=1e-5)
    rec = json.loads((tmp_path / "all" / "drive" / "f1.json").read_text())
    assert sorted(o["n_fused"] for o in rec["objects"] if o["status"] == "completed") == [900, 900]


def test_fuse_and_refine_on_shared_nuscenes(tmp_path):
    """A few keyframes of scene-0523, causal window, boxes refined: exit 0, every file parses, fused inputs hold
    more points than the frames' own crops."""
    pytest.importorskip("torch")
    from spotlights.geometry.io import load_ply_fields

    from learning_fixtures import make_checkpoint

    src = need(LIDAR / "nuscenes")
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    out = tmp_path / "out"
    argv = ["real", "complete", str(src), "--format", "nuscenes", "--out", str(out), "-c", str(ck), "--no-clip"]
    assert main([*argv, "--frames", "0:3", "--fuse", "past:3", "--refine-boxes", "--no-pictures", "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_frames"] == 3 and summary["tracks"]["fuse"] == "past:3" and summary["tracks"]["refine_boxes"]
    for fr in summary["frames"]:
        assert load_ply_fields(fr["ply"])["source"].size > 1000
    tracks = json.loads((out / "tracks.json").read_text())
    rows = [r for tr in tracks["tracks"] for r in tr["frames"]]
    assert {r["status"] for r in rows} <= {
        "refined",
        "no_reference",
        "too_few_points",
        "not_converged",
        "exceeds_bound",
        "single_frame",
        "no_gain",
    }
    # the bound holds on the correction in the box frame; a tilted box's heading about the scan z differs slightly
    assert all(r["moved_m"] <= 0.5 + 1e-9 and abs(r["turned_deg"]) <= 10.1 for r in rows)
    later = [r for r in rows if r["n_points"] >= 10 and r["timestamp_s"] > min(x["timestamp_s"] for x in rows)]
    assert sum(r["n_fused"] for r in later) > sum(r["n_points"] for r in later)
    plys = sorted((out / "scene-0523" / "tracks").glob("*.ply"))
    assert len(plys) == tracks["n_tracks"] > 0
    f = load_ply_fields(plys[0])
    assert set(f) >= {"x", "y", "z", "source", "frame"}
