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
        dist = np.array([float(np.hypot(*b.center[:2])) for b in f.boxes]).reshape(-1)
        ok = [
            b.cls in classes and counts[i] >= model.min_points and dist[i] <= model.range_m
            for i, b in enumerate(f.boxes)
        ]
        idx = [i for i in range(len(f.boxes)) if ok[i]]
        gt = [f.boxes[i] for i in idx]
        truth.append(replace(f, boxes=gt, velocities=None))
        out: list[Box] = []
        if idx:
            h = _hardness(dist[idx], counts[idx], model.range_m)
            w = 0.25 + 1.5 * h
            p_miss = np.clip(model.miss_rate * w / w.mean(), 0.0, 1.0)
            missed = rng.random(len(idx)) < p_miss
            for k, b in enumerate(gt):
                noise = rng.normal(size=6)  # drawn for every box, so one miss does not shift the others' noise
                flip = rng.random() < model.flip_rate
                score = float(np.clip(0.9 - 0.5 * h[k] + 0.1 * rng.normal(), 0.05, 1.0))
                if missed[k]:
                    continue
                center = b.center + model.position_sigma_m * noise[:3]
                size = b.size * np.maximum(1.0 + model.size_sigma_rel * noise[3:6], 0.1)
                yaw = b.yaw + math.radians(model.yaw_sigma_deg) * rng.normal() + (math.pi if flip else 0.0)
                out.append(Box(center, size, rotation_z(yaw), b.label, b.cls, "", score))
        n_fp = int(rng.poisson(model.false_positive_rate * len(idx)))
        for _ in range(n_fp):
            r = math.sqrt(rng.uniform(25.0, model.range_m**2))  # uniform over the ring's area
            a, yaw = rng.uniform(-math.pi, math.pi, size=2)
            score = 0.05 + 0.35 * float(rng.beta(2.0, 3.0))
            if gt:
                like = gt[int(rng.integers(len(gt)))]
                size = like.size * np.maximum(1.0 + 0.1 * rng.normal(size=3), 0.3)
                z, label, cls = float(like.center[2]), like.label, like.cls
            else:
                size, z, label, cls = np.array([4.5, 1.9, 1.7]), -1.0, "car", "car"
            out.append(Box([r * math.cos(a), r * math.sin(a), z], size, rotation_z(yaw), label, cls, "", score))
        out.sort(key=lambda b: -(b.score or 0.0))
        dets.append(replace(f, boxes=out, velocities=None))
    return dets, truth


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
    return frames, counts
