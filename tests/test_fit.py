"""Evidence fitting at inference (:mod:`spotlights.learning.fit`, ``--fit``): checked against brute force and geometry.

The fit may change only the rays that carry evidence and their neighbours (brute-force line distances); no fitted
point lies in observed free space (point-to-beam geometry); the gate returns the unfitted completion, bit for bit,
when the fit cannot come closer to the observed points; same inputs, same bytes; the flag end to end.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch")

from spotlights.assets import asset_path  # noqa: E402
from spotlights.errors import ParameterError  # noqa: E402
from spotlights.geometry.boxes import unit_extents  # noqa: E402
from spotlights.learning.fit import FitSettings, fit_completions, gate  # noqa: E402
from spotlights.learning.fit_evidence import dilate, ray_neighbours  # noqa: E402
from spotlights.learning.rays import directions_for_extents  # noqa: E402

from helpers import assert_user_error, run_cli  # noqa: E402

SIZE = np.array([[4.5, 1.8, 1.5]])  # a car's box, metres


@pytest.fixture(scope="module")
def completer():
    from spotlights.learning.inference import load_completer

    return load_completer("default", device="cpu")


def _patch(centre, u, v, half: float, step: float) -> np.ndarray:
    """(n, 3) a square grid of points: ``centre + a u + b v`` for a, b in [-half, half] every ``step``."""
    a = np.arange(-half, half + 1e-9, step)
    g = np.stack(np.meshgrid(a, a, indexing="ij"), -1).reshape(-1, 2)
    return np.asarray(centre) + g[:, :1] * np.asarray(u) + g[:, 1:] * np.asarray(v)


def test_neighbours_are_the_nearest_rays_of_each_viewpoint():
    """Brute force over every ray of a small box rig: the k rays of its viewpoint with the largest cosine."""
    from spotlights.geometry.rig import RigSpec

    spec = RigSpec.from_name("box-4x16-ellipsoid-s1")
    k = 3
    nbr = ray_neighbours(spec, k)
    d = directions_for_extents(spec, np.full((1, 3), 1 / np.sqrt(3)))[0].astype(np.float64)
    m = spec.n_secondary
    for i in range(spec.n_rays):
        view = i // m
        others = [j for j in range(view * m, (view + 1) * m) if j != i]
        cos = [float(d[i] @ d[j]) for j in others]
        best = sorted(zip(cos, others), key=lambda c: (-c[0], c[1]))[:k]
        assert sorted(nbr[i].tolist()) == sorted(j for _, j in best)


def test_dilate_by_hand():
    nbr = np.array([[1], [2], [3], [3]])  # a chain: 0 -> 1 -> 2 -> 3
    m = np.array([False, False, False, True])
    assert dilate(m, nbr, 1).tolist() == [False, False, True, True]
    assert dilate(m, nbr, 2).tolist() == [False, True, True, True]


def test_free_space_of_one_point_by_hand():
    """Sensor at x = 5, one observed point at the origin, margin 0.1: the beam in front of the point (x from 5 down to
    0.1) is free; the point itself, behind it, and places off the beam are not; a NaN sensor frees nothing."""
    from spotlights.learning.fit_evidence import FreeSpace, out_of_free_space

    free = FreeSpace.of(np.zeros((1, 3)), [5.0, 0.0, 0.0], cells=32)
    q = np.array([[2.0, 0, 0], [0.2, 0, 0], [0.05, 0, 0], [0, 0, 0], [-1.0, 0, 0], [2.0, 1.0, 0], [2.0, 0, -1.0]])
    assert free.carved(q, 0.1).tolist() == [True, True, False, False, False, False, False]
    np.testing.assert_allclose(free.depth_inside(q[:1], 0.1), [5.0 - 0.1 - 3.0])  # limit - margin - range
    assert not FreeSpace.of(np.zeros((1, 3)), [np.nan] * 3).carved(q, 0.1).any()
    # a ray along -x from (1, 0, 0) (on the unit sphere, half chord 1), margin 0.12: free space ends at x = 0.12;
    # the point at t = 0.2 (x = 1 - 2t = 0.6) is in it; the nearest place that is not, in steps of 0.05 (t = 0.25,
    # 0.15, 0.3, 0.1, ...; t < 0 is off the ray) is t = 0.45 (x = 0.1)
    t, ok = out_of_free_space(free, [[1.0, 0, 0]], [[-1.0, 0, 0]], [0.2], 0.12, 0.05, 16)
    assert ok.tolist() == [True] and t[0] == pytest.approx(0.45)


def test_gate_by_hand():
    assert gate([0.02, 0.02, 0.02, np.inf], [0.01, 0.02, 0.03, 0.5]).tolist() == [True, False, False, True]
    assert gate([0.02], [np.inf]).tolist() == [False]


@pytest.mark.timeout(120)
def test_rays_without_evidence_keep_the_prior(completer):
    """A small observed patch, no sensor (no free space): the evidence is the rays passing within the radius of a
    patch point ahead of their origin (brute force over every ray and point); every ray farther than the
    neighbourhood's rings from those keeps the prior's depth and hit exactly; the data rays end nearer the patch."""
    cfg = FitSettings(steps=4)
    patch = _patch([0.75, 0.1, 0.05], [0, 1, 0], [0, 0, 1], 0.08, 0.02)  # near the front of the box
    partial = patch[None].astype(np.float32)
    ext = unit_extents(SIZE)
    res = fit_completions(completer, partial, ext, sensor_origins=None, settings=cfg)
    o = completer.model.origins.numpy().astype(np.float64)
    d = directions_for_extents(completer.rig, ext)[0].astype(np.float64)
    rel = patch[None] - o[:, None]  # (R, K, 3)
    t = 0.5 * np.einsum("rkj,rj->rk", rel, d)
    dist = np.linalg.norm(rel - (2 * t)[..., None] * d[:, None], axis=-1)
    near = ((dist <= cfg.radius) & (t > 0)).any(1)
    assert 0 < near.sum() < 0.2 * len(near)
    reach = dilate(near, ray_neighbours(completer.rig, cfg.neighbours), cfg.rings)
    far = ~reach
    assert far.sum() > 0.7 * len(far)
    np.testing.assert_array_equal(res.depth_fit[0][far], res.depth_prior[0][far])
    np.testing.assert_array_equal(res.keep_fit[0][far], res.keep_prior[0][far])
    assert not (res.changed[0] & far).any()
    # the data rays put their points on the patch: nearer than the prior's
    rows = np.flatnonzero(res.data[0])
    assert len(rows) > 20

    def gap(depth):
        pts = o[rows] + 2 * depth[rows, None].astype(np.float64) * d[rows]
        return np.median(np.linalg.norm(pts[:, None] - patch[None], axis=-1).min(1))

    assert gap(res.depth_fit[0]) < 0.5 * cfg.radius
    assert gap(res.depth_fit[0]) < gap(res.depth_prior[0])


def _beam_violations(points, sensor, observed, margin, cone):
    """Brute force: the points (n, 3) within angle ``cone`` (radians) of the beam from ``sensor`` to some
    ``observed`` point and nearer to the sensor than that point less ``margin``."""
    q = points - sensor
    p = observed - sensor
    rq, rp = np.linalg.norm(q, axis=1), np.linalg.norm(p, axis=1)
    cos = (q / rq[:, None]) @ (p / rp[:, None]).T
    inside = (cos > np.cos(cone)) & (rq[:, None] < rp[None] - margin)
    return inside.any(1)


@pytest.mark.timeout(120)
def test_no_fitted_point_in_observed_free_space(completer):
    """A sensor in front of the car and a dense wall of observed points *behind* the prior's front surface: the
    beams to the wall cross the prior's points. After the fit no point lies within a thin cone around a beam to an
    inner wall point, nearer to the sensor than that point less the margin (and a centimetre for the grid: a
    cell's free space ends at its nearest point)."""
    cfg = FitSettings(steps=4)
    sensor = np.array([6.0, 0.0, 0.3])
    wall = _patch([0.2, 0.0, 0.05], [0, 1, 0], [0, 0, 1], 0.25, 0.01)  # a plane x = 0.2, inside the box
    inner = wall[(np.abs(wall[:, 1]) < 0.15) & (np.abs(wall[:, 2] - 0.05) < 0.15)]
    ext = unit_extents(SIZE)
    res = fit_completions(
        completer, wall[None].astype(np.float32), ext, sensor_origins=sensor[None], observed=[wall], settings=cfg
    )
    o = completer.model.origins.numpy().astype(np.float64)
    d = directions_for_extents(completer.rig, ext)[0].astype(np.float64)

    def points(depth, keep):
        h = np.clip(-(o * d).sum(1), 0, None)
        return (o + 2 * np.minimum(np.clip(depth.astype(np.float64), 0, None), h)[:, None] * d)[keep]

    prior = points(res.depth_prior[0], res.keep_prior[0])
    fitted = points(res.depth_fit[0], res.keep_fit[0])
    margin = cfg.margin + 0.01
    assert _beam_violations(prior, sensor, inner, margin, 0.001).sum() > 10  # the case is what it says
    assert not _beam_violations(fitted, sensor, inner, margin, 0.001).any()
    # the returned completion (gated) is the fitted one here
    assert res.fitted[0]
    assert not _beam_violations(res.clouds[0].astype(np.float64), sensor, inner, margin, 0.001).any()


@pytest.mark.timeout(120)
def test_gate_keeps_the_prior_when_the_fit_cannot_come_closer(completer):
    """Observed points taken from the prior's own completion: its fidelity is 0, no fit can be lower, so the
    completion returned is the unfitted one, byte for byte (the completer's own output)."""
    ext = unit_extents(SIZE)
    partial = _patch([0.75, 0.1, 0.05], [0, 1, 0], [0, 0, 1], 0.08, 0.02)[None].astype(np.float32)
    prior = completer.complete(partial, extents=ext)[0]
    observed = prior[::50]
    res = fit_completions(completer, partial, ext, observed=[observed], settings=FitSettings(steps=2))
    assert res.fidelity_prior[0] == 0.0
    assert not res.fitted[0]
    assert res.clouds[0].tobytes() == prior.tobytes()


@pytest.mark.timeout(120)
def test_no_observed_point_no_fit(completer):
    """An empty observed set carries no evidence: nothing may change, and the completion is the unfitted one."""
    ext = unit_extents(SIZE)
    partial = _patch([0.75, 0.1, 0.05], [0, 1, 0], [0, 0, 1], 0.08, 0.02)[None].astype(np.float32)
    res = fit_completions(completer, partial, ext, observed=[np.zeros((0, 3))], settings=FitSettings(steps=2))
    assert not res.changed.any() and not res.fitted[0]
    assert res.clouds[0].tobytes() == completer.complete(partial, extents=ext)[0].tobytes()


@pytest.mark.timeout(120)
def test_same_inputs_same_bytes(completer):
    ext = unit_extents(np.array([[4.5, 1.8, 1.5], [4.0, 1.7, 1.6]]))
    rng = np.random.default_rng(0)
    partial = (rng.normal(size=(2, 256, 3)) * [0.4, 0.15, 0.1]).astype(np.float32)
    sensor = np.array([[4.0, 2.0, 0.5], [-3.0, 3.0, 0.4]])
    cfg = FitSettings(steps=3)
    a = fit_completions(completer, partial, ext, sensor_origins=sensor, settings=cfg)
    b = fit_completions(completer, partial, ext, sensor_origins=sensor, settings=cfg)
    for x, y in zip(a.clouds, b.clouds):
        assert x.tobytes() == y.tobytes()
    assert a.depth_fit.tobytes() == b.depth_fit.tobytes()


def test_settings_are_checked():
    with pytest.raises(ParameterError, match="steps"):
        FitSettings(steps=0)
    with pytest.raises(ParameterError, match="steps"):
        FitSettings(steps=51)
    from spotlights.completion.frame import SceneConfig

    with pytest.raises(ParameterError, match="snap"):
        SceneConfig(fit=True, snap=0.05)
    with pytest.raises(ParameterError, match="fit_steps"):
        SceneConfig(fit=True, fit_steps=2.5)


def test_a_runtime_without_the_torch_model_cannot_be_fitted(completer):
    """An ONNX-like completer (rays, but no torch model to differentiate) is refused in one line naming `fit`."""

    class RaysOnly:
        model_name = "onnx-like"
        rig = completer.rig

    with pytest.raises(ParameterError, match="cannot be fitted") as err:
        fit_completions(RaysOnly(), np.zeros((1, 8, 3), np.float32), unit_extents(SIZE))
    assert err.value.parameters == ("fit",)


@pytest.mark.timeout(300)
def test_fit_flag_end_to_end(tmp_path):
    """``complete --fit`` on the bundled demo scan: the summary says whether the fit was kept, and the fidelity is
    never worse than without the flag (the gate); wrong uses are one-line errors."""
    scan, box = asset_path("demo_scan.pcd"), asset_path("demo_scan_box.json")
    common = [str(scan), "--box", str(box), "--complete-unknown"]
    runs = {}
    for name, extra in (("plain", []), ("fit", ["--fit", "--fit-steps", "4"])):
        out, summary = tmp_path / f"{name}.ply", tmp_path / f"{name}.json"
        proc = run_cli("complete", *common, *extra, "--out", str(out), "--summary", str(summary))
        assert proc.returncode == 0, proc.stderr
        runs[name] = json.loads(summary.read_text())["objects"][0]
    assert "fitted" not in runs["plain"]
    assert isinstance(runs["fit"]["fitted"], bool)
    if runs["fit"]["fitted"]:
        assert runs["fit"]["fidelity"] < runs["plain"]["fidelity"]
    else:
        assert runs["fit"]["fidelity"] == runs["plain"]["fidelity"]
    bad = tmp_path / "bad.ply"
    assert_user_error(run_cli("complete", *common, "--fit", "--snap", "0.05", "--out", str(bad)), "snap")
    assert_user_error(run_cli("complete", *common, "--fit-steps", "3", "--out", str(bad)), "fit")
    proc = run_cli("complete", *common, "--fit", "--fit-steps", "0", "--out", str(bad))
    assert proc.returncode == 2 and "--fit-steps" in proc.stderr
    assert not bad.exists()


@pytest.mark.timeout(120)
def test_complete_frame_with_fit_and_the_heading_check(completer):
    """The API's ``fit=True`` beside the heading check (a batch of both headings): every completed box says
    whether its kept heading's fit was kept, and its fidelity is at most the unfitted one's of the same heading."""
    import spotlights
    from spotlights.data.real.scans import read_scan
    from spotlights.geometry.box_json import load_box

    scan = read_scan(asset_path("demo_scan.pcd"))
    box = load_box(asset_path("demo_scan_box.json")).replace(label="car", cls="car")
    opts = {"heading_check": True, "complete_unknown": True, "fallback": None}
    plain = spotlights.complete_frame(scan, [box], completer, **opts).objects[0]
    fitted = spotlights.complete_frame(scan, [box], completer, fit=True, fit_steps=3, **opts).objects[0]
    assert plain.fitted is None and isinstance(fitted.fitted, bool)
    assert fitted.flipped == plain.flipped  # the demo box is right: both keep it
    assert fitted.fidelity <= plain.fidelity
    assert fitted.summary()["fitted"] == fitted.fitted


def test_the_study_quotes_its_results():
    """docs/studies/fit.md quotes the committed results as they are (no number typed by hand)."""
    from helpers import REPO

    text = " ".join((REPO / "docs" / "studies" / "fit.md").read_text().split())
    res = json.loads((REPO / "docs" / "results" / "fit" / "fit.json").read_text())
    val = json.loads((REPO / "docs" / "results" / "fit" / "fit_val.json").read_text())
    for s in res["synthetic"].values():
        for row in ("without", "with"):
            for key in ("accuracy", "completeness", "chamfer_l1", "fscore", "fidelity", "cpu_s_per_scan"):
                assert str(s[row][key]) in text, (row, key, s[row][key])
    for r in res["real"].values():
        for row in ("without", "with"):
            for key in ("fidelity_average", "consistency_voxel_average", "cpu_s_per_scan"):
                assert str(r[row][key]) in text, (row, key, r[row][key])
    for row in ("without", "with"):
        assert str(res["frame"][row]["cpu_s"]) in text
    v = val["synthetic"]["apollo-val"]
    for row, key in (
        ("with", "accuracy"),
        ("without", "accuracy"),
        ("steps16", "chamfer_l1"),
        ("rings0", "chamfer_l1"),
    ):
        assert str(v[row][key]) in text, (row, key)


@pytest.mark.timeout(120)
def test_a_plain_sanet_on_a_cap_rig_is_fitted_too(tmp_path):
    """The paper's SA-Net (one depth per ray, a cap rig: fixed rays), untrained: the same invariants (rays without
    evidence in reach keep the prior exactly; a kept fit comes closer to the observed points)."""
    from spotlights.learning.inference import load_completer

    from learning_fixtures import make_checkpoint

    comp = load_completer(make_checkpoint(tmp_path / "sanet.pt", "sanet"), device="cpu")
    assert not comp.needs_box
    patch = _patch([0.3, 0.0, 0.1], [0, 1, 0], [0, 0, 1], 0.2, 0.04)
    ext = unit_extents(SIZE)
    cfg = FitSettings(steps=3)
    res = fit_completions(comp, patch[None].astype(np.float32), ext, sensor_origins=[[4.0, 0.5, 0.5]], settings=cfg)
    far = ~dilate(res.evidence[0], ray_neighbours(comp.rig, cfg.neighbours), cfg.rings)
    np.testing.assert_array_equal(res.depth_fit[0][far], res.depth_prior[0][far])
    np.testing.assert_array_equal(res.keep_fit[0][far], res.keep_prior[0][far])
    if res.fitted[0]:
        assert res.fidelity_fit[0] < res.fidelity_prior[0]
    else:
        assert res.clouds[0].tobytes() == comp.complete(patch[None].astype(np.float32))[0].tobytes()


@pytest.mark.timeout(120)
def test_an_onnx_export_is_fitted_through_its_checkpoint(tmp_path):
    """A completer that runs an ONNX export (its ``path``, no torch model) is fitted with the checkpoint beside it
    (``NAME.pt`` next to ``NAME.onnx``, as the packaged models ship); without one the fit is refused in one line."""
    import shutil

    from spotlights.completion.frame import SceneConfig, complete_scene
    from spotlights.data.real.scans import read_scan
    from spotlights.geometry.box_json import load_box
    from spotlights.learning.checkpoint import resolve_checkpoint

    shutil.copy(resolve_checkpoint("default"), tmp_path / "model.pt")

    class Export:  # what an onnxruntime completer shows: its file, rays, no torch model
        path = tmp_path / "model.onnx"
        model_name = "sanet-hit"
        rig = None

        def complete(self, *args, **kwargs):
            raise AssertionError("the fit must not run the export")

    scan = read_scan(asset_path("demo_scan.pcd"))
    box = load_box(asset_path("demo_scan_box.json")).replace(label="car", cls="car")
    config = SceneConfig(fit=True, fit_steps=2, complete_unknown=True)
    done = complete_scene(scan, [box], Export(), config).objects[0]
    assert done.status == "completed" and isinstance(done.fitted, bool)
    (tmp_path / "model.pt").unlink()
    with pytest.raises(ParameterError, match="cannot be fitted"):
        complete_scene(scan, [box], Export(), config)


def test_real_evaluate_fits_and_no_fitted_observation_moves_away(tmp_path, completer):
    """``real evaluate --fit``: the gate keeps a fit only where it comes closer to the observed points, so every
    track's mean fidelity with the fit is at most the unfitted one; the settings record the fit's steps (a report
    scored without it is not reused for it); --fit with --snap and --fit-steps without --fit are one line each."""
    from spotlights.data.real.extract import write_observations
    from spotlights.experiments.real_evaluation import RealEvaluationSettings, evaluate_consistency

    from builders import tracked_scene

    obs = tracked_scene(tmp_path / "scene")
    quick = dict(heading_check=False, noise_floor=False, equal_points=None, equal_density=None)
    plain = evaluate_consistency(obs, [completer], progress=False, **quick)
    fitted = evaluate_consistency(obs, [completer], progress=False, fit=True, fit_steps=4, **quick)
    (p,), (f,) = plain["models"], fitted["models"]
    assert p["fitted"] is None and 0.0 < f["fitted"] <= 1.0
    assert plain["data"]["settings"]["fit_steps"] is None and fitted["data"]["settings"]["fit_steps"] == 4
    before = {o["track_id"]: o["fidelity"] for o in p["objects"]}
    after = {o["track_id"]: o["fidelity"] for o in f["objects"]}
    assert before.keys() == after.keys() and all(after[t] <= before[t] + 1e-9 for t in before)
    assert any(after[t] < before[t] for t in before)
    with pytest.raises(ParameterError, match="`fit_steps` goes with `fit`"):
        RealEvaluationSettings(fit_steps=3)
    with pytest.raises(ParameterError, match="does not go with `snap`"):
        RealEvaluationSettings(fit=True, snap=0.05, heading_check=False)
    path = tmp_path / "obs.h5"
    write_observations(path, obs)
    r = run_cli("real", "evaluate", path, "--fit", "--snap", "0.05", "--no-heading-check", "-o", tmp_path / "x", "-q")
    assert_user_error(r, "--fit")
    r = run_cli("real", "evaluate", path, "--fit-steps", "3", "-o", tmp_path / "y", "-q")
    assert_user_error(r, "--fit-steps goes with --fit")
    assert not list(tmp_path.glob("x*")) and not list(tmp_path.glob("y*"))
