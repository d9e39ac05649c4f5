"""The speed-ups of track completion give the same answers: one KD-tree crop for every box of a scan, and the
box rig's rays kept per box size."""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.geometry.boxes import Box, crop_boxes
from spotlights.geometry.rig import parse_rig
from spotlights.learning.rays import directions_for_extents


def brute_force_crop(points: np.ndarray, box: Box, margin: float, clearance: float) -> np.ndarray:
    """Indices of the points inside the box grown by ``margin``, bottom raised by ``clearance``, by hand."""
    idx = []
    half = 0.5 * box.size
    for i, p in enumerate(points):
        q = box.rotation.T @ (p - box.center)
        if (
            abs(q[0]) <= half[0] + margin
            and abs(q[1]) <= half[1] + margin
            and q[2] <= half[2] + margin
            and q[2] >= -half[2] + clearance
        ):
            idx.append(i)
    return np.array(idx, dtype=np.int64)


def test_one_tree_crop_equals_each_box_by_hand():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-8, 8, size=(3000, 3))
    boxes = [
        Box.from_yaw(rng.uniform(-6, 6, 3), rng.uniform(0.5, 4.5, 3), float(rng.uniform(-np.pi, np.pi)))
        for _ in range(12)
    ]
    got = crop_boxes(pts, boxes, 0.15, 0.10)
    for b, g in zip(boxes, got):
        want = brute_force_crop(pts, b, 0.15, 0.10)
        np.testing.assert_array_equal(g, want)
    assert sum(len(g) for g in got) > 0
    assert crop_boxes(np.zeros((0, 3)), boxes[:2])[0].shape == (0,)


def test_kept_rays_equal_fresh_rays_in_any_batch_order():
    rig = parse_rig("box-8x8-ellipsoid-s1")
    e = np.array([[0.8, 0.5, 0.33], [0.7, 0.6, 0.39], [0.9, 0.4, 0.17]])
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    first = directions_for_extents(rig, e)
    again = directions_for_extents(rig, e[::-1])[::-1]  # served from the kept rays
    for k in range(3):
        fresh = rig.for_box(e[k]).directions.astype(np.float32)
        np.testing.assert_array_equal(first[k], fresh)
        np.testing.assert_array_equal(again[k], fresh)
    np.testing.assert_allclose(np.linalg.norm(first, axis=-1), 1.0, atol=1e-6)


def test_few_query_tree_gives_brute_force_distances():
    from spotlights.geometry.neighbors import NearestNeighbors
    from spotlights.metrics.consistency import fidelity

    rng = np.random.default_rng(1)
    c = rng.normal(size=(3000, 3))
    p = rng.normal(size=(40, 3))
    brute = np.sqrt(((p[:, None, :] - c[None]) ** 2).sum(-1)).min(axis=1)
    np.testing.assert_allclose(NearestNeighbors(c, few_queries=True).distances(p), brute, rtol=0, atol=1e-12)
    assert fidelity(p, c) == pytest.approx(brute.mean(), abs=1e-12)
