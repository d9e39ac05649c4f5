"""geometry.distances (every nearest-neighbour / Chamfer metric) against a naive full-distance-matrix reference."""

from __future__ import annotations

import itertools
import math
import subprocess
import sys

import numpy as np
import pytest

from spotlights.geometry import distances as D
from spotlights.geometry.neighbors import NearestNeighbors

from helpers import src_pythonpath


def naive_chamfer(x, y, squared=False, single_directional=False, point_reduction="mean", direction_reduction="sum"):
    """The definition, spelt out: the full (K, L) distance matrix, its row and column minima, reduced."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    dist = np.sqrt(((x[:, None, :] - y[None, :, :]) ** 2).sum(-1))
    d_xy, d_yx = dist.min(axis=1), dist.min(axis=0)
    if squared:
        d_xy, d_yx = d_xy**2, d_yx**2
    if point_reduction == "none":
        return d_xy if single_directional else (d_xy, d_yx)
    red = np.mean if point_reduction == "mean" else np.sum
    if single_directional:
        return float(red(d_xy))
    total = float(red(d_xy)) + float(red(d_yx))
    return total if direction_reduction == "sum" else total / 2


@pytest.fixture
def clouds():
    rng = np.random.default_rng(7)
    return rng.normal(size=(230, 3)), rng.normal(size=(170, 3)) * 0.8 + 0.2


@pytest.mark.parametrize(
    "squared, single, point_reduction, direction_reduction",
    list(itertools.product([False, True], [False, True], ["mean", "sum"], ["sum", "mean"])),
)
def test_chamfer_distance_every_setting_matches_the_naive_reference(
    clouds, squared, single, point_reduction, direction_reduction
):
    x, y = clouds
    kw = dict(
        squared=squared,
        single_directional=single,
        point_reduction=point_reduction,
        direction_reduction=direction_reduction,
    )
    expect = naive_chamfer(x, y, **kw)
    assert D.chamfer_distance(x, y, **kw) == pytest.approx(expect, rel=1e-12)
    # prebuilt trees on either side give the same value
    assert D.chamfer_distance(NearestNeighbors(x), NearestNeighbors(y), **kw) == pytest.approx(expect, rel=1e-12)


def test_per_point_distances_and_float32(clouds):
    x, y = clouds
    d_xy, d_yx = D.chamfer_distance(x, y, point_reduction="none")
    ref_xy, ref_yx = naive_chamfer(x, y, point_reduction="none")
    np.testing.assert_allclose(d_xy, ref_xy, rtol=1e-12)
    np.testing.assert_allclose(d_yx, ref_yx, rtol=1e-12)
    np.testing.assert_allclose(D.nearest_distances(x, y, squared=True), ref_xy**2, rtol=1e-12)
    np.testing.assert_allclose(
        D.chamfer_distance(x, y, single_directional=True, point_reduction="none"), ref_xy, rtol=1e-12
    )
    # float32 points: the query runs in float32, distances come back as float64 within float32 accuracy
    x32, y32 = x.astype(np.float32), y.astype(np.float32)
    d = D.nearest_distances(x32, y32)
    assert d.dtype == np.float64
    np.testing.assert_allclose(d, naive_chamfer(x32, y32, point_reduction="none")[0], rtol=1e-5, atol=1e-6)


def test_named_metrics_are_the_stated_settings(clouds):
    p, g = clouds
    d_pg, d_gp = naive_chamfer(p, g, point_reduction="none")
    assert D.accuracy(p, g) == pytest.approx(d_pg.mean(), rel=1e-12)
    assert D.completeness(p, g) == pytest.approx(d_gp.mean(), rel=1e-12)
    assert D.chamfer_distance(p, g) == pytest.approx(d_pg.mean() + d_gp.mean(), rel=1e-12)  # the paper's Eq. (1)
    assert D.chamfer_l1(p, g) == pytest.approx((d_pg.mean() + d_gp.mean()) / 2, rel=1e-12)
    assert D.chamfer_l2(p, g) == pytest.approx((d_pg**2).mean() + (d_gp**2).mean(), rel=1e-12)
    for t in (0.05, 0.15, 10.0):
        prec, rec = (d_pg <= t).mean(), (d_gp <= t).mean()
        expect = 2 * prec * rec / (prec + rec) if prec + rec else 0.0
        assert D.fscore(p, g, t) == pytest.approx(expect, rel=1e-12)
    # the scalings relate as stated
    assert D.chamfer_l1(p, g) == pytest.approx(D.chamfer_distance(p, g) / 2, rel=1e-15)
    assert D.chamfer_distance(p, g) == pytest.approx(D.accuracy(p, g) + D.completeness(p, g), rel=1e-15)


def test_closed_forms():
    a = np.zeros((1, 3))
    b = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 10.0]])
    # a -> b: 5; b -> a: mean(5, 10) = 7.5
    assert D.chamfer_distance(a, b) == 12.5
    assert D.chamfer_distance(a, b, direction_reduction="mean") == 6.25
    assert D.chamfer_distance(a, b, squared=True) == 25.0 + 62.5
    assert D.chamfer_distance(a, b, point_reduction="sum") == 5.0 + 15.0
    assert D.chamfer_distance(b, a, single_directional=True) == 7.5
    # every point of a unit sphere is at distance 1 from its centre
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(1000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    assert D.accuracy(a, sphere) == pytest.approx(1.0) and D.completeness(a, sphere) == pytest.approx(1.0)
    assert D.chamfer_l2(sphere, sphere) == 0.0 and D.fscore(sphere, sphere) == 1.0


def test_empty_sets():
    pts = np.random.default_rng(1).normal(size=(20, 3))
    empty = np.zeros((0, 3))
    assert math.isnan(D.accuracy(empty, pts)) and math.isnan(D.completeness(empty, pts))
    assert math.isnan(D.chamfer_distance(pts, empty)) and math.isnan(D.chamfer_l1(empty, pts))
    assert math.isnan(D.completeness(empty, pts))
    assert D.fscore(empty, pts) == 0.0


def test_reduce_points_segments_match_per_set_reductions():
    rng = np.random.default_rng(2)
    lengths = np.array([5, 0, 17, 1, 40])
    d = rng.random(lengths.sum())
    sets = np.split(d, np.cumsum(lengths)[:-1])
    means = D.reduce_points(d, "mean", lengths=lengths)
    sums = D.reduce_points(d, "sum", lengths=lengths)
    for k, s in enumerate(sets):
        if len(s) == 0:
            assert math.isnan(means[k]) and sums[k] == 0.0
        else:
            assert means[k] == pytest.approx(s.mean(), rel=1e-12) and sums[k] == pytest.approx(s.sum(), rel=1e-12)
    assert D.reduce_points(d, "none") is d
    with pytest.raises(ValueError, match="lengths"):
        D.reduce_points(d, "mean", lengths=[1, 2])


def test_bad_parameters_and_shapes():
    x = np.zeros((3, 3))
    with pytest.raises(ValueError, match="point reduction"):
        D.chamfer_distance(x, x, point_reduction="max")
    with pytest.raises(ValueError, match="direction reduction"):
        D.chamfer_distance(x, x, direction_reduction="max")
    with pytest.raises(ValueError, match=r"\(K, 3\)"):
        D.chamfer_distance(np.zeros((3, 2)), x)


def test_every_caller_uses_the_same_numbers():
    """The consistency metric, the learning metrics and the rig study's completeness are the module's."""
    from spotlights.metrics import completion as metrics
    from spotlights.metrics.consistency import chamfer, fidelity

    rng = np.random.default_rng(4)
    a, b = rng.normal(size=(60, 3)), rng.normal(size=(90, 3))
    c = chamfer(a, b)
    assert c["cd"] == D.chamfer_distance(a, b)
    assert c["cd_half"] == D.chamfer_l1(a, b) == metrics.chamfer_l1(a, b)
    assert c["cd_l2"] == D.chamfer_l2(a, b)
    assert c["d_ab"] == D.accuracy(a, b) and c["d_ba"] == D.completeness(a, b)
    assert fidelity(a, b) == D.accuracy(np.unique(a, axis=0), b)
    assert metrics.accuracy is D.accuracy and metrics.fscore is D.fscore


def test_distances_module_does_not_import_torch():
    code = "import sys, spotlights.geometry.distances; assert 'torch' not in sys.modules"
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={"PYTHONPATH": src_pythonpath()}
    )
    assert proc.returncode == 0, proc.stderr


@pytest.mark.timeout(60)
def test_farthest_point_sample_against_the_definition():
    """Each index after the seeded first one is a point farthest (full distance matrix) from those chosen before."""
    from spotlights.geometry.sampling import farthest_point_sample

    rng = np.random.default_rng(5)
    p = rng.normal(size=(400, 3)) * [3.0, 1.0, 0.2]
    idx = farthest_point_sample(p, 60, seed=2)
    assert idx[0] == np.random.default_rng(2).integers(400) and len(set(idx.tolist())) == 60
    d = np.sqrt(((p[:, None, :] - p[None, :, :]) ** 2).sum(-1))
    for j in range(1, 60):
        to_set = d[:, idx[:j]].min(axis=1)
        assert to_set[idx[j]] == pytest.approx(to_set.max(), rel=1e-12)
    assert np.array_equal(farthest_point_sample(p, 60, seed=2), idx)  # deterministic


def test_voxel_downsample_sums_in_canonical_order_bit_for_bit():
    """Each centroid is its cell's points added up one by one in canonical order (x, then y, then z), divided by
    their count, then float32: bit for bit, for a compact cloud and for one whose cells span more than an int64
    can index (1 mm cells over 2 km)."""
    from spotlights.geometry.sampling import voxel_downsample

    rng = np.random.default_rng(7)
    for p, v in ((rng.normal(size=(3000, 3)) * 0.4, 0.1), (rng.uniform(-1000, 1000, (500, 3)), 1e-3)):
        q = p[np.lexsort((p[:, 2], p[:, 1], p[:, 0]))]
        sums: dict = {}
        for row in q:
            k = tuple(int(x) for x in np.floor(row / v))
            acc = sums.setdefault(k, [0.0, 0.0, 0.0, 0])
            for j in range(3):
                acc[j] += float(row[j])
            acc[3] += 1
        want = np.array([[acc[j] / acc[3] for j in range(3)] for _, acc in sorted(sums.items())]).astype(np.float32)
        np.testing.assert_array_equal(voxel_downsample(p, v), want)


def test_voxel_downsample_against_the_definition():
    """Centroid of each occupied cell (brute force over a dict of cells); order-independent, bit for bit; a dense and
    a sparse sampling of one surface give nearly the same cloud, two fixed-count subsets of it do not."""
    from spotlights.geometry.sampling import voxel_downsample

    rng = np.random.default_rng(3)
    p = rng.normal(size=(2000, 3)) * 0.4
    got = voxel_downsample(p, 0.1)
    cells: dict = {}
    for q in p:
        cells.setdefault(tuple(np.floor(q / 0.1).astype(int)), []).append(q)
    want = np.array([np.mean(cells[k], axis=0) for k in sorted(cells)], dtype=np.float32)
    assert got.shape == want.shape and np.allclose(got, want, atol=1e-6)
    np.testing.assert_array_equal(voxel_downsample(p[rng.permutation(len(p))], 0.1), got)
    assert voxel_downsample(np.zeros((0, 3)), 0.1).shape == (0, 3)
    with pytest.raises(Exception, match="voxel size"):
        voxel_downsample(p, 0.0)
    with pytest.raises(Exception, match="too small"):
        voxel_downsample(p, 1e-30)
    # one plane z = 0 sampled at two densities: the voxel clouds nearly agree (centroids of 0.1 cells)
    dense, sparse = rng.uniform(0, 1, (20000, 2)), rng.uniform(0, 1, (1500, 2))
    dense, sparse = (np.c_[x, np.zeros(len(x))] for x in (dense, sparse))
    vd, vs = voxel_downsample(dense, 0.1), voxel_downsample(sparse, 0.1)
    cd = D.chamfer_distance(vd, vs)
    sub = D.chamfer_distance(dense[rng.choice(20000, 100, replace=False)], dense[rng.choice(20000, 100, replace=False)])
    assert len(vd) == len(vs) == 100 and cd < 0.5 * sub
