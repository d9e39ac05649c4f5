"""Track fusion, window policies and box refinement (spotlights.data.tracks), against hand-built geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from spotlights.data.tracks import (
    FLAGGED,
    TrackFrame,
    check_track,
    fuse_track,
    parse_window,
    refine_track,
)
from spotlights.errors import ParameterError
from spotlights.geometry.boxes import Box

from builders import drive_past


def test_cube_seen_from_two_sides_fuses_both_sides_in_the_box_frame():
    # frame 0: a 2 m cube 10 m ahead, turned by 90 degrees, so its left side (+y) faces the sensor;
    # frame 1: 10 m to the left, not turned, so its right side (-y) faces the sensor.
    rng = np.random.default_rng(0)
    b0 = Box([10.0, 0.0, 0.0], [2.0, 2.0, 2.0], yaw=math.pi / 2)
    b1 = Box([0.0, 10.0, 0.0], [2.0, 2.0, 2.0], yaw=0.0)
    # scan-frame points on the face nearest the sensor, by hand: x = 9 (frame 0), y = 9 (frame 1)
    f0 = np.c_[np.full(50, 9.0), rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50)]
    f1 = np.c_[rng.uniform(-1, 1, 60), np.full(60, 9.0), rng.uniform(-1, 1, 60)]
    frames = [TrackFrame(f0, b0, np.zeros(3), 0.0), TrackFrame(f1, b1, np.zeros(3), 0.5)]
    fused = fuse_track(frames)
    assert fused.points.shape == (110, 3)
    np.testing.assert_array_equal(fused.frame_index, np.r_[np.zeros(50, int), np.ones(60, int)])
    # frame 0's face is the cube's left side (object y = +1), its coordinates (-(y), x - 10 -> 0 .. )
    np.testing.assert_allclose(fused.points[:50, 1], 1.0, atol=1e-12)
    np.testing.assert_allclose(fused.points[:50, 0], f0[:, 1], atol=1e-12)  # object x = scan y (turned 90 deg)
    np.testing.assert_allclose(fused.points[50:, 1], -1.0, atol=1e-12)  # frame 1: the right side
    np.testing.assert_allclose(fused.points[50:, 0], f1[:, 0], atol=1e-12)
    np.testing.assert_allclose(fused.points[:, 2], np.r_[f0[:, 2], f1[:, 2]], atol=1e-12)
    # the sensor, in each box frame: 10 m to the left of the first cube, 10 m to the right of the second
    np.testing.assert_allclose(fused.origins, [[0.0, 10.0, 0.0], [0.0, -10.0, 0.0]], atol=1e-12)
    np.testing.assert_array_equal(fused.counts, [50, 60])
    # a window fuses only its frames; a margin crop keeps only points inside the grown box
    one = fuse_track(frames, indices=[1])
    assert one.points.shape == (60, 3) and set(one.frame_index) == {1}
    stray = TrackFrame(np.r_[f0, [[20.0, 0.0, 0.0]]], b0, np.zeros(3), 0.0)
    assert len(fuse_track([stray], margin=0.15).points) == 50


@pytest.mark.parametrize(
    "spec,t,expected",
    [
        ("none", 3, [3]),
        ("all", 0, [0, 1, 2, 3, 4, 5]),
        ("past:3", 0, [0]),
        ("past:3", 1, [0, 1]),
        ("past:3", 4, [2, 3, 4]),
        ("past:1", 5, [5]),
        ("centered:3", 0, [0, 1]),
        ("centered:3", 2, [1, 2, 3]),
        ("centered:4", 2, [1, 2, 3, 4]),
        ("centered:3", 5, [4, 5]),
    ],
)
def test_window_policies_select_the_right_frames(spec, t, expected):
    assert parse_window(spec).select(6, t).tolist() == expected


def test_causal_window_never_looks_ahead():
    for k in (1, 2, 5, 9):
        pol = parse_window(f"past:{k}")
        assert pol.causal
        for n in (1, 4, 12):
            for t in range(n):
                sel = pol.select(n, t)
                assert sel.max() == t and len(sel) == min(k, t + 1)
    assert not parse_window("centered:3").causal and not parse_window("all").causal


@pytest.mark.parametrize("bad", ["past", "past:0", "past:x", "all:3", "centred:3", ""])
def test_bad_window_is_one_clear_error(bad):
    with pytest.raises(ParameterError, match="none, all, past:K or centered:K"):
        parse_window(bad)


def test_track_checks_gap_order_and_frame_count():
    check_track([0.0, 0.5, 1.0], max_gap_s=2.0)
    with pytest.raises(ParameterError, match=r"track 7 has a gap of 3 s .*limit 2 s"):
        check_track([0.0, 0.5, 3.5], max_gap_s=2.0, name="track 7")
    with pytest.raises(ParameterError, match="increasing time order"):
        check_track([0.0, 0.5, 0.5])
    with pytest.raises(ParameterError, match="1 frame.*at least 2"):
        check_track([0.0], min_frames=2)
    box = Box([0, 0, 0], [4, 2, 1.5], yaw=0.0)
    with pytest.raises(ParameterError, match="at least 2 frames"):
        refine_track([TrackFrame(np.zeros((20, 3)), box)])
    with pytest.raises(ParameterError, match="at least one frame"):
        fuse_track([])


def test_refinement_recovers_a_known_perturbation():
    # frame 1 (seen from the front-right: two faces) given 0.3 m off and turned by 5 degrees
    d = 0.3 / math.sqrt(2)
    frames, truth = drive_past({1: (d, -d, math.radians(5.0))})
    ref = refine_track(frames, "all", margin=0.8, ground_clearance=0.1)
    assert ref.status[1] == "refined"
    assert not ref.flagged.any()
    for b, t in zip(ref.boxes, truth):
        assert np.linalg.norm(b.center - t.center) < 0.02
        assert abs(math.degrees(math.remainder(b.yaw - t.yaw, 2 * math.pi))) < 0.5
        np.testing.assert_array_equal(b.size, t.size)
    assert ref.translation[1] == pytest.approx(0.3, abs=0.02)
    assert math.degrees(abs(ref.yaw[1])) == pytest.approx(5.0, abs=0.5)
    # re-fused with the refined boxes, the shape is sharp: every point within 2 cm of the true box surface
    fused = fuse_track(frames, boxes=ref.boxes)
    half = np.array([2.2, 0.9, 0.75])
    gap = np.min(np.abs(np.abs(fused.points) - half), axis=1)
    assert np.percentile(gap, 99) < 0.03
    smeared = fuse_track(frames)
    assert np.percentile(np.min(np.abs(np.abs(smeared.points) - half), axis=1), 99) > 0.1


def test_causal_refinement_uses_only_earlier_frames():
    # frame 5 (seen from behind) perturbed; with past:3 it registers to frames 3 and 4 (side; back and side);
    # frame 0 has no reference. A causal chain carries its earlier frames' residual drift (frame 4 registers
    # to frame 3, which shows only the side: 2 cm along it), hence 3 cm here
    frames, truth = drive_past({5: (0.2, 0.1, math.radians(-4.0))})
    ref = refine_track(frames, "past:3", margin=0.8, ground_clearance=0.1)
    assert ref.status[0] == "no_reference"
    assert ref.boxes[0] is frames[0].box
    assert np.linalg.norm(ref.boxes[5].center - truth[5].center) < 0.03
    assert abs(math.degrees(math.remainder(ref.boxes[5].yaw - truth[5].yaw, 2 * math.pi))) < 0.5
    # changing the last frame changes nothing before it
    frames2 = list(frames)
    frames2[6] = TrackFrame(frames[6].points, frames[6].box.replace(center=frames[6].box.center + 0.4))
    ref2 = refine_track(frames2, "past:3", margin=0.8, ground_clearance=0.1)
    for i in range(6):
        np.testing.assert_array_equal(ref2.boxes[i].center, ref.boxes[i].center)
    assert not np.array_equal(ref2.boxes[6].center, ref.boxes[6].center)


def test_frame_that_cannot_converge_keeps_its_box_and_is_flagged():
    frames, truth = drive_past({})
    # frame 2's box is 3 m off its points: nothing within reach of the reference shape
    bad = frames[2].box.replace(center=frames[2].box.center + [3.0, 0.0, 0.0])
    frames[2] = TrackFrame(frames[2].points, bad, frames[2].origin, frames[2].timestamp)
    ref = refine_track(frames, "all", margin=5.0, ground_clearance=0.1, rounds=1)
    assert ref.status[2] in FLAGGED and ref.flagged[2]
    assert ref.boxes[2] is bad and ref.translation[2] == 0.0
    # a correction beyond the bound is refused too: 0.3 m with a 0.1 m bound
    frames, truth = drive_past({1: (0.3, 0.0, 0.0)})
    ref = refine_track(frames, "all", max_translation=0.1, margin=0.8, ground_clearance=0.1, rounds=1)
    assert ref.status[1] == "exceeds_bound" and ref.boxes[1] is frames[1].box
    assert ref.proposed_translation[1] == pytest.approx(0.3, abs=0.03)
