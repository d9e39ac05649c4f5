"""The consistency metric against brute force, the track pairing, the aggregation, and the evaluation API."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from spotlights.data.real import open_reader
from spotlights.data.real.extract import ExtractConfig, extract
from spotlights.errors import InputFileError
from spotlights.experiments.real_evaluation import evaluate_consistency, write_report
from spotlights.metrics.consistency import (
    aggregate,
    chamfer,
    consecutive_pairs,
    diversity,
    fidelity,
    minimal_matching_distance,
    nn_distances,
    track_consistency,
)

from builders import Identity, tracked_scene


def test_chamfer_matches_brute_force():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(300, 3)), rng.normal(size=(170, 3)) + 0.3
    d = cdist(a, b)  # unsquared Euclidean
    ab, ba = d.min(axis=1).mean(), d.min(axis=0).mean()
    c = chamfer(a, b)
    assert c["d_ab"] == pytest.approx(ab, rel=1e-12)
    assert c["d_ba"] == pytest.approx(ba, rel=1e-12)
    assert c["cd"] == pytest.approx(ab + ba, rel=1e-12)  # the paper's Eq. (1)
    assert c["cd_half"] == pytest.approx((ab + ba) / 2, rel=1e-12)
    assert c["cd_l2"] == pytest.approx((d.min(axis=1) ** 2).mean() + (d.min(axis=0) ** 2).mean(), rel=1e-12)
    np.testing.assert_allclose(nn_distances(a, b), d.min(axis=1), rtol=1e-12)


def test_chamfer_closed_form():
    a = np.zeros((1, 3))
    b = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 10.0]])
    c = chamfer(a, b)
    assert c["d_ab"] == 5.0 and c["d_ba"] == 7.5 and c["cd"] == 12.5 and c["cd_l2"] == 25.0 + 62.5


def test_consecutive_pairs_order_and_gaps():
    keys = ["a", "b", "a", "c", "a", "b"]
    ts = [30, 5, 10, 1, 20, 7]
    # a: rows 2 (t10), 4 (t20), 0 (t30); b: rows 1 (t5), 5 (t7); c alone
    assert consecutive_pairs(keys, ts) == [(2, 4), (4, 0), (1, 5)]
    assert consecutive_pairs(["x", "y"], [0, 0]) == []


def test_track_consistency_frames_and_aggregation():
    # Track "a" (car): R = 2 in both frames; completions differ by a 0.2 m shift along x in metres:
    # in unit frames that is 0.1, so d_ab = d_ba = 0.1 m / R_track = 0.1 -> cd = 0.2 (metres: 0.4).
    pts = np.array([[0.0, 0.0, 0.0]])
    comps = [pts, pts + [0.1, 0, 0]]
    keys, ts, cls, radii = [("s", "a")] * 2, [0, 1], ["car", "car"], [2.0, 2.0]
    # Track "b" (car): radii 1 and 3 but the same metric shape -> perfectly consistent.
    comps += [np.array([[0.3, 0, 0]]), np.array([[0.1, 0, 0]])]
    keys += [("s", "b")] * 2
    ts += [0, 1]
    cls += ["car", "car"]
    radii += [1.0, 3.0]
    # Track "t" (truck), three frames, R = 1: shifts 0.1 then 0.3 -> cd 0.2 and 0.6, mean 0.4.
    comps += [pts, pts + [0.1, 0, 0], pts + [0.4, 0, 0]]
    keys += [("s", "t")] * 3
    ts += [0, 1, 2]
    cls += ["truck"] * 3
    radii += [1.0] * 3
    # Track "e" (trailer): one completion empty -> unscored.
    comps += [pts, np.zeros((0, 3))]
    keys += [("s", "e")] * 2
    ts += [0, 1]
    cls += ["trailer"] * 2
    radii += [1.0, 1.0]
    tracks = {t.key[1]: t for t in track_consistency(comps, keys, ts, cls, radii)}
    assert tracks["a"].values["cd"] == pytest.approx(0.2)
    assert tracks["a"].values["cd_m"] == pytest.approx(0.4)
    assert tracks["b"].values["cd"] == pytest.approx(0.0, abs=1e-12)
    assert tracks["t"].values["cd"] == pytest.approx(0.4) and tracks["t"].n_pairs == 2
    assert math.isnan(tracks["e"].values["cd"]) and tracks["e"].n_pairs_empty == 1
    agg = aggregate(list(tracks.values()), classes=["car", "truck", "trailer"])
    assert agg["classes"]["car"]["cd"] == pytest.approx(0.1)  # mean of 0.2 and 0
    assert agg["classes"]["truck"]["cd"] == pytest.approx(0.4)
    assert agg["classes"]["trailer"]["cd"] is None and agg["classes"]["trailer"]["n_objects_unscored"] == 1
    assert agg["average"]["cd"] == pytest.approx(0.25)  # mean over the classes with a score
    assert agg["all_objects"]["cd"] == pytest.approx(0.2)  # mean over the three scored tracks
    assert agg["average"]["n_classes"] == 2


class Ellipsoid:
    model_name = "ellipsoid"
    n_params = 3

    def __init__(self):
        from spotlights.geometry.rig import fibonacci_sphere

        self.points = (fibonacci_sphere(512) * [0.9, 0.38, 0.3]).astype(np.float32)

    def complete(self, partials):
        return [self.points for _ in partials]


def test_evaluate_consistency_with_fake_completers(tmp_path):
    obs = tracked_scene(tmp_path)
    assert len(obs) == 5
    report = evaluate_consistency(obs, [Identity(), Ellipsoid()], progress=False)
    ident, ell = report["models"]
    assert report["data"]["n_objects_tracked"] == 2 and report["data"]["n_pairs"] == 2
    assert report["data"]["objects_per_class"] == {"car": 1, "caravan": 1}
    # Identity: the completion is the partial; check against brute force on the stored partials.
    for cls, tid in (("car", "a"), ("caravan", "v")):
        rows = [i for i, t in enumerate(obs.track_id) if t == tid]
        d = cdist(obs.partial[rows[0]].astype(np.float64), obs.partial[rows[1]].astype(np.float64))
        want = d.min(axis=1).mean() + d.min(axis=0).mean()  # same box size in both frames: unit frames agree
        assert ident["classes"][cls]["cd"] == pytest.approx(want, rel=1e-6)
    assert ident["average"]["cd"] == pytest.approx(
        (ident["classes"]["car"]["cd"] + ident["classes"]["caravan"]["cd"]) / 2
    )
    assert ell["average"]["cd"] == pytest.approx(0.0, abs=1e-12)  # the same prediction every time
    assert ell["diversity"] == pytest.approx(0.0, abs=1e-12) and ell["consistency_over_diversity"] is None
    assert ident["diversity"] > 0.1 and ident["consistency_over_diversity"] == pytest.approx(
        ident["all_objects"]["cd"] / ident["diversity"]
    )
    md, js = write_report(report, tmp_path / "out" / "rep")
    text = md.read_text()
    assert "| identity |" in text and "| Car | Caravan |" in text.replace("Model | ", "")
    assert json.loads(js.read_text())["models"][1]["name"] == "ellipsoid"


def test_evaluate_needs_tracks(tmp_path):
    """A scene whose only object is seen in one frame (tracked_scene's "once" car, alone) has no pair to compare."""
    rng = np.random.default_rng(5)
    obj = rng.uniform(-0.5, 0.5, (80, 3)) * [4, 1.8, 1.4] + [0, -10, -0.8]
    np.save(tmp_path / "s0.npy", np.concatenate([rng.uniform(-50, 50, (200, 3)) + [0, 0, 30], obj]).astype(np.float32))
    box = {"center": [0, -10, -0.8], "size": [4, 1.8, 1.4], "yaw": 0.0, "label": "Car", "track_id": "once"}
    frame = {"scan": "s0.npy", "timestamp": 0, "sequence": "seq", "boxes": [box]}
    (tmp_path / "scene.json").write_text(json.dumps({"frames": [frame]}))
    single = extract(open_reader(tmp_path / "scene.json", "generic"), ExtractConfig(), progress=False)
    assert list(single.track_id) == ["once"]
    with pytest.raises(InputFileError, match="no object is observed in two or more frames"):
        evaluate_consistency(single, [Identity()], progress=False)


def test_fidelity_against_brute_force_and_closed_form():
    rng = np.random.default_rng(3)
    base = rng.normal(size=(60, 3))
    partial = np.concatenate([base, base[:20]])  # resampling repeats: counted once
    comp = rng.normal(size=(400, 3)) * 1.2
    want = cdist(base, comp).min(axis=1).mean()
    assert fidelity(partial, comp) == pytest.approx(want, rel=1e-12)
    assert fidelity(base, np.concatenate([comp, base])) == 0.0  # the completion keeps every observed point
    # Closed form: observed points on the unit sphere, completion = the same directions at radius 1.25
    dirs = base / np.linalg.norm(base, axis=1, keepdims=True)
    assert fidelity(dirs, 1.25 * dirs) == pytest.approx(0.25, abs=1e-12)
    assert math.isnan(fidelity(base, np.zeros((0, 3))))


def test_minimal_matching_distance_against_brute_force():
    rng = np.random.default_rng(4)
    refs = [
        rng.normal(size=(int(rng.integers(50, 200)), 3)) * s + o
        for s, o in zip(rng.uniform(0.5, 2, 12), rng.normal(size=(12, 3)))
    ]
    for trial in range(5):
        comp = refs[(3 * trial + 5) % 12][rng.permutation(40)] + rng.normal(scale=0.05, size=(40, 3))
        cds = []
        for r in refs:
            d = cdist(comp, r)
            cds.append(d.min(axis=1).mean() + d.min(axis=0).mean())
        got, idx = minimal_matching_distance(comp, refs)
        assert idx == int(np.argmin(cds)) and got == pytest.approx(min(cds), rel=1e-12)
    assert minimal_matching_distance(np.zeros((0, 3)), refs) == (pytest.approx(float("nan"), nan_ok=True), -1)
    with pytest.raises(ValueError, match="at least one reference"):
        minimal_matching_distance(comp, [])


def test_evaluate_reports_fidelity_and_mmd(tmp_path):
    obs = tracked_scene(tmp_path)
    ell = Ellipsoid()
    refs = [ell.points.astype(np.float64), ell.points * 0.5]
    report = evaluate_consistency(
        obs,
        [Identity(), ell],
        progress=False,
        references=refs,
        reference_info={"file": "refs", "split": "all", "n_shapes": 2, "points_per_shape": 512},
    )
    ident, e = report["models"]
    assert ident["average"]["fidelity"] == pytest.approx(0.0, abs=1e-12)  # the completion is the input
    # The fixed ellipsoid: brute-force fidelity per observation -> mean per track -> class -> average
    rows = {tid: [i for i, t in enumerate(obs.track_id) if t == tid] for tid in ("a", "v")}
    per_track = {
        tid: np.mean(
            [cdist(np.unique(obs.partial[i].astype(np.float64), axis=0), ell.points).min(axis=1).mean() for i in r]
        )
        for tid, r in rows.items()
    }
    assert e["classes"]["car"]["fidelity"] == pytest.approx(per_track["a"], rel=1e-6)
    assert e["average"]["fidelity"] == pytest.approx((per_track["a"] + per_track["v"]) / 2, rel=1e-6)
    assert e["average"]["mmd"] == pytest.approx(0.0, abs=1e-12)  # it is reference 0
    assert ident["average"]["mmd"] > 0.05
    text = write_report(report, tmp_path / "rep")[0].read_text()
    assert "| Model | CD (consistency) | Fidelity | Fidelity (m) | MMD |" in text
    assert "MMD reference: 2 complete shapes" in text


def test_per_observation_scores_skip_nan_and_follow_the_track_means():
    pts = np.zeros((1, 3))
    comps = [pts, pts, pts, pts]
    keys = [("s", "a"), ("s", "a"), ("s", "b"), ("s", "b")]
    fid = np.array([0.1, np.nan, np.nan, np.nan])  # track b: every observation empty -> no fidelity
    tracks = track_consistency(
        comps, keys, [0, 1, 0, 1], ["car", "car", "truck", "truck"], [1.0] * 4, per_observation={"fidelity": fid}
    )
    by = {t.key[1]: t for t in tracks}
    assert by["a"].values["fidelity"] == pytest.approx(0.1) and math.isnan(by["b"].values["fidelity"])
    agg = aggregate(tracks, classes=["car", "truck"])
    assert agg["classes"]["truck"]["fidelity"] is None and agg["classes"]["truck"]["cd"] == 0.0
    assert agg["average"]["fidelity"] == pytest.approx(0.1)  # over the classes that have a value
    assert agg["average"]["cd"] == 0.0 and agg["all_objects"]["fidelity"] == pytest.approx(0.1)


def test_serial_queries_restores_the_thread_counts():
    torch = pytest.importorskip("torch")
    from spotlights.geometry.neighbors import serial_queries

    before = torch.get_num_threads()
    with serial_queries():
        d = nn_distances(np.random.default_rng(0).normal(size=(500, 3)), np.zeros((1, 3)))
    assert torch.get_num_threads() == before and d.shape == (500,)


def test_diversity_against_brute_force():
    rng = np.random.default_rng(6)
    comps = [rng.normal(size=(30, 3)) + k for k in range(5)]
    keys = ["a", "a", "b", "c", "c"]
    ts = [5, 1, 0, 0, 3]  # earliest: a -> row 1, b -> row 2, c -> row 3
    comps[3] = np.zeros((0, 3))  # c's earliest is empty: its next observation (row 4) stands for it
    reps = [comps[1], comps[2], comps[4]]
    want = np.mean(
        [cdist(x, y).min(1).mean() + cdist(x, y).min(0).mean() for i, x in enumerate(reps) for y in reps[i + 1 :]]
    )
    got, n = diversity(comps, keys, ts)
    assert n == 3 and got == pytest.approx(want, rel=1e-12)
    same = [np.ones((4, 3))] * 3
    assert diversity(same, ["a", "b", "c"], [0, 0, 0]) == (0.0, 3)  # a template model
    assert math.isnan(diversity(same[:1], ["a"], [0])[0])


def _brute_cd(a, b) -> float:
    d = cdist(np.asarray(a, np.float64), np.asarray(b, np.float64))
    return float(d.min(axis=1).mean() + d.min(axis=0).mean())


def test_noise_floor_equal_points_and_heading_flips(tmp_path):
    """Against brute force: the noise floor of a model that returns its input is the Chamfer between two
    resamplings of the kept points; equal-count consistency compares FPS subsets; a model that ignores its
    input has a zero floor; heading flips are counted by fidelity with the box turned."""
    from spotlights.experiments.real_evaluation import EQUAL_DENSITY, EQUAL_POINTS, equal_count
    from spotlights.geometry.sampling import resample_set, voxel_downsample

    obs = tracked_scene(tmp_path)  # 150 points per car: the 256-point inputs hold every point (+ repeats)
    rep = evaluate_consistency(obs, [Identity(), Ellipsoid()], progress=False, equal_points=64)
    ident, ell = rep["models"]
    assert ident["average"]["noise_floor"] == pytest.approx(0.0, abs=1e-12)  # same points, other repeats
    # more points than inputs: keep 1000 per car
    obs2 = tracked_scene(tmp_path / "dense", points_per_car=1000, seed=6, seen_once=False)  # inputs: 256-point subsets
    rep = evaluate_consistency(obs2, [Identity(), Ellipsoid()], progress=False, equal_points=64)
    ident, ell = rep["models"]
    rows = [i for i, t in enumerate(obs2.track_id) if t in ("a", "v")]
    want = {}
    for i in rows:
        a = obs2.partial[i]
        b = resample_set(obs2.raw(i), 256, seed=1)
        want.setdefault(obs2.track_id[i], []).append(_brute_cd(a, b))
    per_track = {o["track_id"]: o["noise_floor"] for o in ident["objects"]}
    for t, vals in want.items():
        assert per_track[t] == pytest.approx(np.mean(vals), rel=1e-9)  # one box size per track: R_i / R_track = 1
    assert ident["average"]["noise_floor"] > 0.01 and ell["average"]["noise_floor"] == 0.0
    # equal point counts: consistency of FPS subsets of 64 points
    eq = ident["equal_points"]
    assert eq["n_points"] == 64
    pa = [i for i in rows if obs2.track_id[i] == "a"]
    i, j = sorted(pa, key=lambda r: obs2.timestamp[r])
    ca, cb = equal_count(obs2.partial[i], 64), equal_count(obs2.partial[j], 64)
    assert len(ca) == 64 and len(np.unique(ca, axis=0)) == 64
    assert eq["classes"]["car"]["cd"] == pytest.approx(_brute_cd(ca, cb), rel=1e-9)
    assert EQUAL_POINTS == 512  # the default of real evaluate --equal-points
    # equal density: consistency of the voxel-cell centroids (side 0.1, unit frame)
    vd = ident["equal_density"]
    va, vb = voxel_downsample(obs2.partial[i], 0.1), voxel_downsample(obs2.partial[j], 0.1)
    assert vd["voxel"] == EQUAL_DENSITY == 0.1
    assert vd["classes"]["car"]["cd"] == pytest.approx(_brute_cd(va, vb), rel=1e-9)
    assert ell["equal_density"]["average"]["cd"] == pytest.approx(0.0, abs=1e-12)  # a fixed shape stays fixed
    # the report's keys are the ones reproduce's Table 2 reads (producer -> consumer, no hand-made dict)
    from spotlights.experiments.reproduce.tables.real import consistency_values

    vals = consistency_values(rep)[ident["name"]]
    for k in ("average_vox", "noise_floor_vox", "diversity_vox", "points_vox", "average_eq", "diversity_eq", "car_vox"):
        assert vals[k] is not None and np.isfinite(vals[k]), k
    assert vals["average_vox"] == pytest.approx(vd["average"]["cd"]) and vals["car_vox"] == vd["classes"]["car"]["cd"]
    # heading: the identity completion is exact for both headings (fidelity 0): never flipped; the fixed ellipsoid
    # is symmetric under the turn: the same fidelity, never flipped either (not *clearly* closer)
    assert ident["heading"]["n_flipped"] == 0 and ell["heading"]["n_flipped"] == 0
    write_report(rep, tmp_path / "r")
    text = (tmp_path / "r.md").read_text()
    assert "Noise floor @64" in text and "Heading flips" in text and "CD @voxel 0.1" in text
