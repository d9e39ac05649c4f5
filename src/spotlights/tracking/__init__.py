"""From a detector's boxes to tracks: detection readers, a 3-D tracker, writers, a simulated detector, metrics.

- :mod:`.detections` - detections as input (nuScenes result JSON, KITTI results with scores, the generic box
  JSON with scores), the detector class map, the score filter; :class:`DetectionFrame`.
- :mod:`.association` - 3-D GIoU of oriented boxes, centre distances, the optimal assignment.
- :mod:`.tracker` - the tracker (:func:`track_boxes`, :class:`TrackerConfig`): a Kalman filter per track.
- :mod:`.outputs` - tracks as the generic sequence JSON and as a nuScenes tracking result JSON.
- :mod:`.simulate` - detections simulated from ground truth (:func:`simulate_detections`).
- :mod:`.evaluate` - MOTA, IDF1, identity switches (py-motmetrics).

A floor between ``learning`` and ``experiments``: it imports ``geometry``, ``metrics`` and ``data`` only, and no
torch; filterpy, shapely and motmetrics (the ``track`` extra) are imported where they are used.
"""

from __future__ import annotations

from .detections import DetectionFrame, filter_detections, read_detections
from .tracker import TrackerConfig, track_boxes

__all__ = ["DetectionFrame", "TrackerConfig", "filter_detections", "read_detections", "track_boxes"]
