"""``spotlights complete`` on a multi-frame generic scene (a sequence .json or a folder of frames): the frames of
``real complete --format generic`` with ``--fuse``, ``--refine-boxes``, ``--rerun``; its refusals; one scan
unchanged."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spotlights.completion.fusion import usable_cpus
from spotlights.geometry.boxes import Box

from helpers import assert_user_error, run_cli

SIZE = np.array([4.0, 2.0, 1.5])
# the car's pose in each frame (centre, yaw): it drives on and turns; frame 0 sees its back, frame 1 its front
POSES = (([10.0, 3.0, -0.95], 0.0), ([14.0, 3.5, -0.95], 0.3))
N_FACE = 150


def face_points(rng, side: float) -> np.ndarray:
    """(N_FACE, 3) points on the box face x = side * l/2 (box frame, metres), all above the ground cut."""
    p = np.empty((N_FACE, 3))
    p[:, 0] = side * SIZE[0] / 2
    p[:, 1] = rng.uniform(-0.45, 0.45, N_FACE) * SIZE[1]
    p[:, 2] = rng.uniform(-SIZE[2] / 2 + 0.2, SIZE[2] / 2, N_FACE)
    return p


def write_scene(folder, track_ids=("a", "a"), sequence_json=True):
    """Two frames of one car, its back face in frame 0 and its front face in frame 1 (scan frame = box pose applied
    to the hand-made faces), plus ground. A sequence .json (as 'dataset sequences' writes), or a folder of
    NAME.npy + NAME.json frames. Returns the SOURCE."""
    rng = np.random.default_rng(0)
    folder.mkdir(parents=True, exist_ok=True)
    frames = []
    for k, ((center, yaw), side, tid) in enumerate(zip(POSES, (-1.0, 1.0), track_ids)):
        box = Box.from_yaw(np.array(center), SIZE, yaw)
        ground = rng.uniform(-30, 30, (200, 3)) * [1, 1, 0] - [0, 0, 1.75]
        pts = np.concatenate([box.from_object(face_points(rng, side)), ground]).astype(np.float32)
        np.save(folder / f"{k:04d}.npy", pts)
        b = {"center": center, "size": SIZE.tolist(), "yaw": yaw, "label": "car"}
        if tid:
            b["track_id"] = tid
        frames.append({"scan": f"{k:04d}.npy", "frame_id": f"{k:04d}", "timestamp": 0.1 * k, "boxes": [b]})
        if not sequence_json:
            (folder / f"{k:04d}.json").write_text(json.dumps({"timestamp": 0.1 * k, "boxes": [b]}))
    if not sequence_json:
        return folder
    (folder / "sequence.json").write_text(json.dumps({"sequence": "drive", "frames": frames}))
    return folder / "sequence.json"


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    pytest.importorskip("torch")
    from learning_fixtures import make_checkpoint

    return make_checkpoint(tmp_path_factory.mktemp("ck") / "tiny.pt", "sanet")


def model(ckpt) -> list[str]:
    return ["-c", str(ckpt), "--no-clip", "-q"]


def test_fused_track_covers_both_sides(tmp_path, ckpt):
    """--fuse past:2 on a sequence .json: per-frame scene PLYs with source/object, tracks/a.ply whose fused input
    holds the back face (frame 0) and the front face (frame 1) in the box frame, tracks.json with both frames."""
    from spotlights.geometry.io import load_ply_fields

    src = write_scene(tmp_path / "drive")
    out = tmp_path / "out"
    proc = run_cli("complete", src, "--out", out, "--fuse", "past:2", "--refine-boxes", *model(ckpt))
    assert proc.returncode == 0, proc.stderr
    for k in range(2):
        f = load_ply_fields(out / "drive" / f"{k:04d}.ply")
        assert (f["source"] == 1).sum() == N_FACE and set(f["object"][f["source"] == 1]) == {0}
        assert (f["source"] == 2).sum() > 0 and (f["source"] == 0).sum() == 200
    t = load_ply_fields(out / "drive" / "tracks" / "a.ply")
    inp = t["source"] == 1
    assert inp.sum() == 2 * N_FACE
    for k, side in enumerate((-1.0, 1.0)):  # box frame: frame 0 the back face, frame 1 the front face
        x = t["x"][inp & (t["frame"] == k)]
        assert len(x) == N_FACE
        np.testing.assert_allclose(x, side * SIZE[0] / 2, atol=1e-5)
    tracks = json.loads((out / "tracks.json").read_text())
    assert tracks["fuse"] == "past:2" and tracks["refine_boxes"] and tracks["n_tracks"] == 1
    rows = tracks["tracks"][0]["frames"]
    assert [r["n_points"] for r in rows] == [N_FACE, N_FACE]
    assert [r["n_fused"] for r in rows] == [N_FACE, 2 * N_FACE]  # causal: frame 0 alone, frame 1 with frame 0
    # frame 0 has no earlier frame; frame 1 shares no surface with it (front vs back): both boxes are kept
    assert rows[0]["status"] == "no_reference" and rows[1]["status"] != "refined"
    assert [r["refined_box"] == r["box"] for r in rows] == [True, True]
    assert {p.name for p in out.iterdir()} == {"drive", "summary.json", "tracks.json"}


def test_no_track_worker_on_a_scene_is_passed_on(tmp_path, ckpt):
    """``complete SCENE --fuse past:2 --no-track-worker`` does the track work in its own process (tracks.json
    counts no worker CPU) and writes the same track file as with the worker (or without it, one usable CPU)."""
    src = write_scene(tmp_path / "drive")
    runs = {"default": [], "one": ["--no-track-worker"]}
    for name, extra in runs.items():
        argv = ["complete", src, "--out", tmp_path / name, "--fuse", "past:2", *extra, *model(ckpt)]
        proc = run_cli(*argv)
        assert proc.returncode == 0, proc.stderr
    one = json.loads((tmp_path / "one" / "tracks.json").read_text())
    assert one["timings"]["worker_cpu_s"] == 0.0
    default = json.loads((tmp_path / "default" / "tracks.json").read_text())
    assert (default["timings"]["worker_cpu_s"] > 0.0) == (usable_cpus() >= 2)  # the default used the worker
    a, b = (tmp_path / n / "drive" / "tracks" / "a.ply" for n in runs)
    assert a.read_bytes() == b.read_bytes()


def test_fuse_none_is_real_complete_generic(tmp_path, ckpt):
    """Without --fuse a folder of frames gives the files of 'real complete --format generic --no-pictures': the
    same names and the same scene PLY bytes."""
    src = write_scene(tmp_path / "drive", sequence_json=False)
    a, b = tmp_path / "complete", tmp_path / "real"
    assert run_cli("complete", src, "--out", a, *model(ckpt)).returncode == 0
    argv = ["real", "complete", src, "--format", "generic", "--no-pictures", "--out", b]
    assert run_cli(*argv, *model(ckpt)).returncode == 0
    names = sorted(p.relative_to(a) for p in a.rglob("*"))
    assert names == sorted(p.relative_to(b) for p in b.rglob("*"))
    plys = [n for n in names if n.suffix == ".ply"]
    assert len(plys) == 2 and all((a / n).read_bytes() == (b / n).read_bytes() for n in plys)


def test_one_scan_is_unchanged_by_the_track_options(tmp_path, ckpt):
    """One scan: --fuse none changes nothing (the same bytes as without it; --max-gap goes with --fuse only)."""
    write_scene(tmp_path / "drive")
    boxes = tmp_path / "boxes.json"
    rows = json.loads((tmp_path / "drive" / "sequence.json").read_text())["frames"][1]["boxes"]
    boxes.write_text(json.dumps(rows))
    scan = tmp_path / "drive" / "0001.npy"
    assert run_cli("complete", scan, "--boxes", boxes, "--out", tmp_path / "a.ply", *model(ckpt)).returncode == 0
    argv = ["complete", scan, "--boxes", boxes, "--out", tmp_path / "b.ply", "--fuse", "none"]
    assert run_cli(*argv, *model(ckpt)).returncode == 0
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()


@pytest.mark.parametrize(
    "kind,extra,message",
    [
        ("scan", ["--fuse", "past:2"], "--fuse past:2 needs a multi-frame scene"),
        ("scan", ["--refine-boxes"], "--refine-boxes needs a multi-frame scene"),
        ("scan", ["--rerun", "rec.rrd"], "--rerun needs a multi-frame scene"),
        ("scan", ["--no-track-worker"], "--no-track-worker needs a multi-frame scene"),
        ("scene", ["--out", "scene.ply"], "is a multi-frame scene, written to a folder: give --out DIR"),
        ("scene", ["--boxes", "b.json"], "--boxes/--calib/--box/--center/--size/--yaw apply to one scan"),
        ("scene", ["--yaw", "0"], "--boxes/--calib/--box/--center/--size/--yaw apply to one scan"),  # 0 too
        ("scan", ["--yaw", "0.3"], "--yaw goes with --center/--size (a box file gives its own heading)"),
        ("scene", ["--show", "x.png"], "--per-object/--summary/--show/--html apply to one scan"),
        ("scene", ["--up", "y"], "--up/--forward apply to one scan"),
        ("scene", ["--refine-boxes"], "--refine-boxes needs --fuse"),
        ("scene", ["--fuse", "all", "--rerun", "rec.txt"], "a rerun recording's name must end in .rrd"),
        ("folder", [], "box file of scan 0000.npy not found (each scan needs NAME.json beside it; or give this seq"),
    ],
)
def test_refusals_are_one_line_and_write_nothing(tmp_path, kind, extra, message):
    src = write_scene(tmp_path / "drive")
    if kind == "scan":
        src = tmp_path / "drive" / "0000.npy"
        extra = [*extra, "--boxes", tmp_path / "drive" / "sequence.json"]
    elif kind == "folder":  # the folder of a sequence .json is no folder of frames
        src = tmp_path / "drive"
    before = sorted(tmp_path.rglob("*"))
    argv = ["complete", src, "--out", tmp_path / "out", *extra]
    assert_user_error(run_cli(*argv, cwd=tmp_path), message)
    assert sorted(tmp_path.rglob("*")) == before  # nothing written, no temporary left


def test_boxes_without_track_ids_are_refused_with_fuse(tmp_path):
    src = write_scene(tmp_path / "drive", track_ids=("a", ""), sequence_json=False)
    proc = run_cli("complete", src, "--out", tmp_path / "out", "--fuse", "all")
    assert_user_error(proc, "frame drive/0001", "1 vehicle box(es) without a track id; --fuse needs a track id")
    assert not (tmp_path / "out").exists()


def test_rerun_recording_of_a_scene(tmp_path, ckpt):
    pytest.importorskip("rerun", reason="rerun-sdk is an optional extra (pip install 'spotlights[rerun]')")
    from spotlights.viz.rerun_log import read_recording

    src = write_scene(tmp_path / "drive")
    rrd = tmp_path / "drive.rrd"
    proc = run_cli("complete", src, "--out", tmp_path / "out", "--fuse", "all", "--rerun", rrd, *model(ckpt))
    assert proc.returncode == 0, proc.stderr
    got = read_recording(rrd)
    assert got["frames"] == [0, 1] and {"frame", "time"} <= set(got["timelines"])
    names = ("scan", "boxes/given", "boxes/used", "fused", "completion")
    assert got["entities"] == {f"/drive/{n}": 2 for n in names}
