"""The oriented 3-D box of an object: one class for detector boxes, annotations and the normalisation.

Convention (everywhere in spotlights): ``center`` (3,) is the box's geometric
centre (not its bottom), ``size`` = (length, width, height) along the box's own
x (forward), y (left), z (up) axes, and ``rotation`` (3, 3) has as **columns**
those three axes expressed in the frame of the scan (sensor, ego or world), so

    p_object = (p_scan - center) @ rotation         p_scan = p_object @ rotation.T + center

A box given by a heading has ``rotation = rotation_z(yaw)``. The box's unit
frame (where the models work) is its object frame divided by R = half the box
diagonal (:attr:`Box.radius`): :meth:`Box.normalization`; the box's half-extents
there are ``size / (2 R)`` (:func:`unit_extents`, norm 1).

**Corner order** (:data:`CORNER_SIGNS`, :func:`corners`, :meth:`Box.corners`): corner
``4*i + 2*j + k`` is at object coordinates ``(sx l/2, sy w/2, sz h/2)`` with ``sx = +1``
for i = 0 and -1 for i = 1 (likewise j for y, k for z): corner 0 is (+, +, +), corner 7
(-, -, -); even corners are the top face, odd ones the bottom face. :data:`BOX_EDGES`
lists the 12 edges as corner pairs. This module is the one owner of a box's corners,
radius, unit extents, containment and crop; nothing else computes them.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from ..errors import ParameterError
from .frames import Normalization, normalization_from_box
from .rotations import orthonormalize, rotation_z

#: Largest absolute value of a box centre coordinate, metres. Georeferenced frames put boxes far from the origin
#: (UTM northings reach ~1e7 m, ECEF coordinates ~6.4e6 m); 1e8 m leaves ten times that, while anything beyond it
#: is a corrupt file, whose squared distances would overflow float64 (beyond ~1e154 m) in crops and KD-trees.
MAX_BOX_CENTER_M = 1e8

#: Largest box side, metres. A LiDAR sees ~300 m at most, and the largest annotated boxes (KITTI-360's buildings and
#: walls) are a few hundred metres long; 1e4 m leaves a wide margin and keeps radii, norms and unit frames finite.
MAX_BOX_SIZE_M = 1e4

#: How far a box rotation may be from orthonormal (largest entry of ``R.T @ R - I``): the tolerance of
#: :func:`~spotlights.geometry.rotations.is_rotation`; rotations rounded to float32 (~1e-7) pass easily.
ROTATION_TOLERANCE = 1e-3


#: Most boxes one frame may hold (a box file, a frame given to scene completion): the busiest frames of the datasets
#: read hold a few hundred annotations; 2,000 leaves a wide margin, while 100,000 boxes took minutes and 7 GB before
#: a MemoryError. Checked before any box is cropped or completed.
MAX_BOXES_PER_FRAME = 2_000

#: 180 degrees about the box's own z axis: the same box, heading turned around.
FLIP_Z = np.diag([-1.0, -1.0, 1.0])

#: (8, 3) float64 signs of the corners in the box's axes: row ``4*i + 2*j + k`` = (±1, ±1, ±1), + for 0, - for 1.
CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)], dtype=np.float64)
CORNER_SIGNS.setflags(write=False)

#: The 12 edges of a box as pairs of corner indices (corners that differ in one sign).
BOX_EDGES = ((0, 1), (2, 3), (4, 5), (6, 7), (0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7))


def corners(center: ArrayLike, size: ArrayLike, rotation: ArrayLike | None = None) -> np.ndarray:
    """(..., 8, 3) float64 corners of boxes (vectorised over any leading shape), in the scan's frame.

    Parameters
    ----------
    center : (..., 3) box centres, metres. size : (..., 3) (length, width, height), metres.
    rotation : (..., 3, 3) rotations whose columns are the box axes (None: axis-aligned).

    Corner order: :data:`CORNER_SIGNS` (corner 0 at (+l/2, +w/2, +h/2) in the box's axes, corner 7 at (-, -, -)).
    """
    c = np.asarray(center, dtype=np.float64)
    half = 0.5 * np.asarray(size, dtype=np.float64)
    local = CORNER_SIGNS * half[..., None, :]  # (..., 8, 3) object frame
    if rotation is None:
        return c[..., None, :] + local
    r = np.asarray(rotation, dtype=np.float64)
    return c[..., None, :] + local @ np.swapaxes(r, -1, -2)


def unit_extents(size: ArrayLike, radius: ArrayLike | None = None) -> np.ndarray:
    """(..., 3) float64 half-extents of boxes in their unit frames: ``size / (2 R)``, R = half the box diagonal.

    Parameters
    ----------
    size : (..., 3) box length, width, height (any unit; only ratios matter).
    radius : optional (...,) R of each box when it is known (a normalisation's or a dataset's stored radius);
        by default ``2 R = |size|``, so the result is ``size / |size|`` (norm 1).

    What a box-targeted rig is aimed at (:meth:`spotlights.geometry.rig.RigSpec.for_box`). Raises
    :class:`ParameterError` for a shape other than (..., 3), or (without ``radius``) sizes that are not
    finite, negative or all zero.
    """
    s = np.asarray(size, dtype=np.float64)
    if s.shape[-1:] != (3,):
        raise ParameterError(f"box sizes must have shape (..., 3), got {s.shape}")
    if radius is not None:
        return s / (2.0 * np.asarray(radius, dtype=np.float64)[..., None])
    n = np.linalg.norm(s, axis=-1, keepdims=True)
    if not np.all(np.isfinite(s)) or np.any(s < 0) or np.any(n <= 0):
        raise ParameterError("box sizes must be finite, >= 0 and not all zero")
    return s / n


class Box:
    """An oriented 3-D box, optionally with the label, class and track id of its object.

    Parameters
    ----------
    center : (3,) metres, the box centre in the scan's frame.
    size : (3,) metres, (length, width, height) along the box's x, y, z.
    rotation : (3, 3) proper rotation, columns = box forward, left, up axes in the scan's
        frame; or a number, read as the heading ``yaw`` (radians about the scan's +z).
        Default: the identity (axis-aligned box) unless ``yaw`` is given.
    label : the source's own label (e.g. ``"Van"``, ``"vehicle.car"``); ``""`` when unknown.
    cls : one of the vehicle classes of :mod:`spotlights.data.real` (``"car"``, ...) or None.
    track_id : identity of the object across frames (``""`` when there is none).
    score : a detector's or tracker's confidence, a finite number in [0, 1], or None (annotations).
    yaw : keyword alternative to a numeric ``rotation``.

    Attributes are read-only float64 arrays (``center``, ``size``, ``rotation``) and
    strings. Sizes are not checked for sign here (annotations may hold degenerate boxes of
    zero or negative sides; see :meth:`is_valid`), but shapes and numbers are: :class:`ParameterError`
    (one line) for input that is not numeric (booleans included), a NaN or infinite centre,
    size or rotation entry, a centre coordinate beyond
    :data:`MAX_BOX_CENTER_M`, a finite side beyond :data:`MAX_BOX_SIZE_M`, or a finite
    rotation that is not a proper rotation (``R.T @ R`` within :data:`ROTATION_TOLERANCE`
    of the identity, det > 0; readers orthonormalise calibration chains first). The
    checks are cheap: a box is made for every annotation of every frame.
    """

    __slots__ = ("center", "size", "rotation", "label", "cls", "track_id", "score", "_normalization")
    FIELDS = ("center", "size", "rotation", "label", "cls", "track_id", "score")
    center: np.ndarray
    size: np.ndarray
    rotation: np.ndarray
    label: str
    cls: str | None
    track_id: str
    score: float | None
    _normalization: Normalization | None

    def __init__(
        self,
        center: ArrayLike,
        size: ArrayLike,
        rotation: ArrayLike | float | None = None,
        label: str = "",
        cls: str | None = None,
        track_id: str | None = "",
        score: float | None = None,
        *,
        yaw: float | None = None,
    ) -> None:
        c = _numbers(center, "centre")
        s = _numbers(size, "size")
        if c.shape != (3,) or s.shape != (3,):
            raise ParameterError(f"a box needs a 3-vector centre and size, got shapes {c.shape} and {s.shape}")
        for what, v in (("center", c), ("size", s)):
            if not math.isfinite(float(v[0] + v[1] + v[2])) and not np.all(np.isfinite(v)):
                raise ParameterError(f"a box {what} must be finite numbers, got {_short(v.tolist())}")
        problem = _range_problem(c.tolist(), s.tolist())
        if problem:
            raise ParameterError(f"box {problem}")
        if rotation is not None and np.ndim(rotation) == 0:
            if yaw is not None:
                raise ParameterError("give a box either a rotation or a yaw, not both")
            rotation, yaw = None, _scalar(rotation, "yaw")
        if rotation is None:
            r = rotation_z(0.0 if yaw is None else _scalar(yaw, "yaw"))
        else:
            if yaw is not None:
                raise ParameterError("give a box either a rotation or a yaw, not both")
            r = _numbers(rotation, "rotation")
            if r.shape != (3, 3):
                raise ParameterError(f"a box rotation must be (3, 3), got shape {r.shape}")
            if not np.all(np.isfinite(r)):
                raise ParameterError("a box rotation must be finite numbers, got NaN or infinite entries")
            problem = _rotation_problem(r)
            if problem:
                raise ParameterError(f"box rotation {problem}")
        for name, v in (("center", c), ("size", s), ("rotation", r)):
            v.setflags(write=False)
            object.__setattr__(self, name, v)
        object.__setattr__(self, "label", str(label))
        object.__setattr__(self, "cls", None if cls is None else str(cls))
        object.__setattr__(self, "track_id", "" if track_id is None else str(track_id))
        object.__setattr__(self, "score", None if score is None else _score(score))
        object.__setattr__(self, "_normalization", None)  # made once by normalization() (the box is immutable)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError("Box is immutable; use Box.replace(...)")

    def __repr__(self) -> str:
        extra = "".join(f", {k}={getattr(self, k)!r}" for k in ("label", "cls", "track_id") if getattr(self, k))
        extra += "" if self.score is None else f", score={self.score:.4f}"
        return (
            f"Box(center={np.round(self.center, 3).tolist()}, size={np.round(self.size, 3).tolist()}, "
            f"yaw={self.yaw:.4f}{extra})"
        )

    def __reduce__(self) -> tuple:  # picklable (process pools, Ray)
        return (Box, (self.center, self.size, self.rotation, self.label, self.cls, self.track_id, self.score))

    # --- construction -----------------------------------------------------------------

    @classmethod
    def from_yaw(
        cls_,
        center: ArrayLike,
        size: ArrayLike,
        yaw: float,
        label: str = "",
        cls: str | None = None,
        track_id: str = "",
    ) -> Box:
        """A box turned by ``yaw`` radians about the scan's +z axis (:class:`ParameterError` for a NaN or infinite
        yaw, as the constructor's)."""
        return cls_(center, size, label=label, cls=cls, track_id=track_id, yaw=yaw)

    def replace(self, **changes: object) -> Box:
        """A copy with some of ``center``, ``size``, ``rotation``, ``label``, ``cls``, ``track_id``, ``score`` changed."""
        d = {k: getattr(self, k) for k in self.FIELDS}
        unknown = set(changes) - set(d)
        if unknown:
            raise ParameterError(f"unknown box field(s) {sorted(unknown)}")
        d.update(changes)
        return Box(**d)  # type: ignore[arg-type]

    # --- properties -----------------------------------------------------------------

    @property
    def yaw(self) -> float:
        """Heading of the box's x axis about the scan's z axis, radians in (-pi, pi]."""
        return math.atan2(self.rotation[1, 0], self.rotation[0, 0])

    @property
    def radius(self) -> float:
        """Half the box diagonal, metres: the radius R of the circumscribed sphere (the unit frame's scale)."""
        return 0.5 * float(np.linalg.norm(self.size))

    @property
    def unit_extents(self) -> np.ndarray:
        """(3,) float64 half-extents of the box in its unit frame, ``size / (2 R)`` (norm 1; :func:`unit_extents`)."""
        return unit_extents(self.size, self.radius)

    def is_valid(self) -> bool:
        """True when centre, size and rotation are finite, the rotation proper and every size positive."""
        return bool(
            np.all(np.isfinite(self.center))
            and np.all(np.isfinite(self.size))
            and np.all(np.isfinite(self.rotation))
            and np.all(self.size > 0)
        )

    # --- geometry -------------------------------------------------------------------

    def corners(self) -> np.ndarray:
        """(8, 3) float64 corners in the scan's frame.

        Order (:data:`CORNER_SIGNS`): index ``4*i + 2*j + k`` has object coordinates
        ``(±l/2, ±w/2, ±h/2)`` with i, j, k = 0 for + and 1 for - along x, y, z.
        """
        return corners(self.center, self.size, self.rotation)

    def to_object(self, points: ArrayLike) -> np.ndarray:
        """Scan-frame points (..., 3) -> object frame (..., 3) float64, metres (:class:`ParameterError` for anything
        that is not an array of numbers whose last axis has 3 entries)."""
        return (_points(points) - self.center) @ self.rotation

    def from_object(self, points: ArrayLike) -> np.ndarray:
        """Object-frame points (..., 3) -> scan frame (..., 3) float64, metres."""
        return np.asarray(points, dtype=np.float64) @ self.rotation.T + self.center

    def to_unit(self, points: ArrayLike) -> np.ndarray:
        """Scan-frame points (..., 3) -> the box's unit frame (object frame / :attr:`radius`), float64."""
        return self.normalization().to_unit(np.asarray(points, dtype=np.float64))

    def from_unit(self, points: ArrayLike) -> np.ndarray:
        """Unit-frame points (..., 3) -> the scan's frame, float64 metres."""
        return self.normalization().from_unit(np.asarray(points, dtype=np.float64))

    def contains(self, points: ArrayLike, margin: float = 0.0, ground_clearance: float | None = None) -> np.ndarray:
        """Boolean mask (N,) of the scan-frame points (N, 3) inside the box grown by ``margin`` metres.

        ``ground_clearance`` (metres): when given, the bottom face is not grown but raised by it
        (points with object z < -h/2 + ground_clearance are out): this drops the ground returns
        under a vehicle. Faces are inclusive. :class:`ParameterError` (naming ``points``) for anything but an (N, 3)
        array of numbers.
        """
        p = self.to_object(_points(points, flat=True))
        half = 0.5 * self.size
        inside = (
            (np.abs(p[:, 0]) <= half[0] + margin)
            & (np.abs(p[:, 1]) <= half[1] + margin)
            & (p[:, 2] <= half[2] + margin)
        )
        bottom = -half[2] - margin if ground_clearance is None else -half[2] + ground_clearance
        return inside & (p[:, 2] >= bottom)

    def crop(self, points: ArrayLike, margin: float = 0.0, ground_clearance: float | None = None) -> np.ndarray:
        """Indices (k,) int64 of the scan-frame points (N, 3) float64 inside the box as :meth:`contains` cuts it,
        with a cheap distance pre-cut first (scans hold ~100k points): the sphere around the box grown by
        ``margin + |ground_clearance|`` along each of its axes holds every point :meth:`contains` keeps."""
        grow = max(float(margin), 0.0) + abs(float(ground_clearance or 0.0))
        reach = float(np.linalg.norm(0.5 * self.size + grow))
        p = _points(points, flat=True)
        near = np.flatnonzero(np.sum((p - self.center) ** 2, axis=1) <= reach * reach)
        return near[self.contains(p[near], margin, ground_clearance)]

    def normalization(self) -> Normalization:
        """The :class:`~spotlights.geometry.frames.Normalization` scan frame -> unit frame (R = half diagonal); made
        once per box (both are immutable)."""
        made = self._normalization
        if made is None:
            made = normalization_from_box(self.center, self.size, rotation=self.rotation)
            object.__setattr__(self, "_normalization", made)
        return made

    def flipped(self) -> Box:
        """The same box with its heading turned by 180 degrees (forward and left axes negated)."""
        return self.replace(rotation=self.rotation @ FLIP_Z)

    def transformed(self, t: np.ndarray) -> Box:
        """This box moved by the rigid (4, 4) transform ``t`` (new frame <- this box's frame)."""
        t = np.asarray(t, dtype=np.float64)
        rot = t[:3, :3] @ self.rotation
        if np.all(np.isfinite(rot)):  # an invalid (NaN) box stays invalid: there is no rotation to make exact
            rot = orthonormalize(rot)
        return self.replace(center=t[:3, :3] @ self.center + t[:3, 3], rotation=rot)

    def to_dict(self) -> dict:
        """JSON-ready description: centre, size, rotation (rows), yaw, label, class, track id (and score when set)."""
        d = {
            "center": [float(v) for v in self.center],
            "size": [float(v) for v in self.size],
            "rotation": [[float(v) for v in row] for row in self.rotation],
            "yaw": float(self.yaw),
            "label": self.label,
            "cls": self.cls,
            "track_id": self.track_id,
        }
        if self.score is not None:
            d["score"] = self.score
        return d


def _score(value: object) -> float:
    """A box score as a float in [0, 1], or :class:`ParameterError` (one line)."""
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ParameterError(f"a box score must be a number in [0, 1], got {value!r:.60}") from None
    if not 0.0 <= x <= 1.0:  # NaN fails too
        raise ParameterError(f"a box score must be a finite number in [0, 1], got {x}")
    return x


def _numbers(value: object, what: str) -> np.ndarray:
    """``value`` as a float64 array, or :class:`ParameterError` (one line) when it is not numeric (booleans and
    strings are not numbers here, though numpy would read ``True`` as 1 and ``"1.5"`` as 1.5)."""
    if isinstance(value, (bool, str, bytes)) or (isinstance(value, np.ndarray) and value.dtype.kind not in "iuf"):
        raise ParameterError(f"a box {what} must be numbers, got {value!r:.60}")
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"a box {what} must be numbers, got {value!r:.60}") from None
    if isinstance(value, (list, tuple)) and holds_non_numbers(value):
        raise ParameterError(f"a box {what} must be numbers, got {value!r:.60}")
    return a


def holds_non_numbers(items: list | tuple) -> bool:
    """Whether a (nested) list or tuple holds a boolean or a string, which numpy converts to floats silently (``True``
    to 1.0, ``"1.5"`` to 1.5): box files and box arguments refuse both."""
    for v in items:
        if isinstance(v, (list, tuple)):
            if holds_non_numbers(v):
                return True
        elif isinstance(v, (bool, np.bool_, str, bytes)):
            return True
    return False


def _points(points: object, flat: bool = False) -> np.ndarray:
    """``points`` as a float64 array of shape (..., 3) (``flat``: exactly (N, 3)), or :class:`ParameterError` naming
    ``points`` (None, a (5, 2) array or strings gave numpy's own errors, or wrong answers)."""
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        p = None
    if p is None or p.ndim == 0 or p.shape[-1] != 3 or (flat and p.ndim != 2):
        got = "None" if points is None else f"shape {p.shape}" if p is not None else type(points).__name__
        raise ParameterError(f"points must be an {'(N, 3)' if flat else '(..., 3)'} array of numbers, got {got}")
    return p


def _scalar(value: object, what: str) -> float:
    """``value`` as a finite float, or :class:`ParameterError` (one line) when it is not one finite number (a NaN or
    infinite yaw raised "math domain error"; a boolean or a string is not a number here)."""
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise ParameterError(f"a box {what} must be a number, got {value!r:.60}")
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ParameterError(f"a box {what} must be a number, got {value!r:.60}") from None
    if not math.isfinite(x):
        raise ParameterError(f"a box {what} must be a finite number (radians), got {x}")
    return x


def box_range_problem(center: ArrayLike, size: ArrayLike) -> str | None:
    """Why a box's centre (3,) and size (3,), metres, are out of range, or None: a finite centre coordinate
    beyond :data:`MAX_BOX_CENTER_M` in absolute value, or a finite side beyond :data:`MAX_BOX_SIZE_M`.

    The one owner of these bounds (:class:`Box` checks every box with it; file readers name the file). Non-finite
    values are not judged here: they make an invalid box (:meth:`Box.is_valid`), which readers refuse themselves.
    Returns a phrase such as ``"centre [1e+300, 0, 0] is out of range (each coordinate within ±1e+08 m)"``.
    """
    return _range_problem(
        np.asarray(center, dtype=np.float64).reshape(-1).tolist(),
        np.asarray(size, dtype=np.float64).reshape(-1).tolist(),
    )


def _range_problem(c: list[float], s: list[float]) -> str | None:
    """:func:`box_range_problem` of a centre and a size as lists of floats."""
    if max(map(abs, c), default=0.0) <= MAX_BOX_CENTER_M and max(s, default=0.0) <= MAX_BOX_SIZE_M:
        return None  # the common case, cheaply (a NaN never passes a larger value in max: it takes the long way)
    if any(math.isfinite(v) and abs(v) > MAX_BOX_CENTER_M for v in c):
        return f"centre {_short(c)} is out of range (each coordinate within ±{MAX_BOX_CENTER_M:.0e} m)"
    if any(math.isfinite(v) and v > MAX_BOX_SIZE_M for v in s):
        return f"size {_short(s)} is out of range (each side at most {MAX_BOX_SIZE_M:.0e} m)"
    return None


def _short(values: list[float]) -> str:
    return "[" + ", ".join(f"{v:.6g}" for v in values) + "]"


def _rotation_problem(r: np.ndarray) -> str | None:
    """Why a finite (3, 3) matrix is not a proper rotation (see :data:`ROTATION_TOLERANCE`), or None; a matrix with
    non-finite entries is not judged (an invalid box). Pure Python on 9 floats: ~2 us, a box is made per annotation."""
    (a, b, c), (d, e, f), (g, h, i) = r.tolist()
    if not math.isfinite(a + b + c + d + e + f + g + h + i):  # NaN, or an infinity (inf - inf is NaN too)
        if all(math.isfinite(v) for v in (a, b, c, d, e, f, g, h, i)):  # finite, only their sum overflowed
            return "holds numbers far beyond a rotation's (entries are within [-1, 1])"
        return None
    tol = ROTATION_TOLERANCE
    if not (
        abs(a * a + d * d + g * g - 1.0) <= tol  # columns of unit length
        and abs(b * b + e * e + h * h - 1.0) <= tol
        and abs(c * c + f * f + i * i - 1.0) <= tol
        and abs(a * b + d * e + g * h) <= tol  # and at right angles
        and abs(a * c + d * f + g * i) <= tol
        and abs(b * c + e * f + h * i) <= tol
    ):
        return f"is not orthonormal (its columns must be unit axes at right angles, within {tol:g})"
    if a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) <= 0:
        return "is a reflection (determinant < 0): columns must be forward, left, up of a right-handed frame"
    return None


# --- boxes in JSON ---------------------------------------------------------------------


SMALL_CROP = 1_000_000
"""Points x boxes up to which :func:`crop_boxes` pre-cuts each box's sphere with one numpy pass per box instead of
a KD-tree (a KITTI frame: 19k points, 15 boxes)."""


def crop_boxes(
    points: ArrayLike, boxes: list[Box], margin: float = 0.0, ground_clearance: float | None = None
) -> list[np.ndarray]:
    """Per box, the indices (k,) int64 that :meth:`Box.crop` gives for the scan points (N, 3), metres, with one
    KD-tree over the scan for all boxes (its pre-cut sphere; a scan of 35k points and 60 boxes: one tree
    instead of 60 passes over every point). Same indices, same order (increasing) as :meth:`Box.crop`."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not boxes or len(p) == 0:
        return [np.zeros(0, np.int64) for _ in boxes]
    grow = max(float(margin), 0.0) + abs(float(ground_clearance or 0.0))
    reach = np.array([float(np.linalg.norm(0.5 * b.size + grow)) for b in boxes])
    if len(p) * len(boxes) <= SMALL_CROP:  # a pass over the points per box: no scipy.spatial import (0.25 s)
        r2 = (reach * (1 + 1e-9)) ** 2
        near_all = [np.flatnonzero(((p - b.center) ** 2).sum(axis=1) <= r) for b, r in zip(boxes, r2)]
        return [near[b.contains(p[near], margin, ground_clearance)] for b, near in zip(boxes, near_all)]
    from scipy.spatial import cKDTree

    # one query per box: a tree built without balancing is ~2x cheaper to build and finds the same points
    tree = cKDTree(p, balanced_tree=False, compact_nodes=False)
    hits = tree.query_ball_point(np.array([b.center for b in boxes]), reach * (1 + 1e-9))
    out = []
    for b, h in zip(boxes, hits):
        near = np.sort(np.asarray(h, dtype=np.int64))
        out.append(near[b.contains(p[near], margin, ground_clearance)])
    return out
