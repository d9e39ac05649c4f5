"""CLEAR-MOT and identity metrics of tracks against ground truth, with py-motmetrics.

:func:`clear_mot` pairs each tracked frame with its ground-truth frame (same ``sequence`` and ``frame_id``) and feeds
``motmetrics.MOTAccumulator`` the centre distances (metres, bird's eye, the frames' own coordinates) of every
ground-truth box to every tracked box of the same class, pairs farther than ``max_distance_m`` (2 m, the nuScenes
tracking threshold) excluded. Ground-truth ids are prefixed with their sequence. The metrics are motmetrics':
MOTA = 1 - (misses + false positives + identity switches) / ground-truth boxes; MOTP (here the mean matched centre
distance, metres); IDF1 (the F1 of identity-preserving matches); identity switches; mostly tracked / lost.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from .detections import DetectionFrame


def _centres(boxes) -> np.ndarray:
    return np.array([b.center[:2] for b in boxes], dtype=np.float64).reshape(-1, 2)


def clear_mot(
    truth: list[DetectionFrame], tracked: list[DetectionFrame], max_distance_m: float = 2.0
) -> dict[str, float | int]:
    """MOTA, MOTP, IDF1, identity switches and counts of ``tracked`` against ``truth`` (module docstring).

    Returns a dict: ``mota``, ``motp_m``, ``idf1``, ``id_switches``, ``id_switches_per_100_tracks`` (per 100
    ground-truth tracks), ``false_positives``, ``misses``, ``gt_boxes``, ``gt_tracks``, ``mostly_tracked``,
    ``mostly_lost``, ``frames``. Frames of ``truth`` with no tracked frame count as frames with no track.
    """
    import motmetrics as mm

    if not max_distance_m > 0:
        raise ParameterError(f"max_distance_m: a positive distance, got {max_distance_m}")
    hyp = {(f.sequence, f.frame_id): f for f in tracked}
    acc = mm.MOTAccumulator(auto_id=True)
    gt_number: dict[str, int] = {}  # motmetrics 1.4 keeps ids as numbers
    hyp_number: dict[str, int] = {}
    for f in truth:
        h = hyp.get((f.sequence, f.frame_id))
        hb = [] if h is None else h.boxes
        gc, hc = _centres(f.boxes), _centres(hb)
        d = (
            np.linalg.norm(gc[:, None, :] - hc[None, :, :], axis=-1)
            if len(gc) and len(hc)
            else np.zeros((len(gc), len(hc)))
        )
        same = np.array([[g.cls == t.cls for t in hb] for g in f.boxes], dtype=bool).reshape(d.shape)
        d = np.where(same & (d <= max_distance_m), d, np.nan)
        gt_ids = [gt_number.setdefault(f"{f.sequence}/{b.track_id}", len(gt_number)) for b in f.boxes]
        acc.update(gt_ids, [hyp_number.setdefault(b.track_id, len(hyp_number)) for b in hb], d)
    names = ["mota", "motp", "idf1", "num_switches", "num_false_positives", "num_misses", "num_objects",
             "num_unique_objects", "mostly_tracked", "mostly_lost", "num_frames"]  # fmt: skip
    row = mm.metrics.create().compute(acc, metrics=names, name="all").loc["all"]
    n_tracks = int(row["num_unique_objects"])
    return {
        "mota": float(row["mota"]),
        "motp_m": float(row["motp"]),
        "idf1": float(row["idf1"]),
        "id_switches": int(row["num_switches"]),
        "id_switches_per_100_tracks": 100.0 * int(row["num_switches"]) / max(n_tracks, 1),
        "false_positives": int(row["num_false_positives"]),
        "misses": int(row["num_misses"]),
        "gt_boxes": int(row["num_objects"]),
        "gt_tracks": n_tracks,
        "mostly_tracked": int(row["mostly_tracked"]),
        "mostly_lost": int(row["mostly_lost"]),
        "frames": int(row["num_frames"]),
    }
