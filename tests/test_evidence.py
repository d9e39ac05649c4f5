"""Per-ray evidence (geometry/evidence.py, learning/evidence.py) against brute-force loops and hand computations,
and the ray-local SA-Net's free-space decoding."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from spotlights.geometry.boxes import unit_extents
from spotlights.geometry.evidence import (
    EvidenceParams,
    carved_depths,
    free_space_decode,
    near_ray_evidence,
    nearest_per_cell,
    sensor_extent,
    stereo_frames,
)
from spotlights.geometry.rig import RigSpec
from spotlights.learning import evidence as tev

PARAMS = EvidenceParams(near_cells=6, radius=0.3, carve_cells=5, carve_samples=6, margin=0.02)


def tiny_scan(seed=0, k=12):
    """A small box rig (4 viewpoints x 8 rays aimed at a car-like box) and points on two of its faces."""
    spec = RigSpec.from_name("box-4x8-ellipsoid-s1")
    e = unit_extents([4.6, 1.9, 1.6])
    rig = spec.for_box(e)
    rng = np.random.default_rng(seed)
    p = rng.uniform(-1, 1, (k, 3)) * e
    p[: k // 2, 0] = e[0]
    p[k // 2 :, 1] = e[1]
    return np.array(rig.origins), np.array(rig.directions), p, spec.n_secondary


def brute_cell(x, centre, extent, cells):
    """Grid cell of the direction from ``centre`` to ``x``, by the definition, one vector at a time."""
    u, v, w = stereo_frames(np.asarray(centre, dtype=np.float64))
    dvec = np.asarray(x, dtype=np.float64) - centre
    dvec = dvec / np.linalg.norm(dvec)
    s = np.array([dvec @ u, dvec @ v]) / (1.0 + dvec @ w)
    q = (s + extent) / (2 * extent) * cells
    if not (0 <= q[0] < cells and 0 <= q[1] < cells):
        return None
    return int(math.floor(q[0])), int(math.floor(q[1]))


def brute_near(points, origins, directions, m, params):
    """The near-ray evidence by loops over rays and points (the module docstring's definition)."""
    g = params.near_cells
    extent = 0.0
    for o, d in zip(origins, directions):  # the largest stereographic radius of any ray
        u, v, w = stereo_frames(o)
        extent = max(extent, abs(d @ u) / (1 + d @ w), abs(d @ v) / (1 + d @ w))
    out = []
    for r, (o, d) in enumerate(zip(origins, directions)):
        view = origins[(r // m) * m]
        cells = {}
        for j, x in enumerate(points):
            c = brute_cell(x, view, extent, g)
            if c is None:
                continue
            rho = np.linalg.norm(x - view)
            if c not in cells or rho < cells[c][0]:
                cells[c] = (rho, j)
        u, v, w = stereo_frames(view)
        s = np.array([d @ u, d @ v]) / (1.0 + d @ w)
        q = (s + extent) / (2 * extent) * g
        bx, by = math.floor(q[0] - 0.5), math.floor(q[1] - 0.5)
        cands = []
        for dx, dy in ((0, 0), (0, 1), (1, 0), (1, 1)):
            c = (bx + dx, by + dy)
            if c in cells:
                x = points[cells[c][1]]
                t = 0.5 * (x - o) @ d
                delta = np.linalg.norm(x - o - 2 * t * d)
                if t > 0 and delta <= params.radius:
                    cands.append((delta, t))
        out.append(sorted(cands))
    return out


def test_near_ray_evidence_matches_a_brute_force_loop():
    o, d, p, m = tiny_scan()
    ev = near_ray_evidence(p, o, d, m, PARAMS)
    te = tev.ray_evidence(
        torch.from_numpy(p)[None], torch.from_numpy(o), torch.from_numpy(d)[None], None, m, PARAMS
    )  # float64 tensors: the same arithmetic as numpy
    want = brute_near(p, o, d, m, PARAMS)
    assert sum(len(w) for w in want) >= 5  # the case exercises candidates
    for r, w in enumerate(want):
        assert ev["count"][r] == len(w) == int(te["count"][0, r])
        for i, (delta, t) in enumerate(w):
            assert ev["valid"][r, i] and bool(te["valid"][0, r, i])
            assert ev["distance"][r, i] == pytest.approx(delta, abs=1e-12)
            assert ev["depth"][r, i] == pytest.approx(t, abs=1e-12)
            assert float(te["distance"][0, r, i]) == pytest.approx(delta, abs=1e-12)
            assert float(te["depth"][0, r, i]) == pytest.approx(t, abs=1e-12)
        assert not ev["valid"][r, len(w) :].any()


def test_a_point_on_a_ray_is_found_at_its_depth():
    """Hand case: a point placed on a ray's line at depth 0.3 is that ray's first candidate, distance 0."""
    o, d, p, m = tiny_scan()
    r = 5
    x = o[r] + 2 * 0.3 * d[r]
    ev = near_ray_evidence(np.vstack([p, x]), o, d, m, PARAMS)
    assert ev["valid"][r, 0]
    assert ev["depth"][r, 0] == pytest.approx(0.3, abs=1e-12)
    assert ev["distance"][r, 0] == pytest.approx(0.0, abs=1e-9)


def test_carved_bins_from_a_hand_placed_sensor():
    """Sensor at S = (3, 0, 0), one observed point X = (0.5, 0, 0): the segment S-X is empty. The ray from
    o = (0.8, 0.6, 0) along -y (|o| = 1) crosses it at (0.8, 0, 0), 2.2 from S, in front of X: carved there."""
    params = EvidenceParams(carve_cells=9, carve_samples=10, margin=0.02)
    s = np.array([3.0, 0.0, 0.0])
    x = np.array([[0.5, 0.0, 0.0]])
    o = np.array([[0.8, 0.6, 0.0]])
    d = np.array([[0.0, -1.0, 0.0]])
    res = carved_depths(x, o, d, s, params)
    h = 0.6  # half chord: -o.d
    assert res["half_chord"][0] == pytest.approx(h)
    t = (np.arange(10) + 0.5) / 10 * h
    assert np.allclose(res["sample_depth"][0], t)
    # by hand: sample y = o + 2 t d = (0.8, 0.6 - 2t, 0); seen from S its direction is (-2.2, 0.6 - 2t, 0), and X's
    # is (-2.5, 0, 0) (the axis). X's cell is the central one (9 cells over [-a, a], a = tan(asin(1/3) / 2)); y
    # falls in it when |stereo| < a / 9, i.e. |0.6 - 2t| / (|y - S| + 2.2) < a / 9 (for the axis frame w = -x)
    a = math.tan(0.5 * math.asin(1 / 3))
    assert sensor_extent(s) == pytest.approx(a)
    dist = np.hypot(2.2, 0.6 - 2 * t)
    in_cell = np.abs(0.6 - 2 * t) / (dist + 2.2) < a / 9
    want = in_cell & (dist < 2.5 - 0.02)
    assert want.any() and not want.all()
    assert np.array_equal(res["carved"][0], want)
    te = tev.ray_evidence(
        torch.from_numpy(x)[None], torch.from_numpy(o), torch.from_numpy(d)[None], torch.from_numpy(s)[None], 1, params
    )
    assert np.array_equal(te["carved"][0, 0].numpy(), want)
    # unknown sensor: nothing carved
    assert not carved_depths(x, o, d, np.full(3, np.nan), params)["carved"].any()
    # behind the observed point (the ray from (-0.8, 0.6, 0)): never carved
    assert not carved_depths(x, -o * [1, -1, 1], d, s, params)["carved"].any()


def test_carved_depths_match_a_brute_force_loop():
    o, d, p, _ = tiny_scan(seed=1, k=40)
    s = np.array([2.5, 1.5, 0.4])
    res = carved_depths(p, o, d, s, PARAMS)
    a = sensor_extent(s)
    nearest = {}
    for xj in p:
        c = brute_cell(xj, s, a, PARAMS.carve_cells)
        rho = np.linalg.norm(xj - s)
        if c is not None and rho < nearest.get(c, np.inf):
            nearest[c] = rho
    want = np.zeros_like(res["carved"])
    for r in range(len(o)):
        h = max(0.0, -(o[r] @ d[r]))
        for j in range(PARAMS.carve_samples):
            y = o[r] + 2 * (j + 0.5) / PARAMS.carve_samples * h * d[r]
            c = brute_cell(y, s, a, PARAMS.carve_cells)
            want[r, j] = c in nearest and np.linalg.norm(y - s) < nearest[c] - PARAMS.margin
    assert want.sum() >= 3
    assert np.array_equal(res["carved"], want)
    te = tev.ray_evidence(
        torch.from_numpy(p)[None].float(),
        torch.from_numpy(o).float(),
        torch.from_numpy(d)[None].float(),
        torch.from_numpy(s)[None].float(),
        8,
        PARAMS,
    )
    assert (te["carved"][0].numpy() != want).mean() < 0.02  # float32: a sample on a cell border may flip


def test_free_space_decode_moves_surfaces_out_of_carved_bins():
    carved = np.array([[False, True, True, False], [False, True, True, True], [True, False, False, False]])
    h = np.array([1.0, 1.0, 0.8])
    depth = np.array([0.3, 0.6, 0.5])  # bins 1, 2 and 2 (of 4)
    keep = np.array([True, True, True])
    nd, nk = free_space_decode(depth, keep, carved, h)
    assert nd[0] == pytest.approx(0.75)  # next free bin 3 starts at 3/4 h
    assert not nk[1]  # every bin after it is carved: dropped
    assert nd[2] == pytest.approx(0.5) and nk[2]  # not in a carved bin: unchanged
    td, tk = tev.free_space_decode(torch.tensor(depth), torch.tensor(keep), torch.tensor(carved), torch.tensor(h))
    assert np.allclose(td.numpy()[[0, 2]], nd[[0, 2]]) and np.array_equal(tk.numpy(), nk)


def test_batched_free_space_decode_matches_the_numpy_reference():
    """The torch decoding (only the rays whose surface is in a carved bin are moved) against the geometry layer's
    (a reversed running minimum over every ray) on random carved bins: depths outside [0, h], h = 0, kept and
    dropped rays, a batch and a single scan."""
    rng = np.random.default_rng(0)
    carved = rng.random((3, 200, 5)) < 0.5
    carved[:, :10] = True  # every bin carved: dropped when kept
    h = rng.uniform(0.2, 1.0, (3, 200))
    h[:, 10:15] = 0.0
    depth = rng.uniform(-0.2, 1.2, (3, 200))
    keep = rng.random((3, 200)) < 0.7
    nd, nk = free_space_decode(depth, keep, carved, h)
    td, tk = tev.free_space_decode(*(torch.from_numpy(a) for a in (depth, keep, carved, h)))
    assert np.array_equal(td.numpy(), nd) and np.array_equal(tk.numpy(), nk)
    assert (nd != np.clip(depth, 0, h)).sum() > 100 and (keep & ~nk).sum() > 10  # moved and dropped rays
    one = tev.free_space_decode(*(torch.from_numpy(a[1]) for a in (depth, keep, carved, h)))
    assert np.array_equal(one[0].numpy(), nd[1]) and np.array_equal(one[1].numpy(), nk[1])


def test_sanet_local_puts_no_surface_inside_observed_free_space():
    """A ray whose line crosses the LiDAR's view of a wall in front of the wall: whatever the network predicts
    there, the decoded point is not inside the carved interval."""
    from spotlights.geometry.rig import make_rig
    from spotlights.learning.models import build_model, load_config

    rig = make_rig(8, 16, 60.0)
    cfg = load_config(
        "sanet-local",
        overrides={
            "model": {"args": {"code_size": 32, "encoder_widths": [8, 16, 32], "hidden": [16], "local_hidden": [8]}}
        },
    )
    torch.manual_seed(0)
    model = build_model(cfg, rig=rig).eval()
    # a wall of points at x = -0.5 (y, z in [-0.3, 0.3]) seen by a LiDAR at (3, 0, 0): free space x in (-0.5, 3)
    g = np.linspace(-0.3, 0.3, 16)
    wall = np.array([[-0.5, y, z] for y in g for z in g])[::1]
    wall = wall[np.random.default_rng(0).choice(len(wall), 256, replace=False)]
    sensor = np.array([3.0, 0.0, 0.0])
    partial = torch.from_numpy(wall).float()[None]
    out = model(partial, None, torch.from_numpy(sensor).float()[None])
    carved = out["carved"][0].numpy()
    assert carved.any()
    o, d = rig.origins, rig.directions
    h = out["half_chord"][0].numpy()
    t_bins = carved.shape[1]
    # force every ray to hit at the centre of its first carved bin (or 0.5 h if it has none)
    first = np.where(carved.any(1), carved.argmax(1), -1)
    depth = np.where(first >= 0, (first + 0.5) / t_bins * h, 0.5 * h)
    forced = dict(
        out, hit_logits=torch.full_like(out["hit_logits"], 10.0), depths=torch.from_numpy(depth)[None].float()
    )
    pts = model.outputs_to_points(forced)[0].numpy()
    moved = 0
    for r in np.flatnonzero(first >= 0):
        run_end = first[r]
        while run_end < t_bins and carved[r, run_end]:
            run_end += 1
        lo, hi = first[r] / t_bins * h[r], run_end / t_bins * h[r]
        assert lo <= depth[r] < hi  # the forced surface lay inside the carved interval
        forced_hit = o[r] + 2 * depth[r] * d[r]
        assert not np.any(np.all(np.isclose(pts, forced_hit, atol=1e-5), axis=1))
        if run_end < t_bins:  # moved to the far end of the carved interval
            assert np.any(np.all(np.isclose(pts, o[r] + 2 * hi * d[r], atol=1e-5), axis=1))
            moved += 1
    assert moved > 0
    assert len(pts) == int((first < 0).sum()) + moved  # rays without free space keep their hit


def test_evidence_features_shape():
    o, d, p, m = tiny_scan()
    ev = tev.ray_evidence(
        torch.from_numpy(p)[None].float(), torch.from_numpy(o), torch.from_numpy(d)[None], None, m, PARAMS
    )
    f = tev.evidence_features(ev, PARAMS)
    assert f.shape == (1, len(o), tev.feature_count(PARAMS))
    assert not f[..., -PARAMS.carve_samples :].any()  # no sensor: nothing carved


def batch_of_scans(seed=2, b=4, k=40):
    """b scans of the tiny rig (each with its own box directions) and one sensor each: outside the sphere, inside
    it (|S| < 1: the whole disc), unknown (NaN), outside again and (b = 5) at the box's centre."""
    spec = RigSpec.from_name("box-4x8-ellipsoid-s1")
    rng = np.random.default_rng(seed)
    o = np.array(spec.origins)
    dirs, pts = [], []
    for _ in range(b):
        e = unit_extents(rng.uniform([3.5, 1.6, 1.3], [5.2, 2.1, 2.0]))
        dirs.append(np.array(spec.for_box(e).directions))
        p = rng.uniform(-1, 1, (k, 3)) * e
        p[: k // 2, 0] = e[0]
        p[k // 2 :, 1] = e[1]
        pts.append(p)
    sensors = np.array([[2.5, 1.5, 0.4], [0.6, 0.2, 0.1], [np.nan, 0.0, 0.0], [-1.8, 2.2, 0.9], [0.0, 0.0, 0.0]])[:b]
    return o, np.stack(dirs), np.stack(pts), sensors, spec.n_secondary


def test_batched_carving_matches_the_numpy_reference_for_every_sensor():
    """The torch path (one batch, the sensor handled in torch for torch.compile) against the geometry layer's numpy
    carving of each scan alone: float64, bin for bin; the LiDAR grid's extent and frame match numpy's."""
    o, d, p, s, m = batch_of_scans(b=5)
    assert not carved_depths(p[4], o, d[4], s[4], PARAMS)["carved"].any()  # a sensor at the centre carves nothing
    te = tev.ray_evidence(torch.from_numpy(p), torch.from_numpy(o), torch.from_numpy(d), torch.from_numpy(s), m, PARAMS)
    total = 0
    for i in range(len(p)):
        want = carved_depths(p[i], o, d[i], s[i], PARAMS)
        assert np.array_equal(te["carved"][i].numpy(), want["carved"])
        assert np.allclose(te["half_chord"][i].numpy(), want["half_chord"], rtol=0, atol=1e-15)
        total += int(want["carved"].sum())
    assert total >= 5 and not te["carved"][2].any()  # the case carves, and an unknown sensor carves nothing
    known = s[[0, 1, 3]]
    ext = tev.sensor_extent_torch(torch.from_numpy(known)).numpy()
    assert ext.tolist() == [sensor_extent(x) for x in known]  # bit for bit: 1 inside the sphere
    assert ext[1] == 1.0 and ext[0] == pytest.approx(math.tan(0.5 * math.asin(1 / np.linalg.norm(known[0]))))
    assert np.allclose(tev.stereo_frames_torch(torch.from_numpy(known)).numpy(), stereo_frames(known), atol=1e-15)


class GraphCounter:
    """A torch.compile backend that runs each captured graph as it is and counts them (public API only)."""

    def __init__(self):
        self.graphs = 0

    def __call__(self, gm, example_inputs):
        self.graphs += 1
        return gm.forward


def test_evidence_traces_into_one_graph_for_any_batch_of_the_same_shape():
    """torch.compile captures the whole evidence (fullgraph: no host round trip, no graph break) and new values
    (points, boxes, sensors, an unknown one) reuse that graph: no recompilation, the eager results."""
    o, d, p, s, m = batch_of_scans(seed=3)
    torch.compiler.reset()
    counter = GraphCounter()
    fn = torch.compile(tev.ray_evidence, fullgraph=True, backend=counter, dynamic=False)
    ot = torch.from_numpy(o).float()
    fn(torch.from_numpy(p).float(), ot, torch.from_numpy(d).float(), torch.from_numpy(s).float(), m, PARAMS)
    with torch.compiler.set_stance("fail_on_recompile"):
        for seed in (4, 5, 6):
            o2, d2, p2, s2, _ = batch_of_scans(seed=seed)
            s2 = s2[::-1].copy() * (1.0 + 0.1 * seed)  # other sensors, the unknown one elsewhere
            args = (torch.from_numpy(p2).float(), ot, torch.from_numpy(d2).float(), torch.from_numpy(s2).float(), m)
            got, want = fn(*args, PARAMS), tev.ray_evidence(*args, PARAMS)
            assert want["carved"].any() and want["valid"].any()
            for key in want:
                assert torch.equal(got[key], want[key]), key
    assert counter.graphs == 1
    torch.compiler.reset()


def test_compiled_sanet_local_does_not_recompile_per_batch():
    """The training forward and backward of a compiled ray-local SA-Net over 12 random batches (boxes, sensors,
    unknown sensors): after the second batch (the per-ray MLP's row count becomes dynamic) nothing is traced
    again, 3 graphs in all, and the outputs are the eager model's."""
    from spotlights.learning.models import build_model, load_config
    from spotlights.learning.rays import directions_for_extents

    spec = RigSpec.from_name("box-4x8-ellipsoid-s1")
    args = {"code_size": 16, "encoder_widths": [8, 8, 16], "hidden": [8], "candidate_width": 4, "local_hidden": [4]}
    torch.manual_seed(0)
    model = build_model(load_config("sanet-local", overrides={"model": {"args": args}}), rig=spec).train()
    torch.compiler.reset()
    counter = GraphCounter()
    compiled = torch.compile(model, backend=counter)
    rng = np.random.default_rng(0)
    for i in range(12):
        e = unit_extents(rng.uniform([3.5, 1.6, 1.3], [5.2, 2.1, 2.0], (2, 3)))
        dirs = torch.from_numpy(directions_for_extents(spec, e)).float()
        x = torch.from_numpy((rng.uniform(-1, 1, (2, 32, 3)) * e[:, None]).astype(np.float32))
        s = torch.from_numpy(rng.normal(size=(2, 3)).astype(np.float32) * 3)
        if i % 3 == 2:
            s[1] = float("nan")
        with torch.compiler.set_stance("fail_on_recompile" if i >= 2 else "default"):
            out = compiled(x, dirs, s)
        (out["hit_logits"].sum() + out["depths"].sum()).backward()
        with torch.no_grad():
            ref = model(x, dirs, s)
        assert torch.allclose(out["depths"], ref["depths"], atol=1e-6) and torch.equal(out["carved"], ref["carved"])
    assert counter.graphs == 3
    torch.compiler.reset()


def test_nearest_per_cell_against_a_loop_with_ties():
    rng = np.random.default_rng(3)
    keys = rng.integers(-1, 40, 2000)
    ranges = np.round(rng.uniform(0.0, 1.0, 2000), 2)  # rounded: many ties within a key
    got = nearest_per_cell(keys, ranges, 50)
    for key in range(50):
        rows = [i for i in range(len(keys)) if keys[i] == key]
        want = min(rows, key=lambda i: (ranges[i], i)) if rows else -1  # smallest range, then lowest index
        assert got[key] == want, key
    assert np.array_equal(nearest_per_cell(np.full(5, -1), np.ones(5), 3), [-1, -1, -1])
