"""The grown-box clamp (spotlights.geometry.box_clamp) on a synthetic long box, 16 x 2.5 x 4 m."""

from __future__ import annotations

import math

import numpy as np
import pytest

from spotlights.errors import ParameterError
from spotlights.geometry.box_clamp import (
    clamp_points_to_box,
    clamp_to_grown_boxes,
    clip_depths_to_box,
    exit_depths,
    grown_half_extents,
    ray_box_interval,
)
from spotlights.learning.inference import complete_in_boxes

from helpers import slab_interval

SIZE = np.array([16.0, 2.5, 4.0])
R = math.sqrt(16.0**2 + 2.5**2 + 4.0**2) / 2  # 8.3403...
# grown by 0.15 m: half-extents 8.15, 1.40, 2.15 m, in the unit frame / R
HX, HY, HZ = 8.15 / R, 1.40 / R, 2.15 / R


def test_grown_half_extents_by_hand():
    np.testing.assert_allclose(grown_half_extents(SIZE), [HX, HY, HZ], rtol=1e-15)
    np.testing.assert_allclose(grown_half_extents(SIZE[None], margin=0.0), [SIZE / 2 / R], rtol=1e-15)
    with pytest.raises(ParameterError):
        grown_half_extents([16.0, 0.0, 4.0])


def test_exit_depths_by_hand():
    half = np.array([HX, HY, HZ])
    s2 = math.sqrt(2.0)
    origins = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0, 1.0, 0]])
    dirs = np.array([[-1.0, 0, 0], [0, -1.0, 0], [1 / s2, 0, -1 / s2], [0, 0, -1.0]])
    t_in, t_out = ray_box_interval(origins, dirs, half)
    # along -x from (1, 0, 0): in at x = HX, out at x = -HX
    assert t_in[0] == pytest.approx(1 - HX, abs=1e-15) and t_out[0] == pytest.approx(1 + HX, abs=1e-15)
    # along -y from (0, 1, 0): in at y = HY, out at y = -HY
    assert t_in[1] == pytest.approx(1 - HY, abs=1e-15) and t_out[1] == pytest.approx(1 + HY, abs=1e-15)
    # from the top (0, 0, 1) forward and down at 45 deg: in through the top z = HZ at t = s2 (1 - HZ),
    # out through the front x = HX at t = s2 HX (before the bottom, at s2 (1 + HZ))
    assert t_in[2] == pytest.approx(s2 * (1 - HZ), abs=1e-15)
    assert t_out[2] == pytest.approx(s2 * HX, abs=1e-15) and s2 * HX < s2 * (1 + HZ)
    # straight down from (0, 1, 0): y = 1 > HY, the ray misses the box
    assert t_in[3] > t_out[3]
    np.testing.assert_allclose(exit_depths(origins, dirs, half), [(1 + HX) / 2, (1 + HY) / 2, s2 * HX / 2, 0.0])


def test_ray_box_interval_matches_an_independent_slab_test():
    rng = np.random.default_rng(0)
    half = np.array([HX, HY, HZ])
    o = rng.normal(size=(500, 3))
    o /= np.linalg.norm(o, axis=1, keepdims=True)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a = ray_box_interval(o, d, half)
    b = slab_interval(o, d, -half, half)
    np.testing.assert_allclose(a[0], b[0], rtol=1e-12)
    np.testing.assert_allclose(a[1], b[1], rtol=1e-12)


def test_clip_depths_by_hand():
    half = np.array([HX, HY, HZ])
    o = np.array([[1.0, 0, 0]] * 4 + [[0, 1.0, 0]])
    u = np.array([[-1.0, 0, 0]] * 4 + [[0, 0, -1.0]])
    # along -x: beyond the exit, before the entry, inside, a miss; a hit on a ray that misses the box
    d = np.array([0.99, 0.01, 0.5, 0.0, 0.3])
    clipped, share = clip_depths_to_box(d, o, u, half)
    np.testing.assert_allclose(clipped, [(1 + HX) / 2, (1 - HX) / 2, 0.5, 0.0, 0.0], rtol=1e-15)
    assert share == pytest.approx(1 / 4)  # of the four hits, one was inside
    pts = o + 2 * clipped[:, None] * u
    assert np.all(np.abs(pts[:3]) <= half + 1e-12)


def test_clamp_points_projects_onto_the_box():
    half = np.array([HX, HY, HZ])
    rng = np.random.default_rng(1)
    p = rng.uniform(-1.2, 1.2, size=(4000, 3)).astype(np.float32)
    inside = np.all(np.abs(p.astype(np.float64)) <= half, axis=1)
    out, share = clamp_points_to_box(p, half)
    assert out.dtype == np.float32
    assert share == pytest.approx(inside.mean()) and 0 < share < 0.5
    assert np.all(np.abs(out.astype(np.float64)) <= half)  # exactly, in float32
    assert np.array_equal(out[inside], p[inside])
    # the nearest point of the box: the distance moved equals the exact point-to-box distance
    q = np.abs(p.astype(np.float64)) - half
    dist = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    np.testing.assert_allclose(np.linalg.norm(out - p, axis=1), dist, atol=1e-6)
    assert clamp_points_to_box(np.zeros((0, 3)), half)[1] == 1.0


class _Outside:
    """A completer whose points lie on a long line through the box, most of them outside it."""

    needs_box = False

    def complete(self, partials, clip=None):
        line = np.linspace(-1.5, 1.5, 301)[:, None] * np.array([[1.0, 0.3, 0.3]])
        return [line.astype(np.float32) for _ in partials]


def test_complete_in_boxes_holds_the_grown_box_and_reports_the_share():
    sizes = np.array([SIZE, [4.5, 1.8, 1.5]])
    shares: list = []
    outs = complete_in_boxes(_Outside(), np.zeros((2, 256, 3), np.float32), sizes, inside=shares)
    for c, size in zip(outs, sizes):
        half = grown_half_extents(size)
        assert np.all(np.abs(c.astype(np.float64)) <= half)
        assert np.all(np.linalg.norm(c.astype(np.float64), axis=1) <= 1.0)
    # by hand for the long box: t in [-1.5, 1.5] with |t| <= HX, |0.3 t| <= HY, |0.3 t| <= HZ: |t| <= min(HX, HY / 0.3)
    t = np.linspace(-1.5, 1.5, 301).astype(np.float32).astype(np.float64)
    lim = min(HX, HY / 0.3, HZ / 0.3)
    line = t[:, None] * np.array([1.0, 0.3, 0.3])
    expect = float(np.mean(np.all(np.abs(line.astype(np.float32).astype(np.float64)) <= [HX, HY, HZ], axis=1)))
    assert shares[0] == pytest.approx(expect) and expect == pytest.approx(np.mean(np.abs(t) <= lim), abs=0.01)
    assert len(shares) == 2
    # the same through the geometry function
    again, shares2 = clamp_to_grown_boxes(_Outside().complete([0, 0]), sizes)
    assert shares2 == shares and all(np.array_equal(a, b) for a, b in zip(again, outs))


def test_clamp_points_at_the_float32_edge_of_the_box():
    """Points on, one float32 step inside and one step outside the box's face (float64 half-extents that are not
    float32 numbers): inside exactly when |p| <= half in float64, as the definition says."""
    half = np.array([HX, HY, HZ])
    h32 = half.astype(np.float32)
    below = np.where(h32.astype(np.float64) > half, np.nextafter(h32, np.float32(0)), h32)  # largest float32 <= half
    above = np.nextafter(below, np.float32(2))
    p = np.zeros((6, 3), np.float32)
    for axis in range(3):
        p[2 * axis, axis] = below[axis]
        p[2 * axis + 1, axis] = -above[axis]
    truth = np.all(np.abs(p.astype(np.float64)) <= half, axis=1)  # the definition, in float64
    assert truth.tolist() == [True, False] * 3
    out, share = clamp_points_to_box(p, half)
    assert share == pytest.approx(truth.mean())
    assert np.array_equal(out[truth], p[truth])
    assert np.all(np.abs(out.astype(np.float64)) <= half)
    # all inside: the points come back unchanged, share 1
    same, share = clamp_points_to_box(p[truth], half)
    assert share == 1.0 and np.array_equal(same, p[truth])
    # NaN stays NaN and counts as outside
    nan = np.array([[np.nan, 0, 0], [0.0, 0, 0]], np.float32)
    out, share = clamp_points_to_box(nan, half)
    assert share == 0.5 and np.isnan(out[0, 0]) and np.array_equal(out[1], nan[1])
