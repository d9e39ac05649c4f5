"""Multi-frame generic data: folders of frames, sequence JSONs with per-frame box files, float timestamps,
several SOURCEs in one call; ``real complete`` over them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from spotlights.cli import main
from spotlights.data.real import open_reader
from spotlights.data.real.extract import ExtractConfig, extract, read_observations, write_observations
from spotlights.errors import InputFileError
from spotlights.geometry.boxes import Box
from spotlights.metrics.consistency import consecutive_pairs

SIZE = [4.2, 1.8, 1.5]


def car_points(rng, center, yaw, n=300):
    obj = rng.uniform(-0.5, 0.5, (n, 3)) * SIZE
    obj[:, 2] = np.abs(obj[:, 2])
    return obj @ Box.from_yaw(center, SIZE, yaw).rotation.T + center


def write_frame(folder, name, t, rng, ext=".npy", key="timestamp", moving=True):
    """One frame: a scan with car 'a' (moving with t) and car 'b', plus its box file NAME.json."""
    folder.mkdir(parents=True, exist_ok=True)
    ca = [10.0 + (2.0 * t if moving else 0.0), 2.0, -0.9]
    cb = [-6.0, -5.0, -0.9]
    pts = np.concatenate(
        [car_points(rng, ca, 0.3), car_points(rng, cb, -1.0), rng.uniform(-30, 30, (500, 3)) * [1, 1, 0] - [0, 0, 1.7]]
    )
    pts = pts.astype(np.float32)
    if ext == ".npy":
        np.save(folder / f"{name}.npy", pts)
    elif ext == ".bin":
        np.c_[pts, np.zeros(len(pts))].astype("<f4").tofile(folder / f"{name}.bin")
    elif ext == ".pcd.bin":
        np.c_[pts, np.zeros(len(pts)), rng.integers(0, 32, len(pts))].astype("<f4").tofile(folder / f"{name}.pcd.bin")
    boxes = [
        {"center": ca, "size": SIZE, "yaw": 0.3, "label": "car", "track_id": "a"},
        {"center": cb, "size": SIZE, "yaw": -1.0, "label": "Car", "track_id": "b"},
    ]
    (folder / f"{name}.json").write_text(json.dumps({key: t, "boxes": boxes}))
    return pts


def test_float_timestamps_order_frames(tmp_path):
    """0.25 s, 0.5 s, 1.0 s, 10.0 s under names that sort otherwise: ordered by time, never cut to integers."""
    rng = np.random.default_rng(0)
    for name, t in (("b", 0.5), ("a", 10.0), ("d", 0.25), ("c", 1.0)):
        write_frame(tmp_path / "drive", name, t, rng)
    reader = open_reader(tmp_path / "drive", "generic")
    assert [k[1] for k in reader.frame_keys()] == ["d", "b", "c", "a"]
    obs = extract(reader, ExtractConfig(), progress=False)
    assert obs.timestamp.dtype == np.float64
    assert sorted(set(obs.timestamp.tolist())) == [0.25, 0.5, 1.0, 10.0]
    pairs = consecutive_pairs(obs.object_keys(), obs.timestamp)
    a_pairs = [(obs.timestamp[i], obs.timestamp[j]) for i, j in pairs if obs.track_id[i] == "a"]
    assert a_pairs == [(0.25, 0.5), (0.5, 1.0), (1.0, 10.0)]
    assert set(obs.sequence) == {"drive"}  # a folder's sequence: its name
    # the file keeps them as floats
    write_observations(tmp_path / "o.h5", obs)
    back = read_observations(tmp_path / "o.h5")
    assert back.timestamp.dtype == np.float64 and back.timestamp.tolist() == obs.timestamp.tolist()
    # car 'a' moves 2 m per second: its box centres follow the time order
    xs = [obs.box_center[i, 0] for i in np.argsort(obs.timestamp) if obs.track_id[i] == "a"]
    np.testing.assert_allclose(xs, [10.5, 11.0, 12.0, 30.0])


def test_frame_index_and_name_order(tmp_path):
    rng = np.random.default_rng(1)
    for name, i in (("x", 2), ("y", 0), ("z", 1)):
        write_frame(tmp_path / "idx", name, i, rng, key="frame_index")
    assert [k[1] for k in open_reader(tmp_path / "idx", "generic").frame_keys()] == ["y", "z", "x"]
    # no key at all: natural order of the names (frame2 before frame10)
    for name in ("frame10", "frame2", "frame1"):
        write_frame(tmp_path / "names", name, 0, rng)
        d = json.loads((tmp_path / "names" / f"{name}.json").read_text())
        (tmp_path / "names" / f"{name}.json").write_text(json.dumps(d["boxes"]))
    assert [k[1] for k in open_reader(tmp_path / "names", "generic").frame_keys()] == ["frame1", "frame2", "frame10"]
    # a sequence mixing frames with and without a timestamp is refused
    (tmp_path / "names" / "frame2.json").write_text(json.dumps({"timestamp": 0.5, "boxes": []}))
    with pytest.raises(InputFileError, match="mixes frames with and without a timestamp"):
        open_reader(tmp_path / "names", "generic")


def test_multi_file_round_trip_sequence_json_and_several_sources(tmp_path, capsys):
    """A sequence JSON referencing per-frame box files (KITTI .bin and nuScenes .pcd.bin scans) plus a folder of
    frames, in one call: every box comes back as an observation of the right track, with its points."""
    rng = np.random.default_rng(2)
    seq_dir = tmp_path / "seq"
    clouds = {}
    for k, (name, ext) in enumerate((("f0", ".bin"), ("f1", ".pcd.bin"), ("f2", ".bin"))):
        clouds[name] = write_frame(seq_dir / "frames", name, 0.1 * k, rng, ext=ext)
        (seq_dir / "frames" / f"{name}.json").rename(seq_dir / f"boxes_{name}.json")
    frames = [
        {"scan": f"frames/{n}{e}", "boxes": f"boxes_{n}.json", "frame_id": n}
        for n, e in (("f0", ".bin"), ("f1", ".pcd.bin"), ("f2", ".bin"))
    ]
    (seq_dir / "sequence.json").write_text(json.dumps({"sequence": "drive-a", "frames": frames}))
    for k in range(2):
        write_frame(tmp_path / "drive-b", f"{k:04d}", 0.05 * k, rng)
    out = tmp_path / "obs.h5"
    assert (
        main(
            [
                "real",
                "extract",
                str(seq_dir / "sequence.json"),
                str(tmp_path / "drive-b"),
                "--format",
                "generic",
                "--out",
                str(out),
                "-q",
            ]
        )
        == 0
    )
    obs = read_observations(out)
    assert len(obs) == 10 and set(obs.sequence) == {"drive-a", "drive-b"}
    assert obs.timestamp.dtype == np.float64  # 0.1 s steps kept
    keys = obs.object_keys()
    assert sorted({k for k in keys}) == [("drive-a", "a"), ("drive-a", "b"), ("drive-b", "a"), ("drive-b", "b")]
    assert all(n == 300 for n in obs.n_points_raw)  # every car point, no ground
    for i in range(len(obs)):  # the stored raw points are the car's points, in its unit frame
        raw = obs.raw(i).astype(np.float64)
        back = raw @ obs.unit_to_sensor[i][:3, :3].T + obs.unit_to_sensor[i][:3, 3]
        assert np.linalg.norm(back - obs.box_center[i], axis=1).max() <= 0.5 * np.linalg.norm(SIZE) + 0.3
    # a frame id found in two sources of one sequence is refused
    write_frame(tmp_path / "dup" / "drive-b", "0000", 0.0, rng)
    assert (
        main(
            [
                "real",
                "extract",
                str(tmp_path / "drive-b"),
                str(tmp_path / "dup" / "drive-b"),
                "--format",
                "generic",
                "--out",
                str(tmp_path / "x.h5"),
                "-q",
            ]
        )
        == 2
    )
    assert "also in" in capsys.readouterr().err and not (tmp_path / "x.h5").exists()

    # real complete over both sources: per-frame scene files, pictures and a summary
    from learning_fixtures import make_checkpoint

    pytest.importorskip("torch")
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    res = tmp_path / "done"
    assert (
        main(
            [
                "real",
                "complete",
                str(seq_dir / "sequence.json"),
                str(tmp_path / "drive-b"),
                "--format",
                "generic",
                "--out",
                str(res),
                "-c",
                str(ck),
                "--no-clip",
                "-q",
                "--frames",
                "0:4",
            ]
        )
        == 0
    )
    from spotlights.geometry.io import load_ply_fields

    summary = json.loads((res / "summary.json").read_text())
    assert summary["n_frames"] == 4 and summary["totals"]["completed"] == 8
    f = load_ply_fields(res / "drive-a" / "f1.ply")
    assert len(f["x"]) == len(clouds["f1"]) + int((f["source"] == 2).sum())
    np.testing.assert_allclose(np.c_[f["x"], f["y"], f["z"]][: len(clouds["f1"])], clouds["f1"], atol=1e-6)
    assert (res / "drive-a" / "f1.png").stat().st_size > 1000 and (res / "drive-a" / "f1.json").is_file()
    assert (res / "drive-b" / "0000.ply").is_file() and not (res / "drive-b" / "0001.ply").exists()  # --frames 0:4
    # --resume: finished frames (their JSON written last) are read back, not recomputed
    before = (res / "drive-a" / "f1.ply").stat().st_mtime_ns
    (res / "drive-a" / "f2.json").unlink()
    args = [
        "real",
        "complete",
        str(seq_dir / "sequence.json"),
        str(tmp_path / "drive-b"),
        "--format",
        "generic",
        "--out",
        str(res),
        "-c",
        str(ck),
        "--no-clip",
        "-q",
        "--frames",
        "0:4",
        "--resume",
    ]
    assert main(args) == 0
    again = json.loads((res / "summary.json").read_text())
    assert again["totals"]["resumed"] == 3 and again["totals"]["completed"] == 8
    assert (res / "drive-a" / "f1.ply").stat().st_mtime_ns == before and (res / "drive-a" / "f2.json").is_file()


def test_rotation_boxes_honoured(tmp_path):
    rng = np.random.default_rng(3)
    write_frame(tmp_path / "r", "f", 0.0, rng)
    d = json.loads((tmp_path / "r" / "f.json").read_text())
    for b in d["boxes"]:
        b["rotation"] = Box.from_yaw(b["center"], b["size"], b.pop("yaw")).rotation.tolist()
    (tmp_path / "r" / "f.json").write_text(json.dumps(d))
    obs = extract(open_reader(tmp_path / "r", "generic"), ExtractConfig(), progress=False)
    assert sorted(obs.box_yaw.round(6).tolist()) == [-1.0, 0.3] and all(n == 300 for n in obs.n_points_raw)
    assert math.isclose(float(obs.timestamp[0]), 0.0)


# ids that sanitise alike ("a" and "../a"; "汽车", "日本", ".." and "frame"), that differ by a dot ("x.1", "x.2",
# which with_suffix cut to "x"), that differ in letter case only, and one that is the run's own summary
CLASHING_IDS = ["a", "../a", "汽车", "日本", "..", "frame", "x.1", "x.2", "B", "b", "summary", "000123"]


def test_frame_stems_are_distinct_readable_and_stable():
    from spotlights.completion.frame_selection import frame_stems

    keys = [("", f) for f in CLASHING_IDS] + [("scene-0523", "smp0"), ("../scene-0523", "smp0"), ("s", "a")]
    stems = frame_stems(keys)
    names = [str(stems[k]) for k in keys]
    assert len({n.casefold() for n in names}) == len(keys)  # distinct, even where letter case is ignored
    assert stems[("", "a")].as_posix() == "a" and stems[("", "000123")].as_posix() == "000123"  # safe ids kept
    assert stems[("", "x.1")].as_posix() == "x.1" and stems[("scene-0523", "smp0")].as_posix() == "scene-0523/smp0"
    assert stems[("s", "a")].as_posix() == "s/a"
    for stem in stems.values():
        assert ".." not in stem.parts and not stem.is_absolute() and stem.name != "summary"
        assert all(len(p) <= 109 and p.isascii() for p in stem.parts)
    assert stems[("", "../a")].as_posix().startswith("a-") and stems[("", "汽车")].as_posix().startswith("frame-")
    # a frame's name does not depend on which other frames the run holds (resume and --frames find it again)
    assert frame_stems([("", "../a")]) == {("", "../a"): stems[("", "../a")]}


def test_real_complete_writes_one_file_set_per_frame_whatever_the_ids(tmp_path):
    """Frame k's scan holds 1,000 + k points: each frame's JSON names its own id and PLY, and that PLY
    holds that frame's raw points (none was overwritten by another frame of a like name)."""
    pytest.importorskip("torch")
    from spotlights.geometry.io import load_ply_fields

    from learning_fixtures import make_checkpoint

    rng = np.random.default_rng(5)
    frames = []
    for k, fid in enumerate(CLASHING_IDS):
        pts = np.concatenate([car_points(rng, [10.0, 2.0, -0.9], 0.3), rng.uniform(-30, 30, (700 + k, 3))])
        np.save(tmp_path / f"s{k}.npy", pts.astype(np.float32))
        box = {"center": [10.0, 2.0, -0.9], "size": SIZE, "yaw": 0.3, "label": "car"}
        frames.append({"scan": f"s{k}.npy", "frame_id": fid, "timestamp": k, "boxes": [box]})
    (tmp_path / "seq.json").write_text(json.dumps({"frames": frames}, ensure_ascii=False))
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    out = tmp_path / "out"
    argv = ["real", "complete", str(tmp_path / "seq.json"), "--format", "generic", "-o", str(out), "-c", str(ck)]
    assert main([*argv, "--no-pictures", "--no-clip", "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_frames"] == len(CLASHING_IDS)
    plys = [f["ply"] for f in summary["frames"]]
    assert len(set(plys)) == len(CLASHING_IDS) and len(list(out.glob("*.ply"))) == len(CLASHING_IDS)
    for rec in summary["frames"]:
        k = CLASHING_IDS.index(rec["frame_id"])
        own = json.loads(Path(rec["ply"][: -len(".ply")] + ".json").read_text())
        assert own["frame_id"] == rec["frame_id"]
        f = load_ply_fields(rec["ply"])
        assert int((f["source"] < 2).sum()) == 300 + 700 + k
