"""Output names taken from the data (frame ids, sequences, track ids) never overwrite a file of the run or of each
other, and the tracks of a sequence go to that sequence's folder (spotlights.completion.names: one owner)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spotlights.cli import main
from spotlights.completion.frame_selection import frame_stems
from spotlights.completion.names import file_stem, sequence_folders, unique_names

SIZE = [4.2, 1.8, 1.5]


def test_no_frame_or_sequence_takes_a_file_of_the_run():
    stems = frame_stems([("", "tracks"), ("", "summary"), ("", "Tracks"), ("", "f1")])
    names = {k[1]: s.as_posix() for k, s in stems.items()}
    assert names["f1"] == "f1"
    for taken in ("tracks", "summary", "Tracks"):  # tracks.json, summary.json (letter case ignored)
        assert names[taken].startswith(f"{taken}-") and len(names[taken]) == len(taken) + 9, names
    folders = sequence_folders([("tracks", "a"), ("tracks.json", "a"), ("summary.json", "a"), ("drive", "a")])
    assert folders["drive"] == "drive"
    for taken in ("tracks", "tracks.json", "summary.json"):  # OUT/tracks/ holds the tracks without a sequence
        assert folders[taken] != taken and folders[taken].startswith(taken + "-")


def test_track_names_are_distinct_and_short():
    ids = ["a/b", "a_b", "A_B", "x" * 300, "汽车", ""]
    names = unique_names(ids, empty="track")
    assert len({n.casefold() for n in names.values()}) == len(ids)
    assert names["a/b"] != "a_b" and all(len(n) <= 109 and n.isascii() for n in names.values())
    assert file_stem("", empty="track").startswith("track-")


def _drive(folder, sequence: str, frame_ids, track_ids):
    """A generic sequence (one JSON): two frames or more, each with one box per track id (points on its faces)."""
    rng = np.random.default_rng(0)
    folder.mkdir(parents=True)
    frames = []
    for k, fid in enumerate(frame_ids):
        pts, boxes = [rng.uniform(-30, 30, (300, 3)) * [1, 1, 0] - [0, 0, 1.7]], []
        for j, tid in enumerate(track_ids):
            c = [8.0 + 0.5 * k, -6.0 + 4.0 * j, -0.9]
            obj = rng.uniform(-0.5, 0.5, (300, 3)) * SIZE
            obj[:, 0] = np.sign(obj[:, 0]) * SIZE[0] / 2
            obj[:, 2] = rng.uniform(-SIZE[2] / 2 + 0.12, SIZE[2] / 2, 300)
            pts.append(obj + c)
            boxes.append({"center": c, "size": SIZE, "yaw": 0.0, "label": "car", "track_id": tid})
        np.save(folder / f"s{k}.npy", np.concatenate(pts).astype(np.float32))
        frames.append({"scan": f"s{k}.npy", "frame_id": fid, "timestamp": 0.5 * k, "boxes": boxes})
    (folder / "seq.json").write_text(json.dumps({"sequence": sequence, "frames": frames}, ensure_ascii=False))
    return folder / "seq.json"


@pytest.mark.timeout(300)
@pytest.mark.parametrize("sequence", ["", "../../evil"])
def test_fused_run_keeps_every_file_whatever_the_names(tmp_path, sequence):
    """A frame named ``tracks`` beside the run files (before: its JSON was overwritten by tracks.json), track ids
    that sanitise alike (``a/b``, ``a_b``: before, one PLY for two tracks) or are 300 characters long (before: the
    run failed after every frame was written), and a sequence whose name is sanitised (before: the frames and the
    tracks went to different folders)."""
    pytest.importorskip("torch")
    from learning_fixtures import make_checkpoint

    long_id = "t" * 300
    seq = _drive(tmp_path / "drive", sequence, ["tracks", "f1", "f2"], ["a/b", "a_b", long_id])
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    out = tmp_path / "out"
    argv = ["real", "complete", str(seq), "-f", "generic", "-o", str(out), "-c", str(ck), "--fuse", "all"]
    assert main([*argv, "--no-pictures", "--no-clip", "-q"]) == 0
    run = json.loads((out / "tracks.json").read_text())
    assert run["n_tracks"] == 3 and len(run["tracks"]) == 3  # the tracks' summary, not a frame's
    summary = json.loads((out / "summary.json").read_text())
    frame_jsons = [out / (f["ply"][len(str(out)) + 1 : -len(".ply")] + ".json") for f in summary["frames"]]
    assert [json.loads(p.read_text())["frame_id"] for p in frame_jsons] == ["tracks", "f1", "f2"]
    folders = {p.parent for p in frame_jsons}
    assert len(folders) == 1
    frames_folder = folders.pop()
    assert frames_folder.resolve().is_relative_to(out.resolve())
    tracks = sorted((frames_folder / "tracks").glob("*.ply"))  # the tracks of the sequence sit in its folder
    assert len(tracks) == 3, sorted(p.relative_to(out).as_posix() for p in out.rglob("*"))
    assert all(len(p.name) <= 113 for p in tracks)
