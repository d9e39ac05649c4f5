"""The one box (geometry.boxes): corner order pinned against hand-written corners, vectorised corners, radius,
unit extents, containment and crop against brute force, frame transforms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from spotlights.errors import ParameterError
from spotlights.geometry.boxes import BOX_EDGES, CORNER_SIGNS, Box, corners, unit_extents


def test_corner_order_is_pinned_by_a_hand_written_box():
    # 4 x 2 x 1 box at (10, 5, 1), heading 90 degrees: its forward axis is +y, its left axis -x.
    box = Box([10.0, 5.0, 1.0], [4.0, 2.0, 1.0], yaw=math.pi / 2)
    hand = np.array(
        [
            [9.0, 7.0, 1.5],  # 0: front, left, top     (+l/2, +w/2, +h/2)
            [9.0, 7.0, 0.5],  # 1: front, left, bottom
            [11.0, 7.0, 1.5],  # 2: front, right, top
            [11.0, 7.0, 0.5],  # 3: front, right, bottom
            [9.0, 3.0, 1.5],  # 4: back, left, top
            [9.0, 3.0, 0.5],  # 5: back, left, bottom
            [11.0, 3.0, 1.5],  # 6: back, right, top
            [11.0, 3.0, 0.5],  # 7: back, right, bottom  (-l/2, -w/2, -h/2)
        ]
    )
    np.testing.assert_allclose(box.corners(), hand, atol=1e-12)
    # the 12 edges join corners one box dimension apart: 4 lengths, 4 widths, 4 heights
    lengths = sorted(round(float(np.linalg.norm(hand[a] - hand[b])), 9) for a, b in BOX_EDGES)
    assert lengths == [1.0] * 4 + [2.0] * 4 + [4.0] * 4
    assert CORNER_SIGNS[0].tolist() == [1, 1, 1] and CORNER_SIGNS[7].tolist() == [-1, -1, -1]


def test_corners_are_vectorised_over_many_boxes():
    rng = np.random.default_rng(1)
    boxes = [Box(rng.normal(size=3) * 10, rng.uniform(1, 5, 3), yaw=float(rng.uniform(-3, 3))) for _ in range(5)]
    many = corners([b.center for b in boxes], [b.size for b in boxes], [b.rotation for b in boxes])
    assert many.shape == (5, 8, 3)
    for b, k in zip(boxes, many):
        # each corner is the centre plus +-half a side along each of the box's own axes
        local = b.to_object(k)
        np.testing.assert_allclose(np.abs(local), np.broadcast_to(b.size / 2, (8, 3)), atol=1e-9)
        np.testing.assert_allclose(np.sign(local), CORNER_SIGNS)
    np.testing.assert_allclose(corners([0, 0, 0], [2, 4, 6])[0], [1, 2, 3])  # axis-aligned, no rotation


def test_radius_and_unit_extents():
    box = Box([0, 0, 0], [3.0, 4.0, 12.0])  # diagonal 13
    assert box.radius == 6.5
    np.testing.assert_allclose(box.unit_extents, [3 / 13, 4 / 13, 12 / 13])
    np.testing.assert_allclose(
        unit_extents([[3.0, 4.0, 12.0], [1.0, 0.0, 0.0]]), [[3 / 13, 4 / 13, 12 / 13], [1, 0, 0]]
    )
    np.testing.assert_allclose(unit_extents([2.0, 2.0, 1.0], radius=1.5), [2 / 3, 2 / 3, 1 / 3])
    for bad in ([0.0, 0.0, 0.0], [1.0, -1.0, 1.0], [np.nan, 1.0, 1.0]):
        with pytest.raises(ParameterError):
            unit_extents(bad)
    with pytest.raises(ParameterError, match=r"\(\.\.\., 3\)"):
        unit_extents([1.0, 2.0])


def test_contains_and_crop_match_brute_force():
    rng = np.random.default_rng(2)
    box = Box([5.0, -2.0, 0.5], [4.0, 2.0, 1.5], yaw=0.6)
    pts = rng.uniform(-3, 3, (4000, 3)) + box.center
    c, s = math.cos(0.6), math.sin(0.6)
    d = pts - box.center
    local = np.c_[c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]]  # rotate by -yaw by hand
    for margin, clearance in ((0.0, None), (0.3, None), (0.15, 0.1)):
        bottom = -0.75 - margin if clearance is None else -0.75 + clearance
        want = (
            (np.abs(local[:, 0]) <= 2 + margin)
            & (np.abs(local[:, 1]) <= 1 + margin)
            & (local[:, 2] <= 0.75 + margin)
            & (local[:, 2] >= bottom)
        )
        assert 200 < want.sum() < 3800
        np.testing.assert_array_equal(box.contains(pts, margin, clearance), want)
        np.testing.assert_array_equal(box.crop(pts, margin, clearance), np.flatnonzero(want))


def test_frame_transforms_round_trip():
    box = Box([1.0, 2.0, 3.0], [4.0, 2.0, 2.0], yaw=math.pi / 2)
    np.testing.assert_allclose(box.to_object([[1.0, 4.0, 3.0]]), [[2.0, 0.0, 0.0]], atol=1e-12)  # 2 m ahead
    np.testing.assert_allclose(box.to_unit(box.corners()) * box.radius, box.to_object(box.corners()), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(box.to_unit(box.corners()), axis=1), 1.0)
    p = np.random.default_rng(3).normal(size=(10, 3))
    np.testing.assert_allclose(box.from_unit(box.to_unit(p)), p, atol=1e-12)
    np.testing.assert_allclose(box.from_object(box.to_object(p)), p, atol=1e-12)
