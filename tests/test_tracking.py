"""The tracker: the Kalman step against a hand computation, the assignment against brute force, GIoU against closed
forms, scripted scenes (a crossing, a missed frame, a moving sensor), the writers, the metrics against a hand count,
the simulated detector, and the ``track`` command."""

from __future__ import annotations

import copy
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from spotlights.errors import ParameterError
from spotlights.geometry.boxes import Box
from spotlights.geometry.rotations import rigid_transform, rotation_z
from spotlights.tracking.association import assign, giou_matrix, giou_pairs, lateral_offsets
from spotlights.tracking.detections import DetectionFrame, read_generic_detections
from spotlights.tracking.evaluate import clear_mot
from spotlights.tracking.outputs import nuscenes_tracking_document, tracks_document
from spotlights.tracking.simulate import DetectorModel, box_velocities, simulate_detections
from spotlights.tracking.tracker import KalmanTrack, TrackerConfig, corrected_yaw, track_boxes, wrap_angle

from helpers import LIDAR, assert_user_error, need, run_cli

# --- the Kalman filter ---------------------------------------------------------------------------------------


def test_kalman_predict_update_by_hand():
    """x axis only: position 0, velocity 2, P = diag(1, 4), no process noise, R = 1, dt = 1, measurement 5.

    By hand: predicted x = 2, P' = [[1 + 4, 4], [4, 4]] = [[5, 4], [4, 4]]; gain K = P'[:, 0] / (5 + 1) = (5/6, 4/6);
    innovation 3: x = 2 + 2.5 = 4.5, v = 2 + 2 = 4; P = (I - K H) P' = [[5/6, 2/3], [2/3, 4/3]]."""
    cfg = TrackerConfig(accel_sigma=0.0, yaw_rate_sigma=0.0, size_rate_sigma=0.0, meas_sigma_xy=1.0)
    tr = KalmanTrack(np.array([0.0, 0, 0, 0, 4, 2, 1.5]), cfg, "1", "car", "car", "car", 0.9)
    tr.kf.x[7, 0] = 2.0
    tr.kf.P[0, 0], tr.kf.P[7, 7] = 1.0, 4.0
    tr.predict(1.0)
    assert tr.kf.x[0, 0] == pytest.approx(2.0)
    np.testing.assert_allclose(tr.kf.P[np.ix_([0, 7], [0, 7])], [[5, 4], [4, 4]])
    tr.update(np.array([5.0, 0, 0, 0, 4, 2, 1.5]), 0.5)
    assert tr.kf.x[0, 0] == pytest.approx(4.5) and tr.kf.x[7, 0] == pytest.approx(4.0)
    np.testing.assert_allclose(tr.kf.P[np.ix_([0, 7], [0, 7])], [[5 / 6, 2 / 3], [2 / 3, 4 / 3]], atol=1e-12)
    assert tr.score == pytest.approx(0.7) and tr.hits == 2


def test_kalman_process_noise_by_hand():
    """White acceleration sigma_a over dt: Q = sigma_a^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]] per axis."""
    cfg = TrackerConfig(accel_sigma=2.0, yaw_rate_sigma=0.1, size_rate_sigma=0.0)
    tr = KalmanTrack(np.zeros(7), cfg, "1", "car", "car", "car", 1.0)
    f, q = tr.transition(0.5)
    assert f[0, 7] == 0.5 and f[2, 9] == 0.5 and f[3, 3] == 1.0
    np.testing.assert_allclose(
        q[np.ix_([1, 8], [1, 8])], 4.0 * np.array([[0.5**4 / 4, 0.5**3 / 2], [0.5**3 / 2, 0.25]])
    )
    assert q[3, 3] == pytest.approx(0.05**2) and q[4, 4] == 0.0


def test_a_coasting_track_moves_only_with_a_velocity_told_from_standstill():
    """No process noise, P_v = diag(1, 1), dt = 1: a track that missed its last frame keeps its position when its
    velocity's Mahalanobis norm |v| / 1 is below coast_velocity_sigmas (2), and moves by v when it is above;
    a matched track, or coast_velocity_sigmas = 0, always moves by v."""
    quiet = dict(accel_sigma=0.0, yaw_rate_sigma=0.0, size_rate_sigma=0.0)

    def coasted(vx, misses, **kw):
        tr = KalmanTrack(
            np.array([0.0, 0, 0, 0, 4, 2, 1.5]), TrackerConfig(**quiet, **kw), "1", "car", "car", "car", 0.9
        )
        tr.kf.x[7, 0] = vx
        tr.kf.P[7:10, 7:10] = np.eye(3)
        tr.misses = misses
        tr.predict(1.0)
        return float(tr.kf.x[0, 0]), float(tr.kf.P[0, 0])

    p0 = 0.2**2  # the new track's position variance (meas_sigma_xy)
    assert coasted(0.5, 1) == pytest.approx((0.0, p0))  # 0.5 sigma: noise, stays (covariance not coupled)
    assert coasted(1.9, 3) == pytest.approx((0.0, p0))
    assert coasted(3.0, 1) == pytest.approx((3.0, p0 + 1.0))  # 3 sigma: moves by v, P_xx + P_vv
    assert coasted(0.5, 0) == pytest.approx((0.5, p0 + 1.0))  # matched last frame: moves
    assert coasted(0.5, 1, coast_velocity_sigmas=0.0) == pytest.approx((0.5, p0 + 1.0))
    with pytest.raises(ParameterError, match="coast_velocity_sigmas"):
        TrackerConfig(coast_velocity_sigmas=-1.0)


def test_yaw_wrapping_and_flip():
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert corrected_yaw(math.radians(179), math.radians(-179)) == pytest.approx(math.radians(-181))
    # a heading turned around (170 degrees off) is the same box: turned back to 10 degrees off
    assert corrected_yaw(math.radians(190), 0.0) == pytest.approx(math.radians(10))
    assert corrected_yaw(math.radians(-100), 0.0) == pytest.approx(math.radians(80))


# --- association -----------------------------------------------------------------------------------------------


def _row(x=0.0, y=0.0, z=0.0, yaw=0.0, length=1.0, w=1.0, h=1.0):
    return [x, y, z, yaw, length, w, h]


def test_giou_closed_forms():
    a = np.array([_row(), _row(), _row(), _row(), _row(length=4, w=2, yaw=0.7), _row()])
    b = np.array(
        [_row(), _row(x=0.5), _row(x=5.0), _row(z=0.5), _row(length=4, w=2, yaw=0.7 + math.pi), _row(yaw=math.pi / 2)]
    )
    g = giou_pairs(a, b)
    assert g[0] == pytest.approx(1.0)  # identical
    assert g[1] == pytest.approx(1 / 3)  # I 0.5, U 1.5, C 1.5
    assert g[2] == pytest.approx(-(6 - 2) / 6)  # disjoint: I 0, U 2, C 6
    assert g[3] == pytest.approx(1 / 3)  # shifted up by half its height
    assert g[4] == pytest.approx(1.0)  # turned around: the same box
    assert g[5] == pytest.approx(1.0)  # a unit cube turned by 90 degrees
    # a square turned by 45 degrees inside the hull of the other: I = area of the regular octagon overlap
    (g45,) = giou_pairs(np.array([_row()]), np.array([_row(yaw=math.pi / 4)]))
    octagon = 2 * (math.sqrt(2) - 1)  # the overlap: the unit square less four corners of legs 1 - sqrt(2)/2
    hull = 0.5 * 8 * 0.5 * math.sin(math.pi / 4)  # the 8 corners lie on a circle of radius sqrt(2)/2, 45 deg apart
    union = 2 - octagon
    assert g45 == pytest.approx(octagon / union - (hull - union) / hull)
    m = giou_matrix(np.array([_row(), _row(x=20.0)]), np.array([_row(x=0.5)]), gate_m=3.0)
    assert m[0, 0] == pytest.approx(1 / 3) and m[1, 0] == -np.inf


def _brute_force(sim: np.ndarray, thr: float) -> float:
    """The best summed margin over one-to-one matchings (every permutation of columns over rows)."""
    n, m = sim.shape
    best = 0.0
    k = max(n, m)
    pad = np.full((k, k), -np.inf)
    pad[:n, :m] = sim
    for perm in itertools.permutations(range(k)):
        total = sum(pad[r, c] - thr for r, c in enumerate(perm) if pad[r, c] > thr)
        best = max(best, total)
    return best


@pytest.mark.parametrize("seed", range(6))
def test_assignment_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    sim = rng.uniform(-1, 1, size=(4, 5))
    sim[rng.random(sim.shape) < 0.3] = -np.inf
    pairs = assign(sim, -0.2)
    assert len({r for r, _ in pairs}) == len(pairs) == len({c for _, c in pairs})
    assert all(sim[r, c] > -0.2 for r, c in pairs)
    assert sum(sim[r, c] + 0.2 for r, c in pairs) == pytest.approx(_brute_force(sim, -0.2))


def test_assignment_tiny_case_by_hand():
    # the greedy pick (0, 0) = 0.9 leaves row 1 unmatched; the optimum pairs (0, 1) and (1, 0)
    sim = np.array([[0.9, 0.8], [0.7, -np.inf]])
    assert assign(sim, 0.0) == [(0, 1), (1, 0)]
    assert assign(np.array([[-0.5]]), 0.0) == [] and assign(np.zeros((0, 3)), 0.0) == []


# --- scripted scenes ------------------------------------------------------------------------------------------


def _car(x, y, yaw, score=0.9, cls="car") -> Box:
    return Box([x, y, 0.0], [4.5, 1.9, 1.6], rotation_z(yaw), cls, cls, "", score)


def _ids_along(tracked, truth_xy, tol=1.0) -> set[str]:
    """Track ids of the boxes within ``tol`` metres of each frame's true position (per frame: one (x, y))."""
    ids = set()
    for f, (x, y) in zip(tracked, truth_xy):
        ids |= {b.track_id for b in f.boxes if math.hypot(b.center[0] - x, b.center[1] - y) < tol}
    return ids


def test_two_crossing_cars_keep_their_ids():
    """Two cars on an X, 10 Hz, 10 m/s, passing the crossing 0.4 s apart (4 m apart when the second arrives)."""
    a = [(-20 + 1.0 * k * math.cos(0.5), -10 + 1.0 * k * math.sin(0.5)) for k in range(40)]
    b = [(-20 + 1.0 * (k - 4) * math.cos(-0.5), 10 + 1.0 * (k - 4) * math.sin(-0.5)) for k in range(40)]
    rng = np.random.default_rng(0)
    frames = []
    for k in range(40):
        na, nb = rng.normal(0, 0.1, 2), rng.normal(0, 0.1, 2)
        boxes = [_car(a[k][0] + na[0], a[k][1] + na[1], 0.5), _car(b[k][0] + nb[0], b[k][1] + nb[1], -0.5)]
        frames.append(DetectionFrame("x", str(k), 0.1 * k, boxes if k % 2 else boxes[::-1]))
    tracked = track_boxes(frames)
    ida, idb = _ids_along(tracked, a), _ids_along(tracked, b)
    assert len(ida) == 1 and len(idb) == 1 and ida != idb
    assert all(len(f.boxes) == 2 for f in tracked[1:])  # confirmed from the second frame on


def test_lateral_offsets_against_a_rotation_by_hand():
    """Each b centre in a's box frame (translate, then turn by -yaw with an explicit rotation matrix): the offset is
    the absolute y."""
    rng = np.random.default_rng(4)
    a = np.column_stack([rng.normal(0, 20, (5, 3)), rng.uniform(-4, 4, 5), rng.uniform(1, 15, (5, 3))])
    b = np.column_stack([rng.normal(0, 20, (7, 3)), rng.uniform(-4, 4, 7), rng.uniform(1, 15, (7, 3))])
    got = lateral_offsets(a, b)
    for i in range(5):
        r = rotation_z(a[i, 3])[:2, :2]
        for j in range(7):
            local = r.T @ (b[j, :2] - a[i, :2])
            assert got[i, j] == pytest.approx(abs(local[1]), abs=1e-9)
    assert lateral_offsets(a, a).diagonal() == pytest.approx(np.zeros(5), abs=1e-12)


def _trailer(x, y, score=0.9) -> Box:
    return Box([x, y, 0.0], [14.8, 2.8, 4.1], rotation_z(math.pi / 2), "trailer", "trailer", "", score)


def test_a_parked_trailers_id_does_not_hop_to_the_one_beside_it():
    """Trailers parked side by side 3 m apart (gaps of 0.2 m, as in a depot of the nuScenes scene), 2 Hz: the first
    is detected in frame 0 and then missed for two frames while the second, seen from frame 1 on, is detected. The
    first track must not take the second's detections (its GIoU with them is about -0.04, above the threshold, and a
    one-hit track's position is uncertain by metres); each trailer keeps one id. Without the sideways gate
    (``lateral_speed_mps`` 0 and a floor of 10 m: off) the first id hops, as it did before."""
    frames = []
    for k in range(8):
        boxes = [] if k in (1, 2) else [_trailer(0.0, 0.0)]
        if k >= 1:
            boxes.append(_trailer(3.0, 0.0))
        frames.append(DetectionFrame("d", str(k), 0.5 * k, boxes))
    config = TrackerConfig(confirm_score=0.5)  # reported from the first hit: a hop shows as a second id
    for cfg, hops in (
        (config, False),
        (TrackerConfig(confirm_score=0.5, lateral_speed_mps=0.0, lateral_floor_m=10.0), True),
    ):
        tracked = track_boxes(frames, cfg)
        first = _ids_along(tracked, [(0.0, 0.0)] * 8, tol=1.0)
        second = _ids_along(tracked, [(3.0, 0.0)] * 8, tol=1.0)
        assert (len(first) == 1 and len(second) == 1 and first != second) is not hops, (first, second)


def test_the_sideways_gate_settings_are_checked():
    assert TrackerConfig(along_heading_classes=["car", "bus"]).along_heading_classes == ("car", "bus")
    for bad in ({"along_heading_classes": "car"}, {"along_heading_classes": ("car", 3)}, {"lateral_floor_m": 0.0},
                {"lateral_speed_mps": -1.0}, {"lateral_speed_mps": math.nan}):  # fmt: skip
        with pytest.raises(ParameterError, match=next(iter(bad))):
            TrackerConfig(**bad)


def test_a_car_changing_lanes_keeps_its_id_and_an_excavator_slewing_sideways_too():
    """The sideways gate lets a lane change through (1 m/s sideways at 12 m/s ahead, 10 Hz, a miss in the middle),
    and is not applied to construction machines, which move across their heading (2 m/s sideways)."""
    car = [(1.2 * k, 0.1 * k) for k in range(30)]
    frames = [
        DetectionFrame("l", str(k), 0.1 * k, [] if k in (12, 13) else [_car(x, y, 0.0)]) for k, (x, y) in enumerate(car)
    ]
    assert len(_ids_along(track_boxes(frames), car)) == 1
    dig = [(0.0, 1.0 * k) for k in range(12)]
    frames = [
        DetectionFrame("c", str(k), 0.5 * k, [_car(x, y, 0.0, cls="construction")]) for k, (x, y) in enumerate(dig)
    ]
    assert len(_ids_along(track_boxes(frames), dig)) == 1


def test_a_missed_detection_keeps_the_track():
    xs = [2.0 * k for k in range(12)]
    frames = [
        DetectionFrame("s", str(k), 0.5 * k, [] if k in (5, 6) else [_car(x, 3.0, 0.0)]) for k, x in enumerate(xs)
    ]
    tracked = track_boxes(frames, TrackerConfig(min_hits=2, confirm_score=1.0))
    assert [len(f.boxes) for f in tracked] == [0, 1, 1, 1, 1, 0, 0, 1, 1, 1, 1, 1]
    assert {b.track_id for f in tracked for b in f.boxes} == {"1"}
    coasted = track_boxes(frames, TrackerConfig(min_hits=2, confirm_score=1.0, report_coasted=True))
    assert coasted[5].boxes[0].track_id == "1" and coasted[5].boxes[0].center[0] == pytest.approx(10.0, abs=0.3)
    v = tracked[-1].velocities[0]
    assert v[0] == pytest.approx(4.0, abs=0.2) and abs(v[1]) < 0.1


def test_a_fast_car_seen_once_keeps_its_id_when_the_detector_reports_its_velocity():
    """10 m/s along the world x, 2 Hz, the sensor turned 90 degrees: seen at 0 s, missed at 0.5 s, seen 10 m on at
    1 s. Without a velocity the first detection's track cannot reach it (a second id); with the detector's velocity
    (in the sensor frame, as frames carry it) it does."""
    pose = rigid_transform(rotation_z(math.pi / 2), [5.0, -3.0, 0.0])
    to_sensor = np.linalg.inv(pose)
    frames = []
    for k, seen in enumerate([True, False, True, True]):
        boxes = [_car(5.0 * k, 2.0, 0.0).transformed(to_sensor)] if seen else []
        frames.append(DetectionFrame("s", str(k), 0.5 * k, boxes, pose))

    def ids(out):
        return {b.track_id for f in out for b in f.boxes}

    assert len(ids(track_boxes(frames))) == 2
    v_sensor = to_sensor[:3, :3] @ np.array([10.0, 0.0, 0.0])  # (0, -10, 0): the world's +x seen from the sensor
    with_v = [
        DetectionFrame(
            f.sequence, f.frame_id, f.timestamp, f.boxes, pose, velocities=np.tile(v_sensor, (len(f.boxes), 1))
        )
        for f in frames
    ]
    assert ids(track_boxes(with_v)) == {"1"}
    assert len(ids(track_boxes(with_v, TrackerConfig(detection_velocity_sigma=0.0)))) == 2  # reported, not used
    unknown = [
        DetectionFrame(
            f.sequence, f.frame_id, f.timestamp, f.boxes, pose, velocities=np.full((len(f.boxes), 3), np.nan)
        )
        for f in frames
    ]
    assert len(ids(track_boxes(unknown))) == 2  # NaN: the detector gave none


def test_reported_velocities_correct_a_tracks_velocity_by_hand():
    """A parked car (the same box every frame) whose detector reports 3 m/s along y: with a reported velocity far
    more certain than the filter's (sigma 1e-3 m/s) the track's velocity is the reported one after each update; by
    hand for one update: the Kalman gain of a velocity measured with variance r against a prior variance p (and no
    covariance with the other axis) is p / (p + r), so the estimate moves from 0 to 3 p / (p + r)."""
    v = np.array([0.0, 3.0, 0.0])
    frames = [DetectionFrame("s", str(k), 0.5 * k, [_car(5.0, 5.0, 0.0)], velocities=v[None]) for k in range(4)]
    out = track_boxes(frames, TrackerConfig(detection_velocity_sigma=1e-3, min_hits=1))
    for f in out:
        np.testing.assert_allclose(f.velocities[0][:2], [0.0, 3.0], atol=1e-4)
    cfg = TrackerConfig(detection_velocity_sigma=2.0)
    track = KalmanTrack(np.array([5.0, 5.0, 0.0, 0.0, 4.5, 1.9, 1.6]), cfg, "1", "car", "car", "car", 0.9)
    track.predict(0.5)
    z = np.array([5.0, 5.0, 0.0, 0.0, 4.5, 1.9, 1.6])
    box_only = copy.deepcopy(track)
    box_only.update(z, 0.9)  # the box: its position says nothing new, vy stays 0; p is vy's variance after it
    p_vy = float(box_only.kf.P[8, 8])
    assert float(box_only.kf.x[8, 0]) == 0.0 and float(box_only.kf.P[7, 8]) == 0.0
    track.update(z, 0.9, velocity=v)  # the box, then the velocity (variance 2^2)
    assert float(track.kf.x[8, 0]) == pytest.approx(3.0 * p_vy / (p_vy + 4.0), rel=1e-9)


def test_a_readers_frames_are_tracked_as_they_are():
    """track_boxes takes a dataset reader's Frame (no velocities field): a car driving along x keeps one id."""
    from spotlights.data.real.base import Frame

    frames = [Frame("s", str(k), 0.5 * k, np.zeros((0, 3), np.float32), [_car(2.0 * k, 3.0, 0.0)]) for k in range(5)]
    out = track_boxes(frames)
    assert {b.track_id for f in out for b in f.boxes} == {"1"} and all(len(f.boxes) == 1 for f in out)


def test_scores_birth_and_death():
    low = [DetectionFrame("s", str(k), 0.1 * k, [_car(0.0, 0.0, 0.0, score=0.2)]) for k in range(5)]
    assert all(f.boxes == [] for f in track_boxes(low))  # low scores never start a track
    mixed = [
        DetectionFrame("s", str(k), 0.1 * k, [_car(0.0, 0.0, 0.0, score=0.9 if k == 0 else 0.2)]) for k in range(5)
    ]
    out = track_boxes(mixed, TrackerConfig(confirm_score=1.0))
    assert [len(f.boxes) for f in out] == [0, 1, 1, 1, 1]  # born by a high score, continued by low ones
    assert out[-1].boxes[0].score == pytest.approx((0.9 + 4 * 0.2) / 5)
    gone = [DetectionFrame("s", str(k), 0.1 * k, [_car(0.0, 0.0, 0.0)] if k < 3 or k == 9 else []) for k in range(10)]
    out = track_boxes(gone, TrackerConfig(max_misses=3))
    assert out[2].boxes[0].track_id != out[9].boxes[0].track_id  # ended after 3 misses; a new track later


def test_classes_are_tracked_apart_and_ids_are_deterministic():
    frames = [
        DetectionFrame("s", str(k), 0.1 * k, [_car(0.1 * k, 0, 0), _car(0.1 * k, 0.2, 0, cls="truck")])
        for k in range(5)
    ]
    out = track_boxes(frames)
    assert all(len(f.boxes) == 2 for f in out) and len({b.track_id for f in out for b in f.boxes}) == 2
    assert {b.cls for b in out[-1].boxes} == {"car", "truck"}
    assert json.dumps(tracks_document(out)) == json.dumps(tracks_document(track_boxes(frames)))


def test_a_moving_sensor_sees_a_parked_car():
    """The sensor drives at 5 m/s along the world x; a car parked at world (30, 4): in the sensor frame it moves."""
    frames = []
    for k in range(10):
        pose = rigid_transform(rotation_z(0.1), [2.5 * k, 0.0, 0.0])
        car = _car(30.0, 4.0, 0.3).transformed(np.linalg.inv(pose))
        frames.append(DetectionFrame("s", str(k), 0.5 * k, [car], pose))
    out = track_boxes(frames)
    assert {b.track_id for f in out for b in f.boxes} == {"1"}
    world = out[-1].boxes[0].transformed(frames[-1].sensor_to_world)
    np.testing.assert_allclose(world.center[:2], [30.0, 4.0], atol=1e-6)
    assert np.linalg.norm(frames[-1].sensor_to_world[:3, :3] @ out[-1].velocities[0]) < 1e-6


def test_frames_out_of_time_order_are_refused():
    frames = [DetectionFrame("s", "a", 1.0, []), DetectionFrame("s", "b", 0.5, [])]
    with pytest.raises(ParameterError, match="time order"):
        track_boxes(frames)
    with pytest.raises(ParameterError, match="giou_threshold"):
        TrackerConfig(giou_threshold=2.0)


# --- writers and metrics -------------------------------------------------------------------------------------


def test_tracks_round_trip_and_nuscenes_document(tmp_path):
    pose = rigid_transform(rotation_z(math.pi / 2), [100.0, 200.0, 0.0])
    frames = [DetectionFrame("s", f"tok{k}", 0.5 * k, [_car(10.0 + k, 0.0, 0.0)], pose) for k in range(4)]
    out = track_boxes(frames)
    path = tmp_path / "tracks.json"
    path.write_text(json.dumps(tracks_document(out, tmp_path)))
    back = read_generic_detections(path)
    assert [len(f.boxes) for f in back] == [1, 1, 1, 1]
    assert back[2].boxes[0].track_id == "1" and back[2].boxes[0].score == pytest.approx(0.9)
    np.testing.assert_allclose(back[2].boxes[0].center, out[2].boxes[0].center, atol=1e-5)
    doc = nuscenes_tracking_document(out)
    (entry,) = doc["results"]["tok2"]
    # sensor x -> global y: the car at sensor (12, 0) is at global (100, 212); size w, l, h; heading 90 degrees
    np.testing.assert_allclose(entry["translation"], [100.0, 212.0, 0.0], atol=0.3)
    np.testing.assert_allclose(entry["size"], [1.9, 4.5, 1.6], atol=0.05)
    np.testing.assert_allclose(
        np.abs(entry["rotation"]), [math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)], atol=0.02
    )
    assert entry["tracking_name"] == "car" and entry["tracking_id"] == "1"


def test_clear_mot_against_a_hand_count():
    """Two objects over three frames. Hypotheses: frame 0 both right; frame 1 object B missed and a false
    positive far away; frame 2 object A under a new id (one switch). GT boxes 6: MOTA = 1 - (1 + 1 + 1) / 6."""
    ga, gb = (
        Box([0, 0, 0], [4, 2, 1.5], label="car", cls="car", track_id="A"),
        Box([10, 0, 0], [4, 2, 1.5], label="car", cls="car", track_id="B"),
    )
    truth = [DetectionFrame("s", str(k), k, [ga, gb]) for k in range(3)]
    h = lambda box, tid: box.replace(track_id=tid)  # noqa: E731
    far = Box([50, 0, 0], [4, 2, 1.5], label="car", cls="car", track_id="9")
    hyp = [
        DetectionFrame("s", "0", 0, [h(ga, "1"), h(gb, "2")]),
        DetectionFrame("s", "1", 1, [h(ga, "1"), far]),
        DetectionFrame("s", "2", 2, [h(ga, "3"), h(gb, "2")]),
    ]
    m = clear_mot(truth, hyp)
    assert (m["misses"], m["false_positives"], m["id_switches"], m["gt_boxes"], m["gt_tracks"]) == (1, 1, 1, 6, 2)
    assert m["mota"] == pytest.approx(0.5) and m["id_switches_per_100_tracks"] == pytest.approx(50.0)


def test_simulated_detector_rates_and_seed():
    rng = np.random.default_rng(1)
    frames = [
        DetectionFrame("s", str(k), 0.5 * k, [_car(*rng.uniform(-40, 40, 2), 0.0, score=None) for _ in range(50)])
        for k in range(20)
    ]
    counts = [np.full(50, 100.0) for _ in frames]
    model = DetectorModel(miss_rate=0.2, false_positive_rate=0.1)
    dets, truth = simulate_detections(frames, counts, model, seed=3)
    n_truth = sum(len(f.boxes) for f in truth)
    tp = sum(sum(b.score > 0.45 for b in f.boxes) for f in dets)  # false positives score at most 0.40
    fp = sum(len(f.boxes) for f in dets) - tp
    assert n_truth == sum(math.hypot(*b.center[:2]) <= 50 for f in frames for b in f.boxes)
    assert tp / n_truth == pytest.approx(0.8, abs=0.04) and fp / n_truth == pytest.approx(0.1, abs=0.03)
    again, _ = simulate_detections(frames, counts, model, seed=3)
    assert json.dumps(tracks_document(again)) == json.dumps(tracks_document(dets))


def test_box_velocities_of_a_constant_velocity_track_by_hand():
    """A car at world (2 + 3 t, 1 - 4 t) seen by a sensor turned 30 degrees and driving along the world y: each
    frame's velocity is the world's (3, -4, 0) turned into that frame; a track seen once has none (zero)."""
    frames = []
    for k in range(4):
        t = 0.5 * k
        pose = rigid_transform(rotation_z(math.radians(30)), [0.0, 6.0 * t, 0.0])
        boxes = [_car(2 + 3 * t, 1 - 4 * t, 0.2).transformed(np.linalg.inv(pose))]
        if k == 2:
            boxes.append(_car(20.0, 0.0, 0.0).replace(track_id="once").transformed(np.linalg.inv(pose)))
        frames.append(DetectionFrame("s", str(k), t, [b.replace(track_id=b.track_id or "a") for b in boxes], pose))
    out = box_velocities(frames)
    for f in out:
        np.testing.assert_allclose(f.sensor_to_world[:3, :3] @ f.velocities[0], [3.0, -4.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(out[2].velocities[1], 0.0)
    model = DetectorModel(miss_rate=0.0, false_positive_rate=0.0, position_sigma_m=0.0, velocity_sigma_mps=0.0)
    dets, _ = simulate_detections(out, [np.full(len(f.boxes), 100.0) for f in out], model, seed=0)
    for d, f in zip(dets, out):  # a noiseless detector reports the true velocities
        for b, v in zip(d.boxes, d.velocities):
            k = int(np.argmin([np.linalg.norm(g.center - b.center) for g in f.boxes]))
            np.testing.assert_allclose(v, f.velocities[k], atol=1e-12)
    with pytest.raises(ParameterError, match="velocity_sigma_mps"):
        simulate_detections([DetectionFrame("s", "0", 0.0, [_car(0, 0, 0)])], [np.ones(1)], model)


# --- the command ----------------------------------------------------------------------------------------------


def _sequence_file(tmp_path):
    frames = [{"timestamp": 0.1 * k, "boxes": [{"center": [1.0 * k, 0, 0], "size": [4.5, 1.9, 1.6], "yaw": 0.0,
                                                  "label": "car", "score": 0.8}]} for k in range(6)]  # fmt: skip
    path = tmp_path / "det.json"
    path.write_text(json.dumps({"sequence": "a", "frames": frames}))
    return path


def test_cli_writes_tracks(tmp_path):
    det = _sequence_file(tmp_path)
    proc = run_cli("track", str(det), "--format", "generic", "--out", str(tmp_path / "o" / "tracks.json"),
                   "--nuscenes-out", str(tmp_path / "nus.json"), "--min-score", "0.5")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "6 frame(s), 6 detection(s) tracked" in proc.stdout and "1 track(s)" in proc.stdout
    doc = json.loads((tmp_path / "o" / "tracks.json").read_text())
    assert [len(f["boxes"]) for f in doc["frames"]] == [1] * 6 and doc["frames"][3]["boxes"][0]["track_id"] == "1"
    assert len(json.loads((tmp_path / "nus.json").read_text())["results"]) == 6


def test_cli_bad_input_is_one_line_and_writes_nothing(tmp_path):
    bad = tmp_path / "det.json"
    bad.write_text(
        json.dumps(
            {"frames": [{"boxes": [{"center": [0, 0, 0], "size": [1, 1, 1], "yaw": 0, "label": "car", "score": 7}]}]}
        )
    )
    out = tmp_path / "tracks.json"
    proc = run_cli("track", str(bad), "--format", "generic", "--out", str(out))
    assert_user_error(proc, str(bad), "score")
    assert not out.exists() and list(tmp_path.iterdir()) == [bad]
    proc = run_cli("track", str(bad), "--format", "nuscenes", "--out", str(out))
    assert_user_error(proc, "--data")
    proc = run_cli("track", str(bad), "--format", "generic", "--calib", "c.txt", "--out", str(out))
    assert_user_error(proc, "--calib")
    proc = run_cli("track", str(_sequence_file(tmp_path)), "--format", "generic", "--out", str(tmp_path / "x.txt"))
    assert_user_error(proc, "--out")
    assert not out.exists()


def test_cli_on_the_shared_nuscenes_scene(tmp_path):
    folder = need(LIDAR / "nuscenes")
    from spotlights.data.real.nuscenes import NuScenesReader

    reader = NuScenesReader(folder)
    results = {}
    for key in reader.frame_keys():
        rows = [r for r in reader.annotations(key) if r.get("num_lidar_pts", 0) >= 20][:30]
        results[key[1]] = [
            {"translation": r["translation"], "size": r["size"], "rotation": r["rotation"], "velocity": [0, 0],
             "detection_name": "car", "detection_score": 0.9, "attribute_name": ""} for r in rows
        ]  # fmt: skip
    det = tmp_path / "det.json"
    det.write_text(json.dumps({"meta": {}, "results": results}))
    nus = tmp_path / "nus.json"
    proc = run_cli("track", str(det), "--format", "nuscenes", "--data", str(folder), "--out", str(tmp_path / "t.json"),
                   "--nuscenes-out", str(nus))  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(nus.read_text())
    assert set(doc["results"]) == {k[1] for k in reader.frame_keys()}
    # every tracked box lies where an annotation was (global frame, within the filter's smoothing)
    for token, entries in doc["results"].items():
        truth = np.array([r["translation"] for r in results[token]]).reshape(-1, 3)
        for e in entries:
            assert np.min(np.linalg.norm(truth - e["translation"], axis=1)) < 1.0


def test_the_study_page_quotes_the_results_file():
    """docs/studies/tracking.md says the numbers of docs/results/tracking/tracker_nuscenes.json."""
    from helpers import REPO

    res = json.loads((REPO / "docs" / "results" / "tracking" / "tracker_nuscenes.json").read_text())
    text = " ".join((REPO / "docs" / "studies" / "tracking.md").read_text().split())
    m = res["metrics"]
    row = f"| 0 (reported) | {m['mota']:.3f} | {m['idf1']:.3f} | {m['id_switches']} | {m['id_switches_per_100_tracks']:.1f} |"
    assert row in text
    assert res["detector_velocities"]["used (default)"]["id_switches_per_100_tracks_mean"] <= 3.0  # "met" in the page
    assert res["mean_over_seeds"]["id_switches_per_100_tracks"] <= 3.0  # "met ... on average"
    assert abs(res["held_out_seeds"]["default"]["id_switches_per_100_tracks_mean"] - 3.0) < 0.05  # "at the target"
    switches = [m["id_switches"]] + [o["id_switches"] for o in res["other_seeds"].values()]
    blocks = [sum(switches[i : i + 10]) for i in (0, 10, 20)]
    assert f"gave {blocks[0]}, {blocks[1]} and {blocks[2]} switches" in text
    mean = res["mean_over_seeds"]
    assert (
        f"| mean of {mean['seeds']} | {mean['mota']:.3f} | {mean['idf1']:.3f} | {mean['id_switches']:.1f} | "
        f"{mean['id_switches_per_100_tracks']:.1f} |" in text
    )
    for seed, o in res["other_seeds"].items():
        assert (
            f"| {seed} | {o['mota']:.3f} | {o['idf1']:.3f} | {o['id_switches']} | {o['id_switches_per_100_tracks']:.1f} |"
            in text
        )
    for phrase in (
        f"{res['speed']['frames_per_cpu_second']:.0f} frames per CPU second",
        f"{m['misses']} misses of {m['gt_boxes']} boxes",
        f"{m['gt_boxes']} boxes of {m['gt_tracks']} tracks",
        f"MOTP {m['motp_m']:.3f} m",
        f"{res['detections']} detections, {res['detections_per_frame']:.1f} a frame",
        f"{m['mostly_tracked']} tracks mostly tracked, {m['mostly_lost']} mostly lost",
        f"over the {res['mean_over_seeds']['seeds']} seeds {res['mean_over_seeds']['id_switches_total']} identity "
        f"switches instead of {res['alternatives']['max_misses=6']['id_switches_total']}",
        f"over the {res['mean_over_seeds']['seeds']} seeds {res['mean_over_seeds']['id_switches_total']} identity "
        f"switches instead of {res['alternatives']['coast_velocity_sigmas=0']['id_switches_total']} "
        f"(`coast_velocity_sigmas=0`), MOTA {res['mean_over_seeds']['mota']:.3f} against "
        f"{res['alternatives']['coast_velocity_sigmas=0']['mota_mean']:.3f}",
        f"**{res['detector_velocities']['used (default)']['id_switches_per_100_tracks_mean']:.1f} identity switches "
        f"per 100 tracks** ({res['detector_velocities']['used (default)']['id_switches_total']} in all; the target of "
        "3: met) against "
        f"{res['detector_velocities']['ignored']['id_switches_per_100_tracks_mean']:.1f} "
        f"({res['detector_velocities']['ignored']['id_switches_total']})",
        f"centre distance 3 m: {res['alternatives']['max_distance_m=3']['id_switches_total']}, "
        f"4 m: {res['alternatives']['max_distance_m=4']['id_switches_total']}",
        f"Over the 30 seeds {res['mean_over_seeds']['id_switches_total']} identity switches instead of "
        f"{res['alternatives']['no sideways gate']['id_switches_total']} without it, MOTA {res['mean_over_seeds']['mota']:.3f} "
        f"against {res['alternatives']['no sideways gate']['mota_mean']:.3f}",
        f"on seeds {res['held_out_seeds']['seeds'][0]}-{res['held_out_seeds']['seeds'][1]}, which played no part in "
        f"choosing any setting, **{res['held_out_seeds']['default']['id_switches_per_100_tracks_mean']:.1f}** "
        f"({res['held_out_seeds']['default']['id_switches_total']} switches; without the sideways gate "
        f"{res['held_out_seeds']['no sideways gate']['id_switches_total']}, "
        f"{res['held_out_seeds']['no sideways gate']['id_switches_per_100_tracks_mean']:.1f})",
        f"on average ({res['mean_over_seeds']['id_switches_per_100_tracks']:.1f})",
    ):
        assert phrase in text, phrase


# --- real complete --detections --track ------------------------------------------------------------------------


CARS = ([10.0, 2.0, -0.9], [-6.0, -5.0, -0.9])  # centres at t = 0; the first drives at 2 m/s along x
CAR_SIZE = [4.2, 1.8, 1.5]


def _write_drive(folder, times):
    """Generic frames ``f0.npy`` + ``f0.json`` ...: two cars as points on their front and back faces, plus ground;
    their boxes have no track id."""
    rng = np.random.default_rng(0)
    folder.mkdir(parents=True)
    size = np.array(CAR_SIZE)
    for k, t in enumerate(times):
        pts, boxes = [rng.uniform(-30, 30, (300, 3)) * [1, 1, 0] - [0, 0, 1.7]], []
        for c in CARS:
            c = [c[0] + (2.0 * t if c is CARS[0] else 0.0), c[1], c[2]]
            obj = rng.uniform(-0.5, 0.5, (300, 3)) * size
            obj[:, 0] = np.sign(obj[:, 0]) * size[0] / 2
            obj[:, 2] = rng.uniform(-size[2] / 2 + 0.12, size[2] / 2, 300)  # above the ground cut
            pts.append(obj + c)
            boxes.append({"center": c, "size": CAR_SIZE, "yaw": 0.0, "label": "car"})
        np.save(folder / f"f{k}.npy", np.concatenate(pts).astype(np.float32))
        (folder / f"f{k}.json").write_text(json.dumps({"timestamp": t, "boxes": boxes}))
    return folder


def _drive_detections(tmp_path, times) -> str:
    """Detections of the two cars of :func:`_write_drive` (no track ids, scores), as a generic sequence JSON."""
    frames = []
    for k, t in enumerate(times):
        boxes = [
            {"center": c, "size": CAR_SIZE, "yaw": 0.0, "label": "car", "score": 0.9}
            for c in ([CARS[0][0] + 2.0 * t, *CARS[0][1:]], CARS[1])
        ]
        frames.append({"frame_id": f"f{k}", "timestamp": t, "boxes": boxes})
    path = tmp_path / "det.json"
    path.write_text(json.dumps({"sequence": "drive", "frames": frames}))
    return str(path)


def test_real_complete_refuses_detections_without_track(tmp_path, capsys):
    from spotlights.cli import main

    src = _write_drive(tmp_path / "drive", [0.0, 0.5])
    det = _drive_detections(tmp_path, [0.0, 0.5])
    out = tmp_path / "out"
    for extra, message in (
        ([], "--detections needs --track"),
        (["--track", "--format", "kitti360"], "--detections is read beside --format nuscenes, kitti, generic"),
    ):
        argv = ["real", "complete", str(src), "--format", "generic", "--out", str(out), "--detections", det, *extra]
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0] and not out.exists(), err
    for alone in (["--track"], ["--min-score", "0.3"]):
        assert main(["real", "complete", str(src), "--format", "generic", "--out", str(out), *alone]) == 2
        assert "--track and --min-score go with --detections" in capsys.readouterr().err and not out.exists()


def test_real_complete_tracks_detections_and_fuses_them(tmp_path):
    """The drive's boxes carry no track id (--fuse alone refuses them); its detections, tracked, give the two cars
    one id each, and --fuse all fuses each car's three frames."""
    pytest.importorskip("torch")
    from spotlights.cli import main

    from learning_fixtures import make_checkpoint

    times = [0.0, 0.5, 1.0]
    src = _write_drive(tmp_path / "drive", times)
    det = _drive_detections(tmp_path, times)
    ck = make_checkpoint(tmp_path / "tiny.pt", "sanet")
    common = ["--format", "generic", "-c", str(ck), "--no-clip", "-q", "--no-pictures", "--fuse", "all"]
    assert main(["real", "complete", str(src), "--out", str(tmp_path / "plain"), *common]) == 2  # no track ids
    argv = ["real", "complete", str(src), "--out", str(tmp_path / "out"), *common, "--detections", det, "--track"]
    assert main(argv) == 0
    tracks = json.loads((tmp_path / "out" / "tracks.json").read_text())
    assert tracks["n_tracks"] == 2
    for tr in tracks["tracks"]:
        assert [r["n_points"] for r in tr["frames"]] == [300, 300, 300]
        assert [r["n_fused"] for r in tr["frames"]] == [900, 900, 900]
    rec = json.loads((tmp_path / "out" / "drive" / "f1.json").read_text())
    assert sorted(o["n_fused"] for o in rec["objects"] if o["status"] == "completed") == [900, 900]
    # --resume keeps the frames made from the same detections, and completes again those of changed ones
    assert main([*argv, "--resume"]) == 0
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["totals"]["resumed"] == 3
    doc = json.loads(Path(det).read_text())
    doc["frames"][1]["boxes"][1]["center"][1] += 0.3
    Path(det).write_text(json.dumps(doc))
    assert main([*argv, "--resume"]) == 0
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["totals"]["resumed"] == 0


def test_tracks_are_split_where_they_go_unseen_longer_than_the_fusion_allows():
    """Track 3 seen at 0, 1.0 s, then again at 4.0 and 4.5 s (a 3 s gap) becomes two tracks for a 2 s limit; track 7,
    seen every second between, keeps its id; ids stay integers, the new one above every id of the call."""
    from spotlights.completion.detections import split_at_gaps
    from spotlights.geometry.boxes import Box
    from spotlights.tracking.detections import DetectionFrame

    def box(tid):
        return Box([10.0, 0.0, 0.0], [4.2, 1.8, 1.5], yaw=0.0, label="car", track_id=tid)

    times = [0.0, 1.0, 2.0, 3.0, 4.0, 4.5]
    frames = [DetectionFrame("s", f"f{k}", t, [box("3")] * (k not in (2, 3)) + [box("7")]) for k, t in enumerate(times)]
    got = split_at_gaps(frames, 2.0)
    expected = [["3", "7"], ["3", "7"], ["7"], ["7"], ["8", "7"], ["8", "7"]]
    assert [[b.track_id for b in f.boxes] for f in got] == expected
    assert [f.frame_id for f in got] == [f.frame_id for f in frames]
    assert [[b.track_id for b in f.boxes] for f in split_at_gaps(frames, 5.0)] == [
        [b.track_id for b in f.boxes] for f in frames
    ]
