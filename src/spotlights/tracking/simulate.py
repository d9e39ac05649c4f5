"""A detector simulated from ground-truth boxes: misses, false positives, noisy boxes and scores (seeded).

:func:`simulate_detections` turns annotated frames into what a LiDAR detector would give, frame by frame,
independently (a detector has no memory), with one random stream (``numpy.random.default_rng(seed)``; the same
frames, model and seed give the same detections):

* **Which boxes count.** A ground-truth box of one of ``classes`` with at least ``min_points`` LiDAR points and its
  centre within ``range_m`` of the sensor (the frame's origin, bird's eye) is *detectable*; the others are never
  detected (nuScenes' detection and tracking evaluations leave them out too: :func:`simulate_detections` returns the
  detectable boxes as the truth to score against).
* **Hardness** of a detectable box: ``h = (d / range_m + 1 - min(1, log(1 + n) / log(1 + 200))) / 2`` in [0, 1]
  (``d`` its distance, metres; ``n`` its point count): far boxes and boxes with few points are hard.
* **Misses.** A detectable box is missed with probability ``miss_rate * (0.25 + 1.5 h) / mean(0.25 + 1.5 h)``
  (the mean over the frame's detectable boxes, clipped to [0, 1]): the share of missed boxes is ``miss_rate`` on
  average, and hard boxes are missed more often (up to 7x an easy one).
* **Noise** of a detected box: its centre + N(0, ``position_sigma_m``^2) on each of x, y, z; its heading +
  N(0, ``yaw_sigma_deg``^2) degrees and turned by 180 degrees with probability ``flip_rate``; each of length, width,
  height x (1 + N(0, ``size_sigma_rel``^2)) (at least 0.1 of the true side).
* **Scores.** A detected box scores ``clip(0.9 - 0.5 h + N(0, 0.1^2), 0.05, 1)``.
* **Velocities** (only with ``velocity_sigma_mps``, as detectors such as CenterPoint report them): the true box's
  velocity (the truth frames' ``velocities``: :func:`nuscenes_ground_truth` gives them) + N(0,
  ``velocity_sigma_mps``^2) on x and y, z 0 (the sensor frame's: nuScenes reports are horizontal in the global
  frame, nearly the same for a level sensor); a false positive's: N(0, ``velocity_sigma_mps``^2) on x and y.
  Without it the detections carry no velocity and the random stream is that of a detector without one.
* **False positives.** Per frame, Poisson(``false_positive_rate`` x detectable boxes) boxes at uniform bird's-eye
  positions between 5 m and ``range_m`` from the sensor, a uniform heading, the class, size (x (1 + N(0, 0.1^2)))
  and height of a random detectable box of the frame (a car 4.5 x 1.9 x 1.7 m at z = -1 m when there is none), and
  low scores ``0.05 + 0.35 Beta(2, 3)`` (in [0.05, 0.40], mean 0.19).

Detections come without track ids, sorted by decreasing score, with the true box's label and class.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..data.real.base import CLASSES
from ..errors import ParameterError
from ..geometry.boxes import Box
from ..geometry.rotations import rotation_z
from .detections import DetectionFrame


@dataclass(frozen=True)
class DetectorModel:
    """The simulated detector's settings (see the module docstring); rates are shares of the detectable boxes."""

    miss_rate: float = 0.10
    false_positive_rate: float = 0.10
    position_sigma_m: float = 0.15
    yaw_sigma_deg: float = 3.0
    size_sigma_rel: float = 0.05
    flip_rate: float = 0.0
    range_m: float = 50.0
    min_points: int = 1
    velocity_sigma_mps: float | None = None

    def __post_init__(self) -> None:
        for name in ("miss_rate", "flip_rate"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ParameterError(f"{name}: a probability in [0, 1], got {getattr(self, name)}")
        for name in ("false_positive_rate", "position_sigma_m", "yaw_sigma_deg", "size_sigma_rel"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v <= 100.0):
                raise ParameterError(f"{name}: a number in [0, 100], got {v}")
        if not (math.isfinite(self.range_m) and self.range_m > 5.0):
            raise ParameterError(f"range_m: more than 5 m, got {self.range_m}")
        if self.min_points < 0:
            raise ParameterError(f"min_points: >= 0, got {self.min_points}")
        v = self.velocity_sigma_mps
        if v is not None and not (math.isfinite(v) and 0.0 <= v <= 100.0):
            raise ParameterError(f"velocity_sigma_mps: None or a number in [0, 100], got {v}")


def _hardness(distance: np.ndarray, points: np.ndarray, range_m: float) -> np.ndarray:
    pts = np.minimum(1.0, np.log1p(points) / math.log1p(200.0))
    return 0.5 * (distance / range_m + 1.0 - pts)


def simulate_detections(
    frames: list[DetectionFrame],
    point_counts: list[np.ndarray],
    model: DetectorModel | None = None,
    seed: int = 0,
    classes: tuple[str, ...] = CLASSES,
) -> tuple[list[DetectionFrame], list[DetectionFrame]]:
    """Detections simulated from the ground-truth frames (module docstring).

    Parameters
    ----------
    frames : ground truth: boxes with track ids in each frame's sensor coordinates (the sensor at the origin, z up).
    point_counts : per frame, (len(frame.boxes),) the LiDAR points in each box.
    model : :class:`DetectorModel` (default settings when None).
    seed : the random stream's seed.
    classes : the classes a detector reports.

    Returns
    -------
    (detections, truth): per frame, the simulated detections (no track id, with scores), and the detectable
    ground-truth boxes (the ones to score a tracker against).
    """
    model = DetectorModel() if model is None else model
    if len(point_counts) != len(frames):
        raise ParameterError(f"point_counts: one array per frame ({len(frames)}), got {len(point_counts)}")
    rng = np.random.default_rng(seed)
    dets, truth = [], []
    for f, counts in zip(frames, point_counts):
        counts = np.asarray(counts, dtype=np.float64).reshape(-1)
        if len(counts) != len(f.boxes):
            raise ParameterError(
                f"point_counts: frame {f.frame_id!r} has {len(f.boxes)} boxes, got {len(counts)} counts"
            )
        true_v = _true_velocities(f, model)
        dist = np.array([float(np.hypot(*b.center[:2])) for b in f.boxes]).reshape(-1)
        idx = [
            i
            for i, b in enumerate(f.boxes)
            if b.cls in classes and counts[i] >= model.min_points and dist[i] <= model.range_m
        ]
        gt = [f.boxes[i] for i in idx]
        truth.append(replace(f, boxes=gt, velocities=None if true_v is None else true_v[idx]))
        gt_v = None if true_v is None else true_v[idx]
        found = _detected(gt, gt_v, dist[idx], counts[idx], model, rng)
        for _ in range(int(rng.poisson(model.false_positive_rate * len(idx)))):
            box = _false_positive(gt, model, rng)
            found.append((box, None if true_v is None else _noisy_velocity(np.zeros(3), model, rng)))
        found.sort(key=lambda bv: -(bv[0].score or 0.0))
        velocities = None if true_v is None else np.array([v for _, v in found], dtype=np.float64).reshape(-1, 3)
        dets.append(replace(f, boxes=[b for b, _ in found], velocities=velocities))
    return dets, truth


def _detected(
    gt: list[Box],
    gt_v: np.ndarray | None,
    dist: np.ndarray,
    counts: np.ndarray,
    model: DetectorModel,
    rng: np.random.Generator,
) -> list[tuple[Box, np.ndarray | None]]:
    """The detected boxes of a frame's detectable boxes ``gt`` (their distances, metres, point counts and, when the
    detector reports velocities, (K, 3) velocities ``gt_v``): misses by hardness, noise (module docstring)."""
    found: list[tuple[Box, np.ndarray | None]] = []
    if not gt:
        return found
    h = _hardness(dist, counts, model.range_m)
    w = 0.25 + 1.5 * h
    missed = rng.random(len(gt)) < np.clip(model.miss_rate * w / w.mean(), 0.0, 1.0)
    for k, b in enumerate(gt):
        box = _noisy_box(b, h[k], bool(missed[k]), model, rng)
        if box is not None:
            found.append((box, None if gt_v is None else _noisy_velocity(gt_v[k], model, rng)))
    return found


def _true_velocities(f: DetectionFrame, model: DetectorModel) -> np.ndarray | None:
    """(K, 3) the truth frame's box velocities when the detector reports velocities (else None)."""
    if model.velocity_sigma_mps is None:
        return None
    if f.velocities is None or len(f.velocities) != len(f.boxes):
        raise ParameterError(
            f"frames: frame {f.frame_id!r} has no box velocities, and velocity_sigma_mps asks for them "
            "(nuscenes_ground_truth gives them)"
        )
    return np.asarray(f.velocities, dtype=np.float64).reshape(-1, 3)


def _noisy_box(b: Box, hardness: float, missed: bool, model: DetectorModel, rng: np.random.Generator) -> Box | None:
    """A detected box: ``b`` with the noise, flip and score of the module docstring; None when ``missed``. Position,
    size, flip and score are drawn for every box, missed or not, so that one miss does not shift the others' noise."""
    noise = rng.normal(size=6)
    flip = rng.random() < model.flip_rate
    score = float(np.clip(0.9 - 0.5 * hardness + 0.1 * rng.normal(), 0.05, 1.0))
    if missed:
        return None
    center = b.center + model.position_sigma_m * noise[:3]
    size = b.size * np.maximum(1.0 + model.size_sigma_rel * noise[3:6], 0.1)
    yaw = b.yaw + math.radians(model.yaw_sigma_deg) * rng.normal() + (math.pi if flip else 0.0)
    return Box(center, size, rotation_z(yaw), b.label, b.cls, "", score)


def _noisy_velocity(v: np.ndarray, model: DetectorModel, rng: np.random.Generator) -> np.ndarray:
    """(3,) a reported velocity: ``v`` + N(0, velocity_sigma_mps^2) on x and y, z 0."""
    out = np.zeros(3)
    out[:2] = np.asarray(v, dtype=np.float64)[:2] + float(model.velocity_sigma_mps or 0.0) * rng.normal(size=2)
    return out


def _false_positive(gt: list[Box], model: DetectorModel, rng: np.random.Generator) -> Box:
    """A false positive of the module docstring, like a random box of ``gt`` (a car where ``gt`` is empty)."""
    r = math.sqrt(rng.uniform(25.0, model.range_m**2))  # uniform over the ring's area
    a, yaw = rng.uniform(-math.pi, math.pi, size=2)
    score = 0.05 + 0.35 * float(rng.beta(2.0, 3.0))
    if gt:
        like = gt[int(rng.integers(len(gt)))]
        size = like.size * np.maximum(1.0 + 0.1 * rng.normal(size=3), 0.3)
        z, label, cls = float(like.center[2]), like.label, like.cls
    else:
        size, z, label, cls = np.array([4.5, 1.9, 1.7]), -1.0, "car", "car"
    return Box([r * math.cos(a), r * math.sin(a), z], size, rotation_z(yaw), label, cls, "", score)


def nuscenes_ground_truth(reader) -> tuple[list[DetectionFrame], list[np.ndarray]]:
    """A nuScenes reader's keyframes as detection frames to simulate a detector from: the annotated boxes
    (LIDAR_TOP frame, metres), timestamps in seconds (the reader's microseconds), the sensor poses; and per frame
    each box's ``num_lidar_pts`` as a (K,) float64 array (the point counts of :func:`simulate_detections`)."""
    frames, counts = [], []
    for key in reader.frame_keys():
        fr = reader.load(key)
        rows = reader.annotations(key)
        frames.append(DetectionFrame(fr.sequence, fr.frame_id, fr.timestamp * 1e-6, fr.boxes, fr.sensor_to_world))
        counts.append(np.array([r.get("num_lidar_pts", 0) for r in rows], dtype=np.float64))
    return box_velocities(frames), counts


def box_velocities(frames: list[DetectionFrame]) -> list[DetectionFrame]:
    """The frames with ``velocities`` set: each box's velocity (m/s, the frame's coordinates, z included) from its
    track's centres in the world frame (``sensor_to_world``; the frames' own where None) by finite differences over
    time, central where the track has a box in the frames before and after (one-sided at its ends; zero for a
    track seen once). Tracks are the boxes' ``track_id`` within each ``sequence``; frames in time order."""
    world: dict[tuple[str, str], list[tuple[float, np.ndarray]]] = {}
    for f in frames:
        pose = np.eye(4) if f.sensor_to_world is None else np.asarray(f.sensor_to_world, dtype=np.float64)
        for b in f.boxes:
            world.setdefault((f.sequence, b.track_id), []).append(
                (float(f.timestamp), pose[:3, :3] @ b.center + pose[:3, 3])
            )
    out = []
    for f in frames:
        pose = np.eye(4) if f.sensor_to_world is None else np.asarray(f.sensor_to_world, dtype=np.float64)
        rows = []
        for b in f.boxes:
            seen = world[(f.sequence, b.track_id)]
            k = next(i for i, (t, _) in enumerate(seen) if t == float(f.timestamp))
            (t0, p0), (t1, p1) = seen[max(k - 1, 0)], seen[min(k + 1, len(seen) - 1)]
            v_world = (p1 - p0) / (t1 - t0) if t1 > t0 else np.zeros(3)
            rows.append(pose[:3, :3].T @ v_world)
        out.append(replace(f, velocities=np.array(rows, dtype=np.float64).reshape(-1, 3)))
    return out
