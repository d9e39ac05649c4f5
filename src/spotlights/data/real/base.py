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
- Box: ``center`` (3,) metres in the sensor frame, ``size`` = (length, width,
  height) metres along the box's own x (forward), y (left), z (up) axes, and
  ``rotation`` (3, 3) whose **columns** are those box axes expressed in the
  sensor frame (so ``p_object = (p_sensor - center) @ rotation``). This is
  exactly the box of :func:`spotlights.geometry.frames.normalization_from_box`.
- Classes: every reader maps its own labels to the four vehicle classes of
  the paper's Table 2 (:data:`CLASSES`) or to ``None`` (not a vehicle of
  interest; counted as skipped by label).
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np

#: The vehicle classes of the paper's Table 2. ``caravan`` is the van/caravan
#: class (KITTI ``Van``, KITTI-360 ``caravan``, Argoverse 2 ``LARGE_VEHICLE``).
CLASSES: tuple[str, ...] = ("car", "truck", "caravan", "trailer")


def rotation_z(yaw: float) -> np.ndarray:
    """(3, 3) float64 rotation by ``yaw`` radians about +z (counter-clockwise seen from above)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def orthonormalize(m: np.ndarray) -> np.ndarray:
    """Nearest proper rotation (3, 3) float64 to ``m`` (polar decomposition via SVD).

    Calibration chains (e.g. KITTI's ``R0_rect`` times ``Tr_velo_to_cam``) are
    rotations only up to rounding; boxes need an exact one.
    """
    u, _, vt = np.linalg.svd(np.asarray(m, dtype=np.float64))
    r = u @ vt
    if np.linalg.det(r) < 0:  # improper: flip the weakest axis
        u[:, -1] = -u[:, -1]
        r = u @ vt
    return r


def quaternion_to_matrix(qw, qx, qy, qz) -> np.ndarray:
    """Rotation matrices from scalar-first unit quaternions.

    Inputs are scalars or arrays of shape (n,); returns (3, 3) or (n, 3, 3)
    float64. The quaternions are normalised first.
    """
    q = np.stack(np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (qw, qx, qy, qz))), axis=-1)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    m = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return m.reshape(q.shape[:-1] + (3, 3))


@dataclass(frozen=True)
class Box:
    """An oriented 3D box of one annotated object, in the sensor frame of its scan.

    Attributes
    ----------
    center : (3,) float64, metres, sensor frame (the box centre, not its bottom).
    size : (3,) float64, metres: (length, width, height) along the box's x, y, z.
    rotation : (3, 3) float64, columns = box x (forward), y (left), z (up) axes
        in the sensor frame (a proper rotation).
    label : the dataset's own label (e.g. ``"Van"``, ``"REGULAR_VEHICLE"``).
    cls : one of :data:`CLASSES`, or ``None`` when the label is not a vehicle of interest.
    track_id : identity of the object across frames (``""`` when the dataset has none).
    """

    center: np.ndarray
    size: np.ndarray
    rotation: np.ndarray
    label: str
    cls: str | None
    track_id: str = ""

    @classmethod
    def from_yaw(cls_, center, size, yaw: float, label: str, cls: str | None, track_id: str = "") -> "Box":
        """A box rotated by ``yaw`` radians about the sensor's +z axis."""
        return cls_(np.asarray(center, np.float64), np.asarray(size, np.float64), rotation_z(yaw), label, cls, track_id)

    @property
    def yaw(self) -> float:
        """Heading of the box's x axis about the sensor's z axis, radians in (-pi, pi]."""
        return math.atan2(self.rotation[1, 0], self.rotation[0, 0])

    @property
    def radius(self) -> float:
        """Half the box diagonal, metres (the unit-sphere radius R of the normalisation)."""
        return 0.5 * float(np.linalg.norm(self.size))

    def is_valid(self) -> bool:
        """True when centre, size and rotation are finite and all sizes are positive."""
        return bool(
            np.all(np.isfinite(self.center))
            and np.all(np.isfinite(self.size))
            and np.all(np.isfinite(self.rotation))
            and np.all(self.size > 0)
        )

    def corners(self) -> np.ndarray:
        """(8, 3) float64 corners in the sensor frame.

        Order: index ``4*i + 2*j + k`` has object coordinates
        ``(±l/2, ±w/2, ±h/2)`` with i, j, k = 0 for + and 1 for - along x, y, z.
        """
        signs = np.array([[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)], dtype=np.float64)
        return self.center + (signs * (0.5 * self.size)) @ self.rotation.T

    def to_object(self, points: np.ndarray) -> np.ndarray:
        """Sensor-frame points (..., 3) -> object frame (..., 3) float64, metres."""
        return (np.asarray(points, dtype=np.float64) - self.center) @ self.rotation

    def transformed(self, t: np.ndarray) -> "Box":
        """This box moved by the rigid 4x4 transform ``t`` (new_frame <- this box's frame)."""
        t = np.asarray(t, dtype=np.float64)
        rot = orthonormalize(t[:3, :3] @ self.rotation)
        return Box(t[:3, :3] @ self.center + t[:3, 3], self.size.copy(), rot, self.label, self.cls, self.track_id)


@dataclass
class Frame:
    """One LiDAR scan with its boxes.

    Attributes
    ----------
    sequence : the log / drive / folder the frame belongs to (tracks are unique within it).
    frame_id : the frame's name within its sequence (e.g. ``"000123"`` or a timestamp).
    timestamp : integer time key used to order frames of a sequence (nanoseconds
        for Argoverse 2; the frame index for KITTI and KITTI-360).
    points : (N, 3) float32, metres, sensor frame.
    boxes : the annotated boxes of this scan, sensor frame.
    sensor_to_world : (4, 4) float64 pose of the sensor frame in a fixed world
        frame (Argoverse 2 city frame, KITTI-360 world frame), or ``None``.
    scan_path, label_path : the files read (for provenance and ``real show``).
    """

    sequence: str
    frame_id: str
    timestamp: int
    points: np.ndarray
    boxes: list[Box]
    sensor_to_world: np.ndarray | None = None
    scan_path: str = ""
    label_path: str = ""


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


def lookup_class(label: str, table: dict[str, str | None]) -> str | None:
    """Map a dataset label to one of :data:`CLASSES` (case-insensitive); ``None`` if unmapped."""
    return table.get(label.strip().lower())
