"""``real complete --rerun FILE.rrd``: the recording read back with rerun-sdk (entities, frames, times)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spotlights.cli import main

SIZE = [4.2, 1.8, 1.5]


def write_drive(folder, times):
    """Generic frames: two tracked cars (box-surface points on their front and back faces) and ground."""
    rng = np.random.default_rng(0)
    folder.mkdir(parents=True, exist_ok=True)
    for k, t in enumerate(times):
        boxes, pts = [], [rng.uniform(-30, 30, (200, 3)) * [1, 1, 0] - [0, 0, 1.7]]
        for tid, c in zip("ab", ([10.0 + 2.0 * t, 2.0, -0.9], [-6.0, -5.0, -0.9])):
            obj = rng.uniform(-0.5, 0.5, (200, 3)) * SIZE
            obj[:, 0] = np.sign(obj[:, 0]) * SIZE[0] / 2
            obj[:, 2] = rng.uniform(-SIZE[2] / 2 + 0.12, SIZE[2] / 2, 200)
            pts.append(obj + c)
            boxes.append({"center": c, "size": SIZE, "yaw": 0.0, "label": "car", "track_id": tid})
        np.save(folder / f"f{k}.npy", np.concatenate(pts).astype(np.float32))
        (folder / f"f{k}.json").write_text(json.dumps({"timestamp": t, "boxes": boxes}))
    return folder


def test_recording_holds_every_frame_on_a_time_line(tmp_path):
    pytest.importorskip("torch")
    pytest.importorskip("rerun", reason="rerun-sdk is an optional extra (pip install 'spotlights[rerun]')")
    from spotlights.viz.rerun_log import read_recording

    from learning_fixtures import make_checkpoint

    src = write_drive(tmp_path / "drive", [0.0, 0.5, 1.5])
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    rrd = tmp_path / "drive.rrd"
    argv = ["real", "complete", str(src), "--format", "generic", "-c", str(ck), "--no-clip", "-q", "--no-pictures"]
    assert main([*argv, "--out", str(tmp_path / "out"), "--fuse", "all", "--rerun", str(rrd)]) == 0
    got = read_recording(rrd)
    assert got["frames"] == [0, 1, 2]
    assert {"frame", "time"} <= set(got["timelines"])
    names = ("scan", "boxes/given", "boxes/used", "fused", "completion")
    assert got["entities"] == {f"/drive/{n}": 3 for n in names}
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_bad_rerun_name_is_one_line_and_writes_nothing(tmp_path, capsys):
    src = write_drive(tmp_path / "drive", [0.0, 0.5])
    out = tmp_path / "out"
    argv = ["real", "complete", str(src), "--format", "generic", "--out", str(out), "--rerun", str(tmp_path / "x.txt")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "x.txt: a rerun recording's name must end in .rrd" in err[0], err
    assert not out.exists()
