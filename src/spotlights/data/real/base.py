"""The reader interface for real LiDAR data: scans and oriented vehicle boxes.

A dataset reader turns a folder (or file) into a sequence of :class:`Frame`
objects. Each frame holds one LiDAR scan in its **sensor frame** and the
annotated boxes of that scan, expressed in the same sensor frame. A new dataset
is one module that subclasses :class:`SceneReader` and implements
:meth:`SceneReader.frames`; the extraction (:mod:`spotlights.data.real.extract`)
knows nothing about file formats.

Conventions
-----------
- Sensor frame: the frame the scan's points are stored in (KITTI, KITTI-360:
  the Velodyne frame, x forward, y left, z up; Argoverse 2: the ego-vehicle
  frame, same axes), metres.
- Box: :class:`spotlights.geometry.boxes.Box` (the one box class): ``center``
  (3,) metres in the sensor frame, ``size`` = (length, width, height) metres
  along the box's own x (forward), y (left), z (up) axes, and ``rotation``
  (3, 3) whose **columns** are those box axes expressed in the sensor frame (so
  ``p_object = (p_sensor - center) @ rotation``), plus ``label``, ``cls`` and
  ``track_id``.
- Classes: every reader maps its own labels to the vehicle classes
  (:data:`CLASSES`; the paper's Table 2 has the first four) or to ``None`` (not
  a vehicle of interest, e.g. bicycles and motorcycles; counted as skipped by label).
"""

from __future__ import annotations

import abc
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ...geometry.boxes import Box
from ...geometry.rotations import orthonormalize, quaternion_to_matrix, rotation_z

#: Every vehicle class a reader maps its labels to. The first four are the classes of
#: the paper's Table 2 (:data:`PAPER_CLASSES`); ``caravan`` is the van/caravan class
#: (KITTI ``Van``, KITTI-360 ``caravan``, Argoverse 2 ``LARGE_VEHICLE``). ``bus``,
#: ``construction`` and ``emergency`` come from nuScenes' (and AV2's) richer taxonomies.
CLASSES: tuple[str, ...] = ("car", "truck", "caravan", "trailer", "bus", "construction", "emergency")

#: The classes of the paper's Table 2: the default of ``real extract``.
PAPER_CLASSES: tuple[str, ...] = ("car", "truck", "caravan", "trailer")


@dataclass
class Frame:
    """One LiDAR scan with its boxes.

    Attributes
    ----------
    sequence : the log / drive / folder the frame belongs to (tracks are unique within it).
    frame_id : the frame's name within its sequence (e.g. ``"000123"`` or a timestamp).
    timestamp : time key that orders the frames of a sequence, in the source's unit, an
        int or a float (never cut: ints stay exact, floats keep their fraction):
        nanoseconds for Argoverse 2, microseconds for nuScenes, the frame index for KITTI
        and KITTI-360, as given (e.g. seconds as floats) for generic frames.
    points : (N, 3) float32, metres, sensor frame.
    boxes : the annotated boxes of this scan, sensor frame.
    sensor_to_world : (4, 4) float64 pose of the sensor frame in a fixed world
        frame (Argoverse 2 city frame, KITTI-360 world frame), or ``None``.
    scan_path, label_path : the files read (for provenance and ``real show``).
    sensor_origin : (3,) float64 position of the LiDAR's optical centre in the sensor frame, metres;
        ``None`` (the default) means the sensor frame's origin (KITTI, KITTI-360, nuScenes, generic:
        the points are stored in the LiDAR's own frame). Argoverse 2 sweeps are in the ego frame: its
        reader gives the ``up_lidar`` position from the log's calibration (all NaN when the log has none).
    """

    sequence: str
    frame_id: str
    timestamp: int | float
    points: np.ndarray
    boxes: list[Box]
    sensor_to_world: np.ndarray | None = None
    scan_path: str = ""
    label_path: str = ""
    sensor_origin: np.ndarray | None = None

    def lidar_origin(self) -> np.ndarray:
        """(3,) float64 the LiDAR's optical centre in the sensor frame (zeros when :attr:`sensor_origin` is None;
        NaN where the dataset says it is unknown)."""
        return np.zeros(3) if self.sensor_origin is None else np.asarray(self.sensor_origin, dtype=np.float64)

    def lidar_known(self) -> bool:
        """Whether :meth:`lidar_origin` is a place (False for an Argoverse 2 log without calibration: its NaN)."""
        return bool(np.all(np.isfinite(self.lidar_origin())))


class SceneReader(abc.ABC):
    """A dataset: an ordered, finite sequence of :class:`Frame` objects.

    Subclasses set :attr:`format` (the ``--format`` name) and implement
    :meth:`frame_keys` (cheap: no scan is read) and :meth:`load` (reads one
    frame). Constructors validate the folder layout and raise
    :class:`spotlights.errors.InputFileError` naming the missing or bad file.
    """

    format: str = ""

    #: Where the scans of this dataset are, used to read a raw scan back for ``real show``.
    root: str = ""

    @abc.abstractmethod
    def frame_keys(self) -> list[tuple[str, str]]:
        """The (sequence, frame_id) of every frame, in sequence then time order."""

    @abc.abstractmethod
    def load(self, key: tuple[str, str]) -> Frame:
        """Read one frame (scan and boxes) by its key from :meth:`frame_keys`."""

    def frames(self) -> Iterator[Frame]:
        """Every frame, in the order of :meth:`frame_keys`."""
        for key in self.frame_keys():
            yield self.load(key)

    def __len__(self) -> int:
        return len(self.frame_keys())


def finite_rows(points: np.ndarray) -> np.ndarray:
    """``points`` (N, 3) without the rows holding NaN or an infinity (no-return points of organised scans, damaged
    records): what the sensor-scan readers (KITTI .bin, nuScenes .pcd.bin, AV2 feather) return, so every dataset
    reader and ``read_scan`` give finite points; the same array when every row is finite."""
    keep = np.all(np.isfinite(points), axis=1)
    return points if keep.all() else points[keep]


def lookup_class(label: str, table: dict[str, str | None]) -> str | None:
    """Map a dataset label to one of :data:`CLASSES` (case-insensitive); ``None`` if unmapped."""
    return table.get(label.strip().lower())


__all__ = [
    "CLASSES",
    "PAPER_CLASSES",
    "Box",
    "Frame",
    "SceneReader",
    "finite_rows",
    "lookup_class",
    "orthonormalize",
    "quaternion_to_matrix",
    "rotation_z",
]
