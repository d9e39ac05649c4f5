"""A 3-D multi-object tracker in the style of AB3DMOT: a Kalman filter per track, optimal assignment per class.

Per sequence, frame after frame (times in seconds from :attr:`DetectionFrame.timestamp`):

1. **World frame.** Boxes are moved into the world frame with the frame's ``sensor_to_world`` (when given), so a
   moving sensor does not move the objects; outputs are moved back into each frame's own coordinates.
2. **Predict.** Every track's constant-velocity Kalman filter (filterpy's ``KalmanFilter``) over the state
   ``(x, y, z, yaw, l, w, h, vx, vy, vz)`` is advanced by the time since its last frame ``dt``: position += velocity
   x dt; process noise of a white acceleration ``accel_sigma`` (m/s^2) on each axis, random walks of yaw
   (``yaw_rate_sigma`` rad/s) and size (``size_rate_sigma`` m/s). A track that missed its last frame moves only by a
   velocity the filter tells from standstill (``coast_velocity_sigmas``).
3. **Associate** per class (the box's ``cls``, else its label), by
   :func:`~spotlights.tracking.association.assign` (``scipy.optimize.linear_sum_assignment``) in two stages:
   3-D GIoU (:mod:`~spotlights.tracking.association`) above ``giou_threshold`` within a gate that follows the
   track's uncertainty (``gate_floor_m`` + ``gate_sigmas`` standard deviations of its predicted position, at most ``gate_m``), then, among the tracks and detections left, centre distances below
   ``max_distance_m`` (a track whose prediction drifted sideways while it was not seen). ``metric="distance"``: the
   second stage alone. In both stages a road vehicle (``along_heading_classes``) is matched only to a detection
   within ``lateral_floor_m`` + ``lateral_speed_mps`` x (seconds since its last match) of the line along its
   predicted heading: vehicles drive along their heading, so a detection a full width to the side is the
   neighbour parked beside it, not the vehicle (whose velocity, for a new track, is not known yet).
4. **Update** matched tracks with the detection ``(x, y, z, yaw, l, w, h)`` and, where the detector reports one, its
   velocity (``detection_velocity_sigma``). Yaw: the detection's heading is taken
   within +-90 degrees of the track's (a detector's heading turned by 180 degrees is the same box: it is turned back,
   the **flip correction**), angles are wrapped to (-pi, pi]. A track's score is the mean score of the detections
   it matched (a box without a score counts as 1).
5. **Birth and death.** An unmatched detection starts a tentative track when its score is at least
   ``birth_score`` (low-score detections may only continue tracks), with the velocity the detector reports for it
   where it reports one (``detection_velocity_sigma``; nuScenes results carry one), else an unknown one; a track
   is confirmed after ``min_hits``
   matched frames and reported from then on; a track unmatched for ``max_misses`` frames in a row ends. While a
   confirmed track misses (fewer than ``max_misses`` frames) its prediction is reported when ``report_coasted``.

Deterministic: no randomness; classes are processed in sorted order; track ids ("1", "2", ...) are given in order
of birth, unique over the call (over every sequence). The output boxes are the filter's posterior (or prediction
while coasting), with the track id, class, label and score, and their velocities.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..geometry.boxes import Box
from ..geometry.rotations import rotation_z
from .association import assign, centre_distances, giou_matrix, lateral_offsets
from .detections import DetectionFrame

log = logging.getLogger(__name__)

METRICS = ("giou", "distance")


@dataclass(frozen=True)
class TrackerConfig:
    """The tracker's settings (see the module docstring); defaults suit 2-10 Hz LiDAR detections of vehicles.

    metric : ``"giou"`` (3-D GIoU of the predicted and detected boxes) or ``"distance"`` (centre distance).
    giou_threshold : match when GIoU > this (-1..1; -0.5 lets a fast car with an unknown velocity be matched).
    gate_m, gate_floor_m, gate_sigmas : a track and a detection whose centres are farther apart than
        ``min(gate_m, gate_floor_m + gate_sigmas * sigma)`` metres (sigma: the predicted position's standard deviation,
        bird's eye) are never matched by GIoU: a new track (velocity unknown) reaches far, a steady one near.
    max_distance_m : the second stage (and ``metric="distance"``): match when the centres are nearer, metres.
    min_hits : matched frames before a track is confirmed (reported).
    max_misses : frames in a row without a match that end a track.
    birth_score : least score of a detection that starts a track.
    confirm_score : a track whose detection scores at least this is confirmed at once (1: only by ``min_hits``).
    report_coasted : report a confirmed track's prediction in the frames it misses (before it ends).
    meas_sigma_xy, meas_sigma_z (m), meas_sigma_yaw (rad), meas_sigma_size (m) : measurement noise.
    accel_sigma (m/s^2), yaw_rate_sigma (rad/s), size_rate_sigma (m/s) : process noise.
    init_velocity_sigma : prior standard deviation of a new track's velocity, m/s.
    detection_velocity_sigma : a detection's reported velocity (the frame's ``velocities``, e.g. a nuScenes result's
        ``velocity``; finite x and y) starts its new track with that velocity, and corrects the velocity of the track
        it matches, with this standard deviation, m/s (0: reported velocities are not used).
    lateral_speed_mps, lateral_floor_m : the sideways gate of a track of ``along_heading_classes``: a detection
        whose centre lies farther than ``lateral_floor_m + lateral_speed_mps * t`` metres from the line along the
        track's predicted heading (t: seconds since its last match) is not matched to it (``lateral_speed_mps`` 0 and
        a large floor: off). 1.5 m/s is a brisk lane change; 1 m holds the detectors' centre noise and the
        prediction's.
    along_heading_classes : the classes (track keys) the sideways gate applies to: road vehicles, which move along
        their heading; not construction machines (an excavator slews) nor pedestrians.
    coast_velocity_sigmas : while a track misses, its velocity moves its prediction only when the filter can tell it
        from standstill: when the bird's-eye velocity's Mahalanobis norm under its own covariance is at least this
        (0: always). Two noisy hits of a parked car give it a velocity of noise, which would carry its prediction
        onto the next parked car while it is not seen.
    """

    metric: str = "giou"
    giou_threshold: float = -0.3
    gate_m: float = 10.0
    gate_floor_m: float = 2.0
    gate_sigmas: float = 2.0
    max_distance_m: float = 2.0
    min_hits: int = 2
    max_misses: int = 10
    birth_score: float = 0.4
    confirm_score: float = 0.6
    report_coasted: bool = False
    meas_sigma_xy: float = 0.2
    meas_sigma_z: float = 0.2
    meas_sigma_yaw: float = math.radians(5.0)
    meas_sigma_size: float = 0.2
    accel_sigma: float = 1.0
    yaw_rate_sigma: float = 0.5
    size_rate_sigma: float = 0.05
    init_velocity_sigma: float = 10.0
    detection_velocity_sigma: float = 0.5
    coast_velocity_sigmas: float = 2.0
    lateral_speed_mps: float = 1.5
    lateral_floor_m: float = 1.0
    along_heading_classes: tuple[str, ...] = ("car", "caravan", "truck", "bus", "trailer", "emergency")

    def __post_init__(self) -> None:
        if self.metric not in METRICS:
            raise ParameterError(f"metric: one of {', '.join(METRICS)}, got {self.metric!r}")
        if not -1.0 <= self.giou_threshold < 1.0:
            raise ParameterError(f"giou_threshold: a GIoU in [-1, 1), got {self.giou_threshold}")
        for name in ("gate_m", "gate_floor_m", "gate_sigmas", "max_distance_m", "lateral_floor_m", "meas_sigma_xy", "meas_sigma_z", "meas_sigma_yaw", "meas_sigma_size",
                     "init_velocity_sigma"):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ParameterError(f"{name}: a positive number, got {v}")
        for name in ("accel_sigma", "yaw_rate_sigma", "size_rate_sigma", "detection_velocity_sigma",
                     "coast_velocity_sigmas", "lateral_speed_mps"):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ParameterError(f"{name}: a number >= 0, got {v}")
        if isinstance(self.along_heading_classes, str) or not all(
            isinstance(c, str) for c in self.along_heading_classes
        ):
            raise ParameterError(f"along_heading_classes: a tuple of class names, got {self.along_heading_classes!r}")
        object.__setattr__(self, "along_heading_classes", tuple(self.along_heading_classes))  # a list given: hashable
        for name in ("min_hits", "max_misses"):
            v = getattr(self, name)
            if not (isinstance(v, int) and 1 <= v <= 1000):
                raise ParameterError(f"{name}: a whole number in 1..1000, got {v}")
        for name in ("birth_score", "confirm_score"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ParameterError(f"{name}: a score in [0, 1], got {getattr(self, name)}")


def wrap_angle(a: float) -> float:
    """``a`` radians wrapped to (-pi, pi]."""
    a = math.fmod(a + math.pi, 2.0 * math.pi)
    if a <= 0.0:
        a += 2.0 * math.pi
    return a - math.pi


def corrected_yaw(measured: float, predicted: float) -> float:
    """The measured heading as the equivalent angle within +-90 degrees of ``predicted`` (radians): the same box
    turned by 180 degrees where it differs by more than 90 degrees (the flip correction), then unwrapped around
    ``predicted`` so the innovation is small."""
    d = wrap_angle(measured - predicted)
    if abs(d) > 0.5 * math.pi:
        d = wrap_angle(d + math.pi)
    return predicted + d


def usable_velocity(velocity: np.ndarray | None, config: TrackerConfig) -> np.ndarray | None:
    """The (2,) float64 bird's-eye velocity (m/s) a detection reports, when the tracker uses it: reported
    (``velocity`` (3,), not None) with finite x and y, and ``config.detection_velocity_sigma`` > 0; else None."""
    if velocity is None or config.detection_velocity_sigma <= 0:
        return None
    v = np.asarray(velocity[:2], dtype=np.float64)
    return v if np.all(np.isfinite(v)) else None


class KalmanTrack:
    """One track: a constant-velocity Kalman filter over ``(x, y, z, yaw, l, w, h, vx, vy, vz)`` (filterpy).

    ``z0`` (7,) the first detection ``(x, y, z, yaw, l, w, h)``; ``velocity`` (3,) its reported velocity, m/s in the
    same frame, or None (unknown: zero with ``config.init_velocity_sigma``); covariances from ``config``. :meth:`predict`
    advances by ``dt`` seconds, :meth:`update` takes one detection (7,). ``kf.x`` (10, 1) and ``kf.P`` (10, 10) are
    filterpy's state and covariance (float64; units: metres, radians, metres per second).
    """

    def __init__(
        self,
        z0: np.ndarray,
        config: TrackerConfig,
        track_id: str,
        key: str,
        cls: str | None,
        label: str,
        score: float,
        velocity: np.ndarray | None = None,
    ):
        from filterpy.kalman import KalmanFilter

        self.config = config
        kf = KalmanFilter(dim_x=10, dim_z=7)
        kf.H = np.eye(7, 10)
        c = config
        r = np.array([c.meas_sigma_xy, c.meas_sigma_xy, c.meas_sigma_z, c.meas_sigma_yaw] + [c.meas_sigma_size] * 3)
        kf.R = np.diag(r**2)
        kf.P = np.diag(np.concatenate([r**2, np.full(3, c.init_velocity_sigma**2)]))
        kf.x = np.zeros((10, 1))
        kf.x[:7, 0] = z0
        reported = usable_velocity(velocity, c)
        if reported is not None:
            kf.x[7:9, 0] = reported  # the detector's estimate: a new track knows where it goes
            kf.P[7, 7] = kf.P[8, 8] = c.detection_velocity_sigma**2
        self.kf = kf
        self.track_id = track_id
        self.key = key  # the class the track is associated within
        self.cls = cls
        self.label = label
        self.scores = [score]
        self.hits = 1
        self.misses = 0
        self.since_update = 0.0  # seconds predicted since the last matched detection
        self.confirmed = config.min_hits <= 1 or score >= config.confirm_score

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(F, Q): the (10, 10) transition and process noise over ``dt`` seconds (see the module docstring)."""
        c = self.config
        f = np.eye(10)
        f[0, 7] = f[1, 8] = f[2, 9] = dt
        q = np.zeros((10, 10))
        a2 = c.accel_sigma**2
        for p, v in ((0, 7), (1, 8), (2, 9)):
            q[p, p] = a2 * dt**4 / 4.0
            q[p, v] = q[v, p] = a2 * dt**3 / 2.0
            q[v, v] = a2 * dt**2
        q[3, 3] = (c.yaw_rate_sigma * dt) ** 2
        q[4, 4] = q[5, 5] = q[6, 6] = (c.size_rate_sigma * dt) ** 2
        return f, q

    def predict(self, dt: float) -> None:
        """Advance the state by ``dt`` seconds (> 0); the yaw is wrapped. While the track misses (``misses`` > 0)
        and its velocity is not :meth:`velocity_significant`, the position stays where it is (its covariance grows
        by the process noise alone)."""
        f, q = self.transition(dt)
        if self.misses and not self.velocity_significant():
            f[0, 7] = f[1, 8] = f[2, 9] = 0.0
        self.kf.predict(F=f, Q=q)
        self.kf.x[3, 0] = wrap_angle(float(self.kf.x[3, 0]))
        self.since_update += dt

    def update(self, z: np.ndarray, score: float, velocity: np.ndarray | None = None) -> None:
        """Correct with one detection ``(x, y, z, yaw, l, w, h)`` (its yaw flip-corrected) of score ``score``, then
        with the velocity ``velocity`` (3,) m/s it reports, if any (finite x and y; a second Kalman update of
        ``(vx, vy)`` with standard deviation ``detection_velocity_sigma``, 0: not used)."""
        z = np.array(z, dtype=np.float64)
        z[3] = corrected_yaw(float(z[3]), float(self.kf.x[3, 0]))
        self.kf.update(z.reshape(7, 1))
        sigma = self.config.detection_velocity_sigma
        reported = usable_velocity(velocity, self.config)
        if reported is not None:
            h = np.zeros((2, 10))
            h[0, 7] = h[1, 8] = 1.0
            self.kf.update(reported.reshape(2, 1), R=np.eye(2) * sigma**2, H=h)
        self.kf.x[3, 0] = wrap_angle(float(self.kf.x[3, 0]))
        self.kf.x[4:7, 0] = np.maximum(self.kf.x[4:7, 0], 1e-3)  # sizes stay positive
        self.scores.append(score)
        self.hits += 1
        self.misses = 0
        self.since_update = 0.0
        if self.hits >= self.config.min_hits or score >= self.config.confirm_score:
            self.confirmed = True

    def velocity_significant(self) -> bool:
        """Whether the bird's-eye velocity ``v`` = (vx, vy) is told from standstill: ``v^T P_v^-1 v`` >=
        ``coast_velocity_sigmas``^2 (``P_v`` its (2, 2) covariance)."""
        k = self.config.coast_velocity_sigmas
        if k <= 0:
            return True
        v = self.kf.x[7:9, 0]
        return float(v @ np.linalg.solve(self.kf.P[7:9, 7:9], v)) >= k * k

    @property
    def state(self) -> np.ndarray:
        """(7,) float64 the box ``(x, y, z, yaw, l, w, h)`` of the current state."""
        return self.kf.x[:7, 0].copy()

    @property
    def position_sigma(self) -> float:
        """Standard deviation of the predicted bird's-eye position, metres: ``sqrt(P_xx + P_yy)``."""
        return math.sqrt(float(self.kf.P[0, 0] + self.kf.P[1, 1]))

    @property
    def velocity(self) -> np.ndarray:
        """(3,) float64 velocity, m/s, in the tracking (world) frame."""
        return self.kf.x[7:10, 0].copy()

    @property
    def score(self) -> float:
        """The mean score of the detections matched so far."""
        return float(np.mean(self.scores))


def _box_row(b: Box) -> np.ndarray:
    return np.array([*b.center, b.yaw, *b.size], dtype=np.float64)


def _class_key(b: Box) -> str:
    return b.cls if b.cls else b.label.strip().lower()


def _check_order(frames: Sequence[DetectionFrame]) -> dict[str, list[int]]:
    """Indices of the frames of each sequence, in input order; :class:`ParameterError` unless times increase."""
    by_seq: dict[str, list[int]] = {}
    for i, f in enumerate(frames):
        t = float(f.timestamp)
        if not math.isfinite(t):
            raise ParameterError(f"frames: frame {f.frame_id!r} has a timestamp that is not finite")
        seq = by_seq.setdefault(f.sequence, [])
        if seq and t <= float(frames[seq[-1]].timestamp):
            raise ParameterError(
                f"frames: frame {f.frame_id!r} of sequence {f.sequence!r} is not later than the frame before it "
                "(frames of a sequence must come in time order)"
            )
        seq.append(i)
    return by_seq


class _Ids:
    def __init__(self) -> None:
        self.n = 0

    def next(self) -> str:
        self.n += 1
        return str(self.n)


def _match_class(
    tracks: list[KalmanTrack],
    ti: list[int],
    det: np.ndarray,
    di: list[int],
    scores: list[float],
    config: TrackerConfig,
    matched: tuple[set[int], set[int]],
    velocities: np.ndarray | None = None,
) -> None:
    """Match the detections ``di`` (rows of ``det``, (D, 7)) to the tracks ``ti`` of one class, GIoU first
    (when ``config.metric`` says so), then the centre distance for what is left; updates the matched tracks
    and adds their indices to ``matched`` = (detection indices, track indices); ``velocities`` (D, 3) the
    detections' reported velocities (world frame; NaN rows: none), or None."""
    matched_det, matched_tracks = matched
    pred = np.array([tracks[j].state for j in ti])
    gate = np.array(
        [min(config.gate_m, config.gate_floor_m + config.gate_sigmas * tracks[j].position_sigma) for j in ti]
    )
    stages = [] if config.metric != "giou" else [(giou_matrix(pred, det[di], gate), config.giou_threshold)]
    stages.append((-centre_distances(pred, det[di]), -config.max_distance_m))
    along = np.array([tracks[j].key in config.along_heading_classes for j in ti])
    if along.any():  # the sideways gate: a detection a width to the side of a vehicle is its neighbour
        reach = config.lateral_floor_m + config.lateral_speed_mps * np.array([tracks[j].since_update for j in ti])
        beside = along[:, None] & (lateral_offsets(pred, det[di]) > reach[:, None])
        stages = [(np.where(beside, -np.inf, sim), thr) for sim, thr in stages]
    for sim, thr in stages:  # GIoU first, then the centre distance for what is left
        free_t = [r for r in range(len(ti)) if ti[r] not in matched_tracks]
        free_d = [c for c in range(len(di)) if di[c] not in matched_det]
        for r, c in assign(sim[np.ix_(free_t, free_d)], thr):
            j, i = ti[free_t[r]], di[free_d[c]]
            tracks[j].update(det[i], scores[i], None if velocities is None else velocities[i])
            matched_tracks.add(j)
            matched_det.add(i)


def _associate(
    tracks: list[KalmanTrack],
    det: np.ndarray,
    keys: list,
    scores: list[float],
    config: TrackerConfig,
    velocities: np.ndarray | None = None,
) -> tuple[set[int], set[int]]:
    """Match one frame's detections (``det`` (D, 7) world rows, their class ``keys`` and ``scores``) to the
    tracks class by class, updating the matched tracks; returns (matched detection indices, matched track indices)."""
    matched: tuple[set[int], set[int]] = (set(), set())
    for key in sorted(set(keys) | {t.key for t in tracks}):
        di = [i for i, k in enumerate(keys) if k == key]
        ti = [j for j, t in enumerate(tracks) if t.key == key]
        if di and ti:
            _match_class(tracks, ti, det, di, scores, config, matched, velocities)
    return matched


def _reported(
    tracks: list[KalmanTrack], pose: np.ndarray | None, config: TrackerConfig
) -> tuple[list[Box], list[np.ndarray]]:
    """The boxes and (3,) velocities (m/s) of the tracks to report in a frame, in the frame's own coordinates
    (``pose``: its (4, 4) sensor-to-world transform, None when the frame is the world)."""
    boxes, velocities = [], []
    to_frame = None if pose is None else np.linalg.inv(pose)
    for tr in tracks:
        if not tr.confirmed or (tr.misses and not config.report_coasted):
            continue
        s = tr.state
        box = Box(s[:3], s[4:7], rotation_z(s[3]), tr.label, tr.cls, tr.track_id, min(1.0, tr.score))
        v = tr.velocity
        if to_frame is not None:
            box = box.transformed(to_frame)
            v = to_frame[:3, :3] @ v
        boxes.append(box)
        velocities.append(v)
    return boxes, velocities


def _world_velocities(f: DetectionFrame, pose: np.ndarray | None) -> np.ndarray | None:
    """(K, 3) float64 the frame's reported box velocities in the tracking (world) frame, m/s (rows may be NaN:
    unknown), or None when the frame reports none."""
    v = getattr(f, "velocities", None)  # a reader's Frame has none
    if v is None or len(v) != len(f.boxes):
        return None
    v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
    return v if pose is None else v @ pose[:3, :3].T


def _sequence(frames: list[DetectionFrame], config: TrackerConfig, ids: _Ids) -> list[DetectionFrame]:
    """Track the frames of one sequence (in time order)."""
    tracks: list[KalmanTrack] = []
    out = []
    t_prev = None
    for f in frames:
        pose = None if f.sensor_to_world is None else np.asarray(f.sensor_to_world, dtype=np.float64)
        world = [b if pose is None else b.transformed(pose) for b in f.boxes]
        if t_prev is not None:
            dt = float(f.timestamp) - t_prev
            for tr in tracks:
                tr.predict(dt)
        t_prev = float(f.timestamp)
        det = np.array([_box_row(b) for b in world]).reshape(-1, 7)
        keys = [_class_key(b) for b in world]
        scores = [1.0 if b.score is None else b.score for b in world]
        velocity = _world_velocities(f, pose)
        matched_det, matched_tracks = _associate(tracks, det, keys, scores, config, velocity)
        for j, tr in enumerate(tracks):
            if j not in matched_tracks:
                tr.misses += 1
        tracks = [t for t in tracks if t.misses < config.max_misses]
        for i, b in enumerate(world):
            if i not in matched_det and scores[i] >= config.birth_score:
                v = None if velocity is None else velocity[i]
                tracks.append(KalmanTrack(det[i], config, ids.next(), keys[i], b.cls, b.label, scores[i], v))
        boxes, velocities = _reported(tracks, pose, config)
        out.append(
            DetectionFrame(
                f.sequence,
                f.frame_id,
                f.timestamp,
                boxes,
                f.sensor_to_world,
                f.scan_path,
                np.array(velocities, dtype=np.float64).reshape(-1, 3),
            )  # fmt: skip
        )
    return out


def track_boxes(frames: Sequence[DetectionFrame], config: TrackerConfig | None = None) -> list[DetectionFrame]:
    """Track detections: the frames with their tracks' boxes (see the module docstring).

    Parameters
    ----------
    frames : :class:`~spotlights.tracking.detections.DetectionFrame` list (any object with ``sequence``,
        ``frame_id``, ``timestamp`` (seconds), ``boxes`` and ``sensor_to_world`` works, e.g. a reader's
        ``Frame`` whose timestamp is converted to seconds); the frames of each sequence in time order
        (sequences may follow one another or interleave). Boxes: metres, the frame's coordinates, with an
        optional ``score`` in [0, 1] and a class (``cls``, else ``label``).
    config : :class:`TrackerConfig` (default settings when None).

    Returns
    -------
    One :class:`DetectionFrame` per input frame, in the input order: the confirmed tracks' boxes in that frame
    (the filter's estimate, in the frame's own coordinates) with ``track_id`` set (ids unique over the call) and
    ``score`` = the track's mean detection score, and ``velocities`` (K, 3) float64 m/s in the same coordinates.
    :class:`ParameterError` for frames out of time order.
    """
    config = TrackerConfig() if config is None else config
    frames = list(frames)
    by_seq = _check_order(frames)
    ids = _Ids()
    out: list[DetectionFrame | None] = [None] * len(frames)
    for seq in by_seq:  # sequences in order of first appearance: ids deterministic
        idx = by_seq[seq]
        for i, f in zip(idx, _sequence([frames[i] for i in idx], config, ids)):
            out[i] = f
    n_tracks = ids.n
    log.info("tracked %d frame(s): %d track(s) started", len(frames), n_tracks)
    return [f for f in out if f is not None]
