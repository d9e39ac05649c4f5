"""Metrics against brute-force numpy and closed forms; aggregation; no torch import."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from spotlights.metrics.completion import (
    NearestNeighbors,
    accuracy,
    chamfer_l1,
    chamfer_l2,
    completeness,
    evaluate_completions,
    fscore,
    kept_ratio,
    nearest_distances,
    summarize,
)

from helpers import src_pythonpath


def brute(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a),) unsquared distance from each a to its nearest b, by the full distance matrix."""
    return np.sqrt(((a[:, None, :].astype(np.float64) - b[None, :, :].astype(np.float64)) ** 2).sum(-1)).min(axis=1)


@pytest.fixture
def clouds():
    rng = np.random.default_rng(1)
    return rng.normal(size=(300, 3)), rng.normal(size=(500, 3)) * 0.9


def test_one_sided_and_symmetric_distances_match_brute_force(clouds):
    p, g = clouds
    d_pg, d_gp = brute(p, g), brute(g, p)
    np.testing.assert_allclose(nearest_distances(p, g), d_pg, rtol=1e-12)
    assert accuracy(p, g) == pytest.approx(d_pg.mean(), rel=1e-12)
    assert completeness(p, g) == pytest.approx(d_gp.mean(), rel=1e-12)
    assert chamfer_l1(p, g) == pytest.approx((d_pg.mean() + d_gp.mean()) / 2, rel=1e-12)
    assert chamfer_l2(p, g) == pytest.approx((d_pg**2).mean() + (d_gp**2).mean(), rel=1e-12)
    t = 0.15
    prec, rec = (d_pg <= t).mean(), (d_gp <= t).mean()
    assert fscore(p, g, t) == pytest.approx(2 * prec * rec / (prec + rec), rel=1e-12)


def test_float32_inputs_and_nearest_indices(clouds):
    p, g = (c.astype(np.float32) for c in clouds)
    d, i = NearestNeighbors(g).query(p)
    full = np.sqrt(((p[:, None].astype(np.float64) - g[None].astype(np.float64)) ** 2).sum(-1))
    np.testing.assert_allclose(d, full.min(1), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(full[np.arange(len(p)), i], full.min(1), rtol=1e-5, atol=1e-6)


def test_closed_forms():
    # Every point of a sphere of radius 1 is at distance exactly 1 from its centre.
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(1000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    centre = np.zeros((1, 3))
    assert accuracy(centre, sphere) == pytest.approx(1.0)
    assert completeness(centre, sphere) == pytest.approx(1.0)
    # Identical clouds: zero distances, F-score 1.
    assert chamfer_l2(sphere, sphere) == 0.0 and fscore(sphere, sphere) == 1.0
    # A cloud shifted by 0.5 along z from a single point.
    assert accuracy(np.array([[0, 0, 0.5]]), np.zeros((1, 3))) == pytest.approx(0.5)
    # Empty prediction
    assert np.isnan(accuracy(np.zeros((0, 3)), sphere)) and fscore(np.zeros((0, 3)), sphere) == 0.0


def test_kept_ratio():
    d = np.array([[0.0, 0.1, 0.3, 0.0], [0.5, 0.5, 0.0, 0.19]])
    np.testing.assert_allclose(kept_ratio(d), [0.5, 0.75])
    np.testing.assert_allclose(kept_ratio(d, clip=0.2), [0.25, 0.5])
    assert kept_ratio(d[0]) == 0.5


def test_evaluate_completions_batched_matches_per_sample():
    rng = np.random.default_rng(3)
    gt = rng.normal(size=(3, 400, 3)).astype(np.float32)
    models = np.array([0, 2, 0, 1, 2, 2])
    preds = [rng.normal(size=(int(k), 3)).astype(np.float32) for k in (50, 10, 0, 77, 1, 30)]
    res = evaluate_completions(preds, models, gt, fscore_threshold=0.3)
    for i, (p, m) in enumerate(zip(preds, models)):
        if len(p) == 0:
            assert np.isnan(res["accuracy"][i]) and np.isnan(res["completeness"][i]) and res["fscore"][i] == 0
            continue
        d_pg, d_gp = brute(p, gt[m]), brute(gt[m], p)
        assert res["accuracy"][i] == pytest.approx(d_pg.mean(), rel=1e-5)
        assert res["completeness"][i] == pytest.approx(d_gp.mean(), rel=1e-5)
        assert res["chamfer_l1"][i] == pytest.approx((d_pg.mean() + d_gp.mean()) / 2, rel=1e-5)
        assert res["chamfer_l2"][i] == pytest.approx((d_pg**2).mean() + (d_gp**2).mean(), rel=1e-5)
        pr, rc = (d_pg <= 0.3).mean(), (d_gp <= 0.3).mean()
        assert res["fscore"][i] == pytest.approx(2 * pr * rc / (pr + rc) if pr + rc else 0.0, rel=1e-5)
        assert res["n_points"][i] == len(p)
    acc_only = evaluate_completions(preds, models, gt, with_completeness=False)
    assert set(acc_only) == {"accuracy", "n_points"}
    np.testing.assert_array_equal(acc_only["accuracy"], res["accuracy"])


def test_summarize_means_over_samples_and_over_categories():
    per = {"accuracy": np.array([1.0, 3.0, 5.0, 10.0, np.nan])}
    cats = ["sedan", "sedan", "sedan", "suv", "suv"]
    s = summarize(per, cats, order=["hatchback", "sedan", "suv"])
    assert s["per_category"]["sedan"]["accuracy"] == 3.0
    assert s["per_category"]["suv"]["accuracy"] == 10.0
    assert s["mean_over_samples"]["accuracy"] == pytest.approx((1 + 3 + 5 + 10) / 4)
    assert s["mean_over_categories"]["accuracy"] == pytest.approx((3 + 10) / 2)
    assert s["count"] == {"sedan": 3, "suv": 2, "all": 5}
    assert s["undefined"]["accuracy"] == 1
    assert "hatchback" not in s["per_category"]


def test_metrics_module_does_not_import_torch():
    code = "import sys, spotlights.metrics.completion; assert 'torch' not in sys.modules"
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={"PYTHONPATH": src_pythonpath()}
    )
    assert proc.returncode == 0, proc.stderr
