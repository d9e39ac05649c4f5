"""A shape per track (``real complete --fuse all|past:K --track-shape``): one completion shown in every frame of a
track through that frame's box, a causal shape that never reads a later frame, tracks of boxes of several sizes
split, the command end to end and its refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spotlights.completion.frame import SceneConfig, complete_scene
from spotlights.completion.fusion import TrackPlan, usable_cpus
from spotlights.completion.shapes import SIZE_TOLERANCE, size_groups
from spotlights.data.real import open_reader
from spotlights.data.tracks import parse_window
from spotlights.errors import ParameterError
from spotlights.geometry.boxes import Box
from spotlights.geometry.io import load_ply_fields

from builders import write_drive
from helpers import run_cli

TIMES = [0.0, 0.5, 1.0, 1.5, 2.0]


class Shifted:
    """A completer whose output moves with the box's size: its input shifted by 0.05 along x, unit frame (so two
    frames' completions differ in metres when their boxes differ in size, unlike the input itself)."""

    model_name = "shifted"
    n_params = 0

    def complete(self, partials, **_):
        return [(np.asarray(p) + np.array([0.05, 0.0, 0.0], np.float32)).astype(np.float32) for p in partials]


def resize(folder, frame: int, track: str, scale: float) -> None:
    """Scale every side of track ``track``'s box in frame ``frame`` of a :func:`write_drive` folder."""
    path = folder / f"f{frame}.json"
    d = json.loads(path.read_text())
    for b in d["boxes"]:
        if b.get("track_id") == track:
            b["size"] = [s * scale for s in b["size"]]
    path.write_text(json.dumps(d))


def run_loop(src, window: str, track_shape: bool, refine: bool = False, completer=None, config=None, results=None):
    """The frame loop of ``real complete`` (in this process, no files): {(track id, position): the completion in
    the box frame of the track's (refined) box at that position (K, 3)}, and the plan (``completer``: default
    :class:`Shifted`; ``config``: default ``SceneConfig()``; ``results``, a list, receives each frame's result)."""
    completer = Shifted() if completer is None else completer
    config = SceneConfig() if config is None else config
    reader = open_reader(src, "generic")
    keys = reader.frame_keys()
    plan = TrackPlan(parse_window(window), config, refine=refine, track_shape=track_shape).build(reader, keys)
    out = {}
    for key in keys:
        frame = plan.take(key) or reader.load(key)
        boxes, extra = plan.frame_inputs(key, frame.boxes)
        result = complete_scene(frame.points, boxes, completer, config, extra_points=extra)
        if results is not None:
            results.append(result)
        plan.place_shapes(key, result)
        plan.record(key, result)
        for o in result.completed:
            tr, pos = plan.where[key][o.index]
            out[(tr.track_id, pos)] = tr.boxes[pos].to_object(o.completion)
    plan.finish()
    return out, plan


#: car a's box sides, per frame, x the drive's (the size noise of a detector); their median is frame 1's
SCALES = {0: 1.06, 1: 1.0, 2: 0.95, 3: 1.03, 4: 0.97}


def drive(tmp_path, sizes: dict | None = None, name: str = "drive"):
    """Five frames of two cars (tracks a and b, :func:`write_drive`); car a's box in frame k scaled by sizes[k]
    (default :data:`SCALES`: every frame's completion differs in metres)."""
    src = write_drive(tmp_path / name, TIMES)
    for k, scale in (sizes if sizes is not None else SCALES).items():
        resize(src, k, "a", scale)
    return src


def test_offline_shape_is_the_same_points_in_every_frame_box_frame(tmp_path):
    """``fuse all`` with a shape per track: every frame of a track shows the same points in its box frame, those
    of the first frame's completion (the whole track fused) in a box of the track's median size; without it the
    frames differ (the box sizes differ)."""
    src = drive(tmp_path)
    plain, _ = run_loop(src, "all", track_shape=False)
    shaped, plan = run_loop(src, "all", track_shape=True)
    # the first frame completed alone in a box of the median size (frame 1's): the same drive, that one box resized
    median = drive(tmp_path, {**SCALES, 0: SCALES[1]}, name="median")
    first_in_median, _ = run_loop(median, "all", track_shape=False)
    for tid in ("a", "b"):
        first = shaped[(tid, 0)]
        np.testing.assert_allclose(first, first_in_median[(tid, 0)], rtol=0, atol=1e-9)
        for pos in range(1, len(TIMES)):
            np.testing.assert_allclose(shaped[(tid, pos)], first, rtol=0, atol=1e-9)
    # car a's boxes differ in size: its plain completions differ by about 0.05 x the change of the half diagonal
    half = 0.5 * np.linalg.norm([4.2, 1.8, 1.5])
    assert np.abs(plain[("a", 1)] - plain[("a", 0)]).max() > 0.5 * 0.05 * 0.06 * half
    assert np.abs(first_in_median[("a", 0)] - plain[("a", 0)]).max() > 0.5 * 0.05 * 0.06 * half
    summ = plan.summary()
    assert summ["track_shape"] == "offline" and summ["size_tolerance"] == SIZE_TOLERANCE
    assert [t["shape_made_at"] for t in summ["tracks"]] == [[0], [0]]
    assert [t["split_from"] for t in summ["tracks"]] == [None, None]


def test_with_fit_the_shape_is_fitted_to_the_whole_track(tmp_path):
    """``--fit`` with a shape per track: the frame that makes the shape fits its completion to the fused track
    (the gate keeps a fit only where it comes closer to the input), every frame shows that one fitted shape, and it
    differs from the unfitted shape where the fit was kept."""
    pytest.importorskip("torch")
    from spotlights.learning.inference import load_completer

    model = load_completer("default", device="cpu")
    src = drive(tmp_path)
    made: list = []
    fitted, _ = run_loop(src, "all", True, completer=model, config=SceneConfig(fit=True), results=made)
    plain, _ = run_loop(src, "all", True, completer=model)
    first = {o.box.track_id: o for o in made[0].completed}
    kept = [tid for tid in ("a", "b") if first[tid].fitted]
    assert kept  # the drive's cars are fitted at the frame that makes their shapes
    for tid in ("a", "b"):
        for pos in range(1, len(TIMES)):
            np.testing.assert_allclose(fitted[(tid, pos)], fitted[(tid, 0)], rtol=0, atol=1e-9)
    for tid in kept:
        assert fitted[(tid, 0)].shape != plain[(tid, 0)].shape or not np.allclose(fitted[(tid, 0)], plain[(tid, 0)])


def test_offline_shape_follows_the_refined_boxes(tmp_path):
    """With box refinement the shape is the same points in every frame's refined box frame."""
    src = drive(tmp_path)
    shaped, plan = run_loop(src, "all", track_shape=True, refine=True)
    for tid in ("a", "b"):
        for pos in range(1, len(TIMES)):
            np.testing.assert_allclose(shaped[(tid, pos)], shaped[(tid, 0)], rtol=0, atol=1e-9)
    assert plan.summary()["refine_boxes"] is True


def test_causal_shape_never_uses_a_later_frame(tmp_path):
    """``past:2``: shapes made at positions 0, 2, 4 (every 2 frames), shown unchanged in between; changing the
    last frame's points changes the last shape and no earlier frame's."""
    src = drive(tmp_path)
    before, plan = run_loop(src, "past:2", track_shape=True)
    assert [t["shape_made_at"] for t in plan.summary()["tracks"]] == [[0, 2, 4], [0, 2, 4]]
    for tid in ("a", "b"):
        np.testing.assert_allclose(before[(tid, 1)], before[(tid, 0)], rtol=0, atol=1e-9)
        np.testing.assert_allclose(before[(tid, 3)], before[(tid, 2)], rtol=0, atol=1e-9)
    # the last frame's points of car a: moved 0.2 m up inside its box (another shape from its past:2 window)
    scan = np.load(src / "f4.npy")
    box = json.loads((src / "f4.json").read_text())["boxes"][0]
    inside = np.all(np.abs(scan - box["center"]) <= np.array(box["size"]) / 2 + 0.2, axis=1)
    scan[inside, 0] += 0.3
    np.save(src / "f4.npy", scan)
    after, _ = run_loop(src, "past:2", track_shape=True)
    for pos in range(4):
        assert np.array_equal(after[("a", pos)], before[("a", pos)]), pos
    assert after[("a", 4)].shape != before[("a", 4)].shape or not np.allclose(after[("a", 4)], before[("a", 4)])


def test_size_groups_by_hand():
    """Frames join the first group whose running median size is within the tolerance on every side."""
    sizes = [[4.0, 2.0, 1.5], [4.1, 2.0, 1.5], [6.0, 2.0, 1.5], [4.0, 2.0, 1.5], [6.1, 2.0, 1.5], [4.0, 2.0, 1.9]]
    # medians: group 0 {4.0}, {4.0, 4.1} -> 4.05; 6.0 is 48% off -> group 1; 1.9 / 1.5 = 1.27 > 1.2 -> group 2
    assert size_groups(np.array(sizes)).tolist() == [0, 0, 1, 0, 1, 2]
    assert size_groups(np.array([[5.0, 2, 1.5], [6.0, 2, 1.5]]), tolerance=0.2).tolist() == [0, 0]  # 6 / 5 = 1.2
    assert size_groups(np.array([[5.0, 2, 1.5], [6.01, 2, 1.5]]), tolerance=0.2).tolist() == [0, 1]
    with pytest.raises(ParameterError, match="tolerance"):
        size_groups(np.ones((2, 3)), tolerance=-1)


def test_a_track_of_two_sizes_is_split_and_flagged(tmp_path):
    """Car a's box 1.5x larger in frames 2 and 3: two tracks (a: frames 0, 1, 4; a-size2: frames 2, 3), each with
    its own shape, listed with split_from; never one shape over both sizes."""
    src = drive(tmp_path, sizes={2: 1.5, 3: 1.5})
    shaped, plan = run_loop(src, "all", track_shape=True)
    summ = plan.summary()
    rows = {t["track_id"]: t for t in summ["tracks"]}
    assert set(rows) == {"a", "a-size2", "b"}
    assert summ["n_size_splits"] == 1
    assert rows["a"]["split_from"] == "a" and rows["a"]["size_group"] == 1
    assert rows["a-size2"]["split_from"] == "a" and rows["a-size2"]["size_group"] == 2
    assert [r["frame_id"] for r in rows["a"]["frames"]] == ["f0", "f1", "f4"]
    assert [r["frame_id"] for r in rows["a-size2"]["frames"]] == ["f2", "f3"]
    np.testing.assert_allclose(shaped[("a", 2)], shaped[("a", 0)], rtol=0, atol=1e-9)  # frame f4
    np.testing.assert_allclose(shaped[("a-size2", 1)], shaped[("a-size2", 0)], rtol=0, atol=1e-9)
    # each shape is its own group's: the car's front face (x = 2.1 m) moved by 0.05 x the maker's half diagonal
    half = 0.5 * np.linalg.norm([4.2, 1.8, 1.5])
    assert shaped[("a", 0)][:, 0].max() == pytest.approx(2.1 + 0.05 * half, abs=0.01)
    assert shaped[("a-size2", 0)][:, 0].max() == pytest.approx(2.1 + 0.05 * 1.5 * half, abs=0.01)


def test_a_window_without_a_shape_per_track_is_refused():
    with pytest.raises(ParameterError, match="track_shape"):
        TrackPlan(parse_window("centered:3"), SceneConfig(), track_shape=True)


def _completion_in_box(ply, box: dict, obj: int) -> np.ndarray:
    f = load_ply_fields(ply)
    xyz = np.stack([f["x"], f["y"], f["z"]], axis=1).astype(np.float64)
    pts = xyz[(f["source"] == 2) & (f["object"] == obj)]
    return Box(box["center"], box["size"], yaw=box["yaw"]).to_object(pts)


def _rows(a: np.ndarray) -> np.ndarray:
    return a[np.lexsort(a.T[::-1])]


@pytest.mark.timeout(300)
@pytest.mark.parametrize("worker", ["--track-worker", "--no-track-worker"])
def test_the_command_writes_one_shape_per_track(tmp_path, worker):
    """``real complete --fuse all --track-shape`` on a tiny drive (the track worker process on, where two CPUs are
    usable, and off): every frame's scene PLY shows car a's one shape through its box, and tracks/a.ply holds it."""
    pytest.importorskip("torch")
    from learning_fixtures import make_checkpoint

    src = drive(tmp_path)
    ck = make_checkpoint(tmp_path / "tiny.pt", "pcn")  # a point-set model: never empty
    out = tmp_path / "out"
    proc = run_cli(
        "real", "complete", src, "--format", "generic", "-c", ck, "--out", out, "--fuse", "all", "--track-shape",
        "--no-pictures", "-q", *([worker] if worker == "--no-track-worker" else []),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    tracks = json.loads((out / "tracks.json").read_text())
    assert tracks["track_shape"] == "offline" and tracks["n_size_splits"] == 0
    shapes = []
    for k in range(len(TIMES)):
        box = json.loads((src / f"f{k}.json").read_text())["boxes"][0]  # car a: object 0
        shapes.append(_rows(_completion_in_box(out / "drive" / f"f{k}.ply", box, 0)))
    assert len(shapes[0]) > 0
    for s in shapes[1:]:
        np.testing.assert_allclose(s, shapes[0], rtol=0, atol=1e-5)  # float32 PLY coordinates
    f = load_ply_fields(out / "drive" / "tracks" / "a.ply")
    track = np.stack([f["x"], f["y"], f["z"]], axis=1)[f["source"] == 2].astype(np.float64)
    np.testing.assert_allclose(_rows(track), shapes[0], rtol=0, atol=1e-5)


@pytest.mark.parametrize(
    "extra, needs",
    [
        ([], "--fuse"),  # nothing fused
        (["--fuse", "centered:3"], "--fuse all"),  # neither the whole track nor the past only
    ],
)
def test_bad_combinations_give_one_line_and_exit_2(tmp_path, extra, needs):
    src = write_drive(tmp_path / "drive", TIMES[:3])
    out = tmp_path / "out"
    proc = run_cli("real", "complete", src, "--format", "generic", "--out", out, "--track-shape", "-q", *extra)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(err) == 1 and "Traceback" not in proc.stderr and "--track-shape" in err[0] and needs in err[0], err
    assert not out.exists()


def test_one_scan_refuses_a_shape_per_track(tmp_path):
    src = write_drive(tmp_path / "drive", TIMES[:1])
    out = tmp_path / "one.ply"
    proc = run_cli("complete", src / "f0.npy", "--boxes", src / "f0.json", "--out", out, "--track-shape")
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1 and "--track-shape" in err[0], proc.stderr
    assert not out.exists()


@pytest.mark.timeout(300)
def test_resume_keeps_the_shape_of_a_skipped_frame(tmp_path):
    """``--resume`` after the last frame's files were lost: the first frame (which makes every track's shape) is
    skipped, completed again in memory, and the last frame shows the same shape as in one run (same PLY bytes)."""
    pytest.importorskip("torch")
    from learning_fixtures import make_checkpoint

    src = drive(tmp_path)
    ck = make_checkpoint(tmp_path / "tiny.pt", "pcn")
    out = tmp_path / "out"
    args = ("real", "complete", src, "--format", "generic", "-c", ck, "--out", out, "--fuse", "all", "--track-shape")
    args += ("--no-pictures", "-q", "--no-track-worker")
    assert run_cli(*args).returncode == 0
    last, track = out / "drive" / "f4.ply", out / "drive" / "tracks" / "a.ply"
    before = last.read_bytes(), track.read_bytes()
    (out / "drive" / "f4.json").unlink()
    last.unlink()
    proc = run_cli(*args, "--resume")
    assert proc.returncode == 0, proc.stderr
    assert json.loads((out / "summary.json").read_text())["totals"]["resumed"] == 4
    assert (last.read_bytes(), track.read_bytes()) == before


@pytest.mark.timeout(300)
def test_complete_scene_takes_a_shape_per_track(tmp_path):
    """``spotlights complete SCENE --fuse past:2 --track-shape`` (a multi-frame generic scene): the causal shapes,
    made at positions 0, 2 and 4 of each track."""
    pytest.importorskip("torch")
    from learning_fixtures import make_checkpoint

    src = drive(tmp_path)
    ck = make_checkpoint(tmp_path / "tiny.pt", "pcn")
    out = tmp_path / "out"
    proc = run_cli("complete", src, "-c", ck, "--out", out, "--fuse", "past:2", "--track-shape", "-q")
    assert proc.returncode == 0, proc.stderr
    tracks = json.loads((out / "tracks.json").read_text())
    assert tracks["track_shape"] == "causal"
    assert [t["shape_made_at"] for t in tracks["tracks"]] == [[0, 2, 4], [0, 2, 4]]


@pytest.mark.timeout(300)
@pytest.mark.skipif(usable_cpus() < 2, reason="a worker process is started with 2+ usable CPUs only")
def test_the_track_worker_gives_the_same_shapes(tmp_path):
    """``--fuse all --refine-boxes --track-shape`` with the track worker process (where two CPUs are usable) and in
    one process: the same scene and track PLYs, byte for byte (the making frames are cropped again in the track's
    median size on both paths)."""
    pytest.importorskip("torch")
    from learning_fixtures import make_checkpoint

    src = drive(tmp_path)
    # points 2.3 m ahead of car a's centre in frame 0: inside its own box grown by the margin (1.06 x 4.2 m long),
    # outside the median-size box's (4.2 m) that frame is completed in
    scan = np.load(src / "f0.npy")
    box = json.loads((src / "f0.json").read_text())["boxes"][0]
    ahead = np.random.default_rng(1).uniform(-0.3, 0.3, (60, 3)) * [0, 1, 1] + [2.3, 0, 0] + box["center"]
    np.save(src / "f0.npy", np.concatenate([scan, ahead]).astype(np.float32))
    ck = make_checkpoint(tmp_path / "tiny.pt", "pcn")
    outs = []
    for name, flags in (("worker", ()), ("alone", ("--no-track-worker",))):
        out = tmp_path / name
        proc = run_cli(
            "real", "complete", src, "--format", "generic", "-c", ck, "--out", out, "--fuse", "all",
            "--refine-boxes", "--track-shape", "--no-pictures", "-q", *flags,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        outs.append({p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*.ply"))})
    assert len(outs[0]) == len(TIMES) + 2 and outs[0] == outs[1]
