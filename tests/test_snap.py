"""Snapping the SA-Nets' rays to the observed points (geometry.evidence.snap_to_observed, ``--snap R``): against
closed forms (a ray meeting a plane, a point's foot on a line, a plane's normal), then through the completers
(torch and onnxruntime alike), the scene completion, the evaluations and the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spotlights.errors import ParameterError
from spotlights.geometry.boxes import unit_extents
from spotlights.geometry.evidence import (
    SNAP_MIN_COSINE,
    EvidenceParams,
    near_ray_evidence,
    point_normals,
    snap_to_observed,
)
from spotlights.geometry.rig import RigSpec

torch = pytest.importorskip("torch")

from helpers import assert_user_error, run_cli  # noqa: E402
from learning_fixtures import cli, make_checkpoint, one_torch_thread  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)

SPEC = RigSpec.from_name("box-16x64-ellipsoid-s1")
E = unit_extents([4.6, 1.9, 1.6])


def rays():
    rig = SPEC.for_box(E)
    return np.array(rig.origins, dtype=np.float64), np.array(rig.directions, dtype=np.float64)


def side_points(k=400, seed=0, x=None):
    """``k`` points on the plane y = 0.8 e_y (a car's left side), spread over the side's x-z extent."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-1, 1, (k, 3)) * E * [0.9, 1.0, 0.9]
    p[:, 1] = 0.8 * E[1]
    return p


def test_normals_of_points_on_a_plane_are_the_plane_normal():
    p = side_points(200)
    n = point_normals(p)
    assert n.shape == p.shape
    assert np.allclose(np.abs(n[:, 1]), 1.0, atol=1e-9)  # the normal of y = c is +-y
    assert np.array_equal(point_normals(p[:2]), np.zeros((2, 3)))  # fewer than 3 points: no plane


def test_snapped_rays_meet_the_observed_plane_exactly_and_the_others_keep_the_network():
    o, d = rays()
    p = side_points()
    r = 0.05
    depth = np.full(len(o), 0.3)
    keep = np.arange(len(o)) % 2 == 0
    dep, kp, snapped = snap_to_observed(p, o, d, SPEC.n_secondary, depth, keep, r)
    ev = near_ray_evidence(p, o, d, SPEC.n_secondary, EvidenceParams(radius=r))
    assert np.array_equal(snapped, ev["count"] > 0)  # the rays with a counted candidate (tested by brute force)
    assert 50 < snapped.sum() < len(o)
    # the rays without evidence keep the network's depth and hit
    assert np.array_equal(dep[~snapped], depth[~snapped]) and np.array_equal(kp[~snapped], keep[~snapped])
    assert kp[snapped].all()
    # a snapped ray that faces the plane meets it where the closed form says: o_y + 2 t d_y = c
    c = 0.8 * E[1]
    facing = snapped & (np.abs(d[:, 1]) >= SNAP_MIN_COSINE)
    t_plane = (c - o[:, 1]) / (2.0 * np.where(facing, d[:, 1], 1.0))
    pt = o + 2.0 * dep[:, None] * d
    near = facing & (np.abs(dep - t_plane) < 1e-9)
    assert near.sum() > 0.8 * facing.sum()  # the others met the plane farther than r from their point: foot
    assert np.allclose(pt[near, 1], c, atol=1e-9)
    # every snapped point is within r of the plane's observed points (the foot of a point is within r of it)
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(p).query(pt[snapped])
    assert dist.max() <= 2 * r + 1e-9


def test_a_lone_point_snaps_the_rays_to_its_foot():
    o, d = rays()
    x = np.array([[0.2, 0.8 * E[1], 0.05]])
    dep, kp, snapped = snap_to_observed(x, o, d, SPEC.n_secondary, np.zeros(len(o)), np.zeros(len(o), bool), 0.08)
    assert snapped.any()
    foot = 0.5 * np.einsum("rj,rj->r", x - o, d)  # (x - o) . d / 2: the point's depth along each ray
    assert np.allclose(dep[snapped], foot[snapped], atol=1e-12)
    line = o + 2 * dep[:, None] * d
    assert np.linalg.norm(line[snapped] - x, axis=1).max() <= 0.08 + 1e-12
    assert kp.sum() == snapped.sum()


def test_snap_inputs_are_checked_and_no_points_change_nothing():
    o, d = rays()
    dep, keep = np.full(len(o), 0.4), np.ones(len(o), bool)
    with pytest.raises(ValueError, match="radius"):
        snap_to_observed(side_points(), o, d, SPEC.n_secondary, dep, keep, 0.0)
    with pytest.raises(ValueError, match="rays"):
        snap_to_observed(side_points(), o, d, SPEC.n_secondary, dep[:-1], keep, 0.05)
    a, b, s = snap_to_observed(np.zeros((0, 3)), o, d, SPEC.n_secondary, dep, keep, 0.05)
    assert np.array_equal(a, dep) and np.array_equal(b, keep) and not s.any()
    # repeats (a resampled input) do not change the result
    p = side_points(100)
    a1 = snap_to_observed(p, o, d, SPEC.n_secondary, dep, keep, 0.05)
    a2 = snap_to_observed(np.concatenate([p, p[:50]]), o, d, SPEC.n_secondary, dep, keep, 0.05)
    assert all(np.array_equal(u, v) for u, v in zip(a1, a2))


def test_a_ray_does_not_snap_through_its_predicted_surface_unless_the_lidar_saw_through_it():
    """The left side (y = +c) observed; the network draws the right side (y = -c). A ray entering from the right
    passes its predicted right side, then the observed left side: it keeps its prediction when the LiDAR stood on
    the left (the right side hidden from it), and snaps when the LiDAR stood on the right (it saw through there)."""
    o, d = rays()
    p = side_points(2000)  # dense: every cell of the LiDAR's grid over the side holds a point
    c, r = 0.8 * E[1], 0.05
    t_right = (-c - o[:, 1]) / (2.0 * np.where(d[:, 1] > 0, d[:, 1], 1.0))  # where they meet y = -c (closed form)
    cross = o + 2.0 * t_right[:, None] * d
    # rays entering from the right (y < 0) toward +y that meet the drawn right side within the observed side's
    # x-z extent (elsewhere the LiDAR saw nothing behind it, so nothing there is carved)
    rightward = (d[:, 1] > SNAP_MIN_COSINE) & (t_right > 0) & np.all(np.abs(cross[:, [0, 2]]) < 0.6 * E[[0, 2]], axis=1)
    depth = np.where(rightward, t_right, 0.3)
    keep = rightward.copy()
    base = snap_to_observed(p, o, d, SPEC.n_secondary, depth, keep, r)  # no sensor: no occlusion rule
    through = rightward & base[2]  # rightward rays snapped (onto the left side, 2c = 0.6 beyond the right)
    assert through.sum() > 20 and np.all(2.0 * (base[0][through] - depth[through]) > r)
    left = snap_to_observed(p, o, d, SPEC.n_secondary, depth, keep, r, sensor=np.array([0.0, 3.0, 0.0]))
    assert np.array_equal(left[0][through], depth[through]) and left[1][through].all() and not left[2][through].any()
    others = ~through  # every other ray as without the rule
    assert all(np.array_equal(a[others], b[others]) for a, b in zip(left, base))
    right = snap_to_observed(p, o, d, SPEC.n_secondary, depth, keep, r, sensor=np.array([0.0, -3.0, 0.0]))
    seen_through = np.abs(right[0][through] - base[0][through]) == 0
    assert seen_through.mean() > 0.9, seen_through.mean()  # the right side was carved: snapped onto the left
    # a sensor unknown or at the centre applies no rule; the carving uses the points seen, not the snap targets
    for unknown in (np.full(3, np.nan), np.zeros(3)):  # unknown, or at the box's centre (an object-frame scan)
        got = snap_to_observed(p, o, d, SPEC.n_secondary, depth, keep, r, sensor=unknown)
        assert all(np.array_equal(a, b) for a, b in zip(got, base))
    far = side_points(2000) + [0.0, -10.0, 0.0]  # "seen" points nowhere near: nothing carved, every such ray kept
    unseen = snap_to_observed(p, o, d, SPEC.n_secondary, depth, keep, r, sensor=np.array([0.0, -3.0, 0.0]), seen=far)
    assert np.array_equal(unseen[0][through], depth[through])


@pytest.fixture(scope="module")
def hit_ckpt(tmp_path_factory):
    return make_checkpoint(tmp_path_factory.mktemp("snap") / "hit.pt", "sanet-hit", rig=SPEC)


def _scans(n=3):
    s = np.stack([side_points(256, seed=i) for i in range(n)]).astype(np.float32)
    return s, np.broadcast_to(E, (n, 3))


def test_the_completer_snaps_only_when_asked_and_onto_the_scan(hit_ckpt):
    from spotlights.learning.inference import load_completer

    c = load_completer(hit_ckpt, device="cpu")
    x, e = _scans()
    plain = c.complete(x, extents=e)
    again = c.complete(x, extents=e, snap=None)
    assert all(np.array_equal(a, b) for a, b in zip(plain, again))
    snapped = c.complete(x, extents=e, snap=0.05)
    for a, b in zip(plain, snapped):
        on_side = lambda q: np.mean(np.abs(q[:, 1] - 0.8 * E[1]) < 1e-5)  # noqa: E731
        assert on_side(b) > on_side(a) + 0.05  # an untrained net does not draw that side; the snap does
    # other observed points than the input: the snap follows them
    other = [side_points(300, seed=9) * [1, -1, 1] for _ in range(3)]  # the right side instead
    mirrored = c.complete(x, extents=e, snap=0.05, observed=other)
    assert all(np.mean(np.abs(q[:, 1] + 0.8 * E[1]) < 1e-5) > 0.05 for q in mirrored)
    with pytest.raises(ParameterError, match="radius"):
        c.complete(x, extents=e, snap=-0.1)
    with pytest.raises(ParameterError, match="`observed` point sets"):
        c.complete(x, extents=e, snap=0.05, observed=other[:2])
    with pytest.raises(ParameterError, match="`seen` point sets"):
        c.complete(x, extents=e, snap=0.05, seen=other[:2])
    with pytest.raises(ParameterError, match="go with a snap radius"):
        c.complete(x, extents=e, seen=other)
    # what the LiDAR saw decides the rule: seen far away carves nothing, so more snaps are refused than with x
    sensors = np.broadcast_to([0.0, -3.0, 0.5], (len(x), 3))
    near = c.complete(x, extents=e, snap=0.05, sensor_origins=sensors)
    far = c.complete(x, extents=e, snap=0.05, sensor_origins=sensors, seen=[p + [0.0, 0.0, 9.0] for p in x])
    assert any(len(a) != len(b) or not np.array_equal(a, b) for a, b in zip(near, far))


def test_a_point_model_refuses_to_snap(tmp_path):
    from spotlights.learning.inference import load_completer

    c = load_completer(make_checkpoint(tmp_path / "pcn.pt", "pcn"), device="cpu")
    with pytest.raises(ParameterError, match="no rays to snap"):
        c.complete(_scans()[0], snap=0.05)
    # in a scene: refused as the main model; as a --fallback it completes its boxes unsnapped (an SA-Net snaps)
    from spotlights.completion.frame import SceneConfig, complete_scene, snap_options
    from spotlights.geometry.boxes import Box

    scan = np.random.default_rng(0).uniform(-1, 1, (400, 3)) * [2.0, 0.9, 0.7] + [10.0, 2.0, 0.8]
    box = Box(center=np.array([10.0, 2.0, 0.8]), size=np.array([4.6, 1.9, 1.6]), yaw=0.0, cls="car")
    with pytest.raises(ParameterError, match="pcn has no rays to snap"):
        complete_scene(scan, [box], c, SceneConfig(crop=False, any_label=True, snap=0.05))
    cfg = SceneConfig(snap=0.05, snap_mirror=True)
    assert snap_options(c, cfg.snap, cfg.snap_mirror) == {"snap": None, "snap_mirror": False}
    sanet = load_completer(make_checkpoint(tmp_path / "hit.pt", "sanet-hit", rig=SPEC), device="cpu")
    assert snap_options(sanet, cfg.snap, cfg.snap_mirror) == {"snap": 0.05, "snap_mirror": True}
    assert snap_options(sanet, 0.0, False) == {"snap": None, "snap_mirror": False}


def test_complete_refuses_snap_for_a_point_model_before_any_work(tmp_path, capsys):
    np.save(tmp_path / "scan.npy", np.random.default_rng(0).uniform(-1, 1, (300, 3)) + [10.0, 2.0, 0.8])
    pcn = make_checkpoint(tmp_path / "pcn.pt", "pcn")
    bad = cli(
        capsys, "complete", tmp_path / "scan.npy", "--center", "10", "2", "0.8", "--size", "4.6", "1.9", "1.6",
        "--no-crop", "--checkpoint", pcn, "--snap", "0.05", "--out", tmp_path / "x.npy",
    )  # fmt: skip
    assert_user_error(bad, "has no rays to snap")
    assert not (tmp_path / "x.npy").exists()


def test_onnxruntime_snaps_like_torch(tmp_path, hit_ckpt):
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnxscript")
    from spotlights.learning.export import export_onnx, load_onnx_completer
    from spotlights.learning.inference import load_completer

    onx = load_onnx_completer(export_onnx(hit_ckpt, tmp_path / "hit.onnx"))
    ref = load_completer(hit_ckpt, device="cpu")
    x, e = _scans()
    half = np.broadcast_to(E + 0.03, (len(x), 3))
    sensors = np.broadcast_to([0.0, 3.0, 0.5], (len(x), 3))  # the occlusion rule, in both runtimes
    for kw in (
        {"snap": 0.05},
        {"snap": 0.05, "box_half": half},
        {"snap": 0.08, "snap_mirror": True},
        {"snap": 0.08, "snap_mirror": True, "sensor_origins": sensors},
    ):
        a = ref.complete(x, extents=e, **kw)
        b = onx.complete(x, extents=e, **kw)
        if "sensor_origins" in kw:  # the rule ran: not the output without the sensor
            plain = ref.complete(x, extents=e, **{k: v for k, v in kw.items() if k != "sensor_origins"})
            assert any(len(p) != len(q) or not np.array_equal(p, q) for p, q in zip(a, plain))
        assert [len(p) for p in a] == [len(p) for p in b]
        assert max(float(np.abs(p - q).max()) for p, q in zip(a, b)) < 1e-4
        if kw.get("snap_mirror"):
            assert all(np.mean(np.abs(q[:, 1] + 0.8 * E[1]) < 1e-4) > 0.05 for q in b)  # the mirrored side, drawn


@pytest.mark.parametrize(
    "value, radius", [(None, None), (0, None), (0.0, None), (0.05, 0.05), (np.float32(0.5), 0.5), (np.int64(1), 1.0)]
)
def test_snap_radius_reads_off_and_radii(value, radius):
    from spotlights.geometry.evidence import snap_radius

    assert snap_radius(value) == (None if radius is None else pytest.approx(radius))


@pytest.mark.parametrize("value", [-0.1, float("nan"), float("inf"), -float("inf"), "abc", "0.08", True, [0.1, 0.2]])
def test_snap_radius_refuses_other_values_naming_the_option(value):
    from spotlights.geometry.evidence import snap_radius

    with pytest.raises(ParameterError, match=r"^`snap`: the snap radius must be a finite number > 0"):
        snap_radius(value)
    with pytest.raises(ParameterError, match=r"^`snap`: the snap radius"):
        snap_radius(value, option="snap")


def test_every_surface_checks_the_snap_radius_and_mirror_alike():
    """SceneConfig (complete, real complete, the API), RealEvaluationSettings (real evaluate) and the completer's
    own check answer the same values with the same messages (one owner: geometry.evidence.snap_radius)."""
    from spotlights.completion.frame import SceneConfig
    from spotlights.experiments.real_evaluation import RealEvaluationSettings

    for make in (lambda **k: SceneConfig(**k), lambda **k: RealEvaluationSettings(heading_check=False, **k)):
        for bad in (-1.0, float("inf")):
            with pytest.raises(ParameterError, match=r"^`snap`: the snap radius must be a finite number > 0"):
                make(snap=bad)
        with pytest.raises(ParameterError, match="^`snap_mirror` goes with `snap` R$"):
            make(snap=0.0, snap_mirror=True)
        assert make(snap=0.0).snap == 0.0 and make(snap=0.05, snap_mirror=True).snap_mirror
        assert make(snap=None).snap == 0.0  # off
        for bad in ("0.5", True):  # text and booleans are not radii (were a raw TypeError further on)
            with pytest.raises(ParameterError, match=r"^`snap`: the snap radius must be a finite number > 0"):
                make(snap=bad)


def test_scene_options_and_real_evaluation_refuse_snap_with_the_heading_check():
    from spotlights.completion.frame import SceneConfig
    from spotlights.experiments.real_evaluation import RealEvaluationSettings

    assert SceneConfig(snap=0.05).snap == 0.05
    for bad in (-0.1, float("nan")):
        with pytest.raises(ParameterError, match="snap radius"):
            SceneConfig(snap=bad)
    with pytest.raises(ParameterError, match="`heading_check`"):
        SceneConfig(snap=0.05, heading_check=True)
    with pytest.raises(ParameterError, match="`no_heading_check`"):
        RealEvaluationSettings(snap=0.05)
    assert RealEvaluationSettings(snap=0.05, heading_check=False).snap == 0.05


def test_complete_snap_from_the_command_line(tmp_path, capsys, hit_ckpt):
    rng = np.random.default_rng(0)
    side = rng.uniform(-1, 1, (600, 3)) * [2.0, 0.0, 0.7] + [10.0, 2.0 + 0.85, 0.8]  # a car's left side, y = 2.85
    np.save(tmp_path / "scan.npy", side)
    box = ["--center", "10", "2", "0.8", "--size", "4.6", "1.9", "1.6", "--no-crop", "--checkpoint", hit_ckpt]
    out = {}
    for name, extra in (("plain", []), ("snap", ["--snap", "0.05"])):
        res = cli(
            capsys, "complete", tmp_path / "scan.npy", *box, *extra, "--no-keep-observed",
            "--out", tmp_path / f"{name}.npy", "--summary", tmp_path / f"{name}.json", "-q",
        )  # fmt: skip
        assert res.returncode == 0, res.stderr
        out[name] = (np.load(tmp_path / f"{name}.npy"), json.loads((tmp_path / f"{name}.json").read_text()))
    assert out["plain"][1]["config"]["snap"] == 0.0 and out["snap"][1]["config"]["snap"] == 0.05
    on_side = lambda q: np.mean(np.abs(q[:, 1] - 2.85) < 1e-3)  # noqa: E731 - scan frame, metres
    assert on_side(out["snap"][0]) > on_side(out["plain"][0]) + 0.05
    assert out["snap"][1]["objects"][0]["fidelity"] < out["plain"][1]["objects"][0]["fidelity"]
    bad = cli(capsys, "complete", tmp_path / "scan.npy", *box, "--snap", "0.05", "--heading-check",
              "--out", tmp_path / "x.npy")  # fmt: skip
    assert_user_error(bad, "--heading-check")
    assert not (tmp_path / "x.npy").exists()
    neg = run_cli(
        "complete", str(tmp_path / "scan.npy"), *map(str, box), "--snap", "-1", "--out", str(tmp_path / "y.npy")
    )
    assert neg.returncode == 2 and "argument --snap" in neg.stderr and "Traceback" not in neg.stderr


def test_evaluate_names_the_snapped_rows(tmp_path, hit_ckpt):
    from spotlights.learning.evaluate import evaluate_checkpoint

    from learning_fixtures import tiny_dataset_path

    data = tiny_dataset_path(tmp_path / "data")
    ck = make_checkpoint(tmp_path / "cap.pt", "sanet-hit")
    res = evaluate_checkpoint(ck, data, progress=False, snap=0.05)
    assert res["snap"] == 0.05 and all("snap 0.05" in r["variant"] for r in res["rows"])
    both = evaluate_checkpoint(ck, data, progress=False, snap=0.05, snap_mirror=True)
    assert both["snap_mirror"] and all(r["variant"].endswith("snap 0.05 mirrored") for r in both["rows"])
    with pytest.raises(ParameterError, match="`snap_mirror` goes with `snap` R"):
        evaluate_checkpoint(ck, data, progress=False, snap_mirror=True)
    plain = evaluate_checkpoint(ck, data, progress=False)
    assert plain["snap"] is None and not any("snap" in r["variant"] for r in plain["rows"])
    assert res["rows"][0]["summary"] != plain["rows"][0]["summary"]


def test_resume_reuses_frames_written_before_snap_existed(tmp_path):
    from dataclasses import asdict

    from spotlights.completion.frame import SceneConfig
    from spotlights.completion.frame_selection import done_frame

    cfg = asdict(SceneConfig())
    cfg["clip"] = str(cfg["clip"])
    old = {k: v for k, v in cfg.items() if k not in ("snap", "snap_mirror")}  # a frame of a run before --snap
    f = tmp_path / "frame.json"
    f.write_text(json.dumps({"model": "sanet-hit", "checkpoint": "default", "config": old}))
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is not None
    assert done_frame(f, SceneConfig(snap=0.05), "sanet-hit", "default") is None  # snapping: computed again
    assert done_frame(f, SceneConfig(snap=0.05, snap_mirror=True), "sanet-hit", "default") is None


def test_mirrored_snapping_draws_the_side_the_lidar_did_not_see(hit_ckpt):
    from spotlights.learning.inference import load_completer, mirrored

    p = np.array([[0.1, 0.2, 0.3], [-0.4, 0.5, 0.0]], dtype=np.float32)
    m = mirrored(p)
    want = np.array([[0.1, 0.2, 0.3], [-0.4, 0.5, 0.0], [0.1, -0.2, 0.3], [-0.4, -0.5, 0.0]], dtype=np.float32)
    assert m.dtype == np.float32 and np.array_equal(m, want)
    c = load_completer(hit_ckpt, device="cpu")
    x, e = _scans()  # the left side (y = +0.8 e_y) only
    right = lambda q: np.mean(np.abs(q[:, 1] + 0.8 * E[1]) < 1e-5)  # noqa: E731 - the unseen side
    plain = c.complete(x, extents=e, snap=0.05)
    both = c.complete(x, extents=e, snap=0.05, snap_mirror=True)
    for a, b in zip(plain, both):
        assert right(a) == 0.0 and right(b) > 0.05
    with pytest.raises(ParameterError, match="`snap_mirror`, `observed` and `seen` go with"):
        c.complete(x, extents=e, snap_mirror=True)


def test_snap_mirror_needs_a_radius_everywhere(tmp_path, capsys, hit_ckpt):
    from spotlights.completion.frame import SceneConfig
    from spotlights.experiments.real_evaluation import RealEvaluationSettings

    assert SceneConfig(snap=0.08, snap_mirror=True).snap_mirror
    with pytest.raises(ParameterError, match="`snap_mirror` goes with `snap` R"):
        SceneConfig(snap_mirror=True)
    with pytest.raises(ParameterError, match="`snap_mirror` goes with `snap` R"):
        RealEvaluationSettings(snap_mirror=True, heading_check=False)
    np.save(tmp_path / "scan.npy", side_points(300) * 2.5 + [10.0, 2.0, 0.8])
    box = ["--center", "10", "2", "0.8", "--size", "4.6", "1.9", "1.6", "--no-crop", "--checkpoint", hit_ckpt]
    bad = cli(capsys, "complete", tmp_path / "scan.npy", *box, "--snap-mirror", "--out", tmp_path / "x.npy")
    assert_user_error(bad, "--snap-mirror goes with --snap R")
    ok = cli(capsys, "complete", tmp_path / "scan.npy", *box, "--snap", "0.05", "--snap-mirror",
             "--out", tmp_path / "y.npy", "--summary", tmp_path / "y.json", "-q")  # fmt: skip
    assert ok.returncode == 0, ok.stderr
    assert json.loads((tmp_path / "y.json").read_text())["config"]["snap_mirror"] is True


def test_evaluate_scores_a_point_model_unsnapped_beside_a_snapped_sanet(tmp_path, hit_ckpt):
    from spotlights.learning.evaluate import evaluate_checkpoint

    from learning_fixtures import tiny_dataset_path

    data = tiny_dataset_path(tmp_path / "data")
    pcn = evaluate_checkpoint(make_checkpoint(tmp_path / "pcn.pt", "pcn"), data, progress=False, snap=0.05)
    assert pcn["snap"] is None and not any("snap" in r["variant"] for r in pcn["rows"])
    with pytest.raises(ParameterError, match="snap radius"):
        evaluate_checkpoint(make_checkpoint(tmp_path / "cap.pt", "sanet-hit"), data, progress=False, snap=float("nan"))


def test_evaluate_snap_from_the_command_line(tmp_path, capsys):
    from learning_fixtures import tiny_dataset_path

    data = tiny_dataset_path(tmp_path / "data")
    ck = make_checkpoint(tmp_path / "cap.pt", "sanet-hit")
    res = cli(capsys, "evaluate", "--data", data, "--checkpoint", ck, "--snap", "0.05", "--snap-mirror",
              "--examples", "0", "--out", tmp_path / "rep", "-q")  # fmt: skip
    assert res.returncode == 0, res.stderr
    rep = json.loads((tmp_path / "rep.json").read_text())
    (r,) = rep["results"]
    assert r["snap"] == 0.05 and r["snap_mirror"] and r["rows"][0]["variant"].endswith("snap 0.05 mirrored")
    bad = cli(capsys, "evaluate", "--data", data, "--checkpoint", ck, "--snap-mirror", "--out", tmp_path / "x")
    assert_user_error(bad, "--snap-mirror goes with --snap R")


class Recorder:
    """A stand-in SA-Net (it has a rig) that records the keywords of every ``complete`` call."""

    rig, needs_box, model_name = SPEC, False, "recorder"

    def __init__(self):
        self.kw = []

    def complete(self, partials, **kw):
        self.kw.append(kw)
        return [np.zeros((1, 3), np.float32) for _ in partials]


def test_complete_in_boxes_hands_the_sensor_to_the_snap():
    """The scene path (complete, real complete, track fusion) gives the occlusion rule its sensor origins."""
    from spotlights.learning.inference import complete_in_boxes

    rec, x = Recorder(), _scans(2)[0]
    sensors = np.array([[0.0, 3.0, 0.5], [0.0, -3.0, 0.5]])
    complete_in_boxes(rec, x, np.full((2, 3), 2.0), sensor_origins=sensors, snap=0.05)
    complete_in_boxes(rec, x, np.full((2, 3), 2.0), sensor_origins=sensors)
    assert np.array_equal(rec.kw[0]["sensor_origins"], sensors) and rec.kw[0]["snap"] == 0.05
    assert "sensor_origins" not in rec.kw[1]  # a model without evidence, no snap: not given


def test_complete_sensor_option_reaches_the_occlusion_rule(tmp_path, capsys, hit_ckpt):
    """``complete --sensor X Y Z``: the LiDAR's place decides which snaps the occlusion rule refuses (the scan's
    origin by default); a bad value or a multi-frame scene is refused in one line."""
    rng = np.random.default_rng(0)
    side = rng.uniform(-1, 1, (600, 3)) * [2.0, 0.0, 0.7] + [10.0, 2.0 + 0.85, 0.8]  # a car's left side, y = 2.85
    np.save(tmp_path / "scan.npy", side)
    box = ["--center", "10", "2", "0.8", "--size", "4.6", "1.9", "1.6", "--no-crop", "--checkpoint", hit_ckpt]
    out = {}
    for name, sensor in (
        ("origin", []),
        ("left", ["--sensor", "10", "12", "0.8"]),
        ("same", ["--sensor", "0", "0", "0"]),
    ):
        res = cli(
            capsys, "complete", tmp_path / "scan.npy", *box, "--snap", "0.08", *sensor, "--no-keep-observed",
            "--out", tmp_path / f"{name}.npy", "--summary", tmp_path / f"{name}.json", "-q",
        )  # fmt: skip
        assert res.returncode == 0, res.stderr
        out[name] = np.load(tmp_path / f"{name}.npy")
        assert json.loads((tmp_path / f"{name}.json").read_text())["sensor"] == ([float(v) for v in sensor[1:]] or None)
    assert np.array_equal(out["origin"], out["same"])  # the default is the scan's origin
    assert out["origin"].shape != out["left"].shape or not np.array_equal(out["origin"], out["left"])
    bad = cli(capsys, "complete", tmp_path / "scan.npy", *box, "--sensor", "nan", "0", "0", "--out", tmp_path / "x.npy")
    assert_user_error(bad, "--sensor")
    assert not (tmp_path / "x.npy").exists()
    (tmp_path / "scene").mkdir()
    multi = cli(capsys, "complete", tmp_path / "scene", "--sensor", "0", "0", "0", "--out", tmp_path / "o", "-q")
    assert_user_error(multi, "--sensor is for one scan")


def test_complete_frame_passes_the_sensor(hit_ckpt):
    """The API's complete_frame hands ``sensor`` to the scene (the snap's occlusion rule reads it)."""
    from spotlights.api import complete_frame
    from spotlights.geometry.boxes import Box
    from spotlights.learning.inference import load_completer

    c = load_completer(hit_ckpt, device="cpu")
    rng = np.random.default_rng(0)
    side = rng.uniform(-1, 1, (600, 3)) * [2.0, 0.0, 0.7] + [10.0, 2.85, 0.8]
    box = Box(center=np.array([10.0, 2.0, 0.8]), size=np.array([4.6, 1.9, 1.6]), yaw=0.0, cls="car")
    kw = dict(fallback="none", crop=False, any_label=True, snap=0.08, keep_observed=False)
    origin = complete_frame(side, [box], c, **kw).objects[0].completion
    same = complete_frame(side, [box], c, sensor=np.zeros(3), **kw).objects[0].completion
    left = complete_frame(side, [box], c, sensor=np.array([10.0, 12.0, 0.8]), **kw).objects[0].completion
    assert np.array_equal(origin, same) and (origin.shape != left.shape or not np.array_equal(origin, left))
    for bad in (np.array([np.nan, 0.0, 0.0]), np.zeros(2)):
        with pytest.raises(ParameterError, match="sensor"):
            complete_frame(side, [box], c, sensor=bad, **kw)


def test_fused_windows_carve_only_from_the_scans_own_points():
    """With other frames fused in (``extra_points``), the occlusion rule's free space is carved from the scan's own
    points (seen from its sensor), not from the fused ones (seen from elsewhere): complete_scene hands them over."""
    from spotlights.completion.frame import SceneConfig, complete_scene
    from spotlights.geometry.boxes import Box

    rng = np.random.default_rng(1)
    box = Box(center=np.array([10.0, 2.0, 0.8]), size=np.array([4.6, 1.9, 1.6]), yaw=0.0, cls="car")
    own = rng.uniform(-1, 1, (300, 3)) * [2.0, 0.0, 0.7] + [10.0, 2.85, 0.8]  # this frame: the left side
    other = rng.uniform(-1, 1, (200, 3)) * [2.0, 0.0, 0.7] + [10.0, 1.15, 0.8]  # another frame's: the right side
    cfg = SceneConfig(crop=False, any_label=True, snap=0.05)
    rec = Recorder()
    res = complete_scene(own, [box], rec, cfg, extra_points={0: other})
    (o,) = res.objects
    want = box.normalization().to_unit(own).astype(np.float32)
    assert o.n_fused == 500 and np.array_equal(o.seen_unit, want)
    (kw,) = rec.kw
    assert kw["snap"] == 0.05 and len(kw["seen"]) == 1 and np.array_equal(kw["seen"][0], want)
    complete_scene(own, [box], rec, cfg)  # a single frame: its input is what it saw (no separate set)
    assert "seen" not in rec.kw[-1]
