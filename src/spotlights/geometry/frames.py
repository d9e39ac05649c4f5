"""Normalisation into the unit sphere (paper Section 3.2, step 1).

A :class:`Normalization` is the similarity transform from a *source* frame
(a mesh's own frame, a LiDAR sensor frame, ...) into the *unit frame*: the
object's box frame (x forward/length, y left, z up, origin at the box centre)
scaled by ``1 / R``, where ``R`` is the radius of the box's circumscribed sphere
(half its diagonal). The object then lies inside the unit sphere.

    unit = ((source - center) @ rotation) / radius
    source = (unit * radius) @ rotation.T + center

``rotation`` is a proper rotation (3, 3) whose *columns* are the box axes
expressed in the source frame (identity for an axis-aligned box).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from .rotations import rotation_z

#: Largest absolute coordinate of the points or mesh vertices a normalisation is made from, in their own unit
#: (metres, millimetres, ...): a vehicle in millimetres spans ~1e4, georeferenced scans reach ~1e7 m (UTM), and
#: 1e12 still leaves a margin for both together; beyond it a file is corrupt, and sizes, squares and norms of
#: such numbers overflow float64 (near 1e154) with RuntimeWarnings instead of an error.
MAX_COORDINATE = 1e12


@dataclass(frozen=True, eq=False)
class Normalization:
    """Similarity transform source frame -> unit frame (see module docstring).

    Attributes
    ----------
    center : (3,) float64, box centre in the source frame (metres or source units).
    radius : float, circumscribed-sphere radius R = half the box diagonal (> 0).
    rotation : (3, 3) float64, columns = box axes in the source frame.
    size : (3,) float64 or None, box extents along its own axes (informative).
    """

    center: np.ndarray
    radius: float
    rotation: np.ndarray
    size: np.ndarray | None = None

    def __post_init__(self):
        c = np.asarray(self.center, dtype=np.float64).reshape(3)
        r = np.asarray(self.rotation, dtype=np.float64).reshape(3, 3)
        rad = float(self.radius)
        if not np.all(np.isfinite(c)) or not np.all(np.isfinite(r)):
            raise ParameterError("normalisation centre and rotation must be finite")
        if not (math.isfinite(rad) and rad > 0.0):
            raise ParameterError(f"normalisation radius must be finite and > 0, got {self.radius!r} (zero-size box?)")
        if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise ParameterError("normalisation rotation must be a proper rotation matrix")
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "rotation", r)
        object.__setattr__(self, "radius", rad)
        if self.size is not None:
            object.__setattr__(self, "size", np.asarray(self.size, dtype=np.float64).reshape(3))

    def to_unit(self, points: np.ndarray) -> np.ndarray:
        """Map (..., 3) source-frame points into the unit frame (float64)."""
        return ((np.asarray(points, dtype=np.float64) - self.center) @ self.rotation) / self.radius

    def from_unit(self, points: np.ndarray) -> np.ndarray:
        """Map (..., 3) unit-frame points back into the source frame (float64)."""
        return (np.asarray(points, dtype=np.float64) * self.radius) @ self.rotation.T + self.center

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) float64 homogeneous matrix source -> unit (acts on column vectors)."""
        m = np.eye(4)
        m[:3, :3] = self.rotation.T / self.radius
        m[:3, 3] = -(self.rotation.T @ self.center) / self.radius
        return m

    @property
    def inverse_matrix(self) -> np.ndarray:
        """(4, 4) float64 homogeneous matrix unit -> source."""
        m = np.eye(4)
        m[:3, :3] = self.rotation * self.radius
        m[:3, 3] = self.center
        return m

    def to_dict(self) -> dict:
        """JSON-serialisable description (lists of floats)."""
        d = {"center": self.center.tolist(), "radius": self.radius, "rotation": self.rotation.tolist()}
        if self.size is not None:
            d["size"] = self.size.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Normalization:
        """Rebuild from :meth:`to_dict` output."""
        return cls(center=d["center"], radius=d["radius"], rotation=d["rotation"], size=d.get("size"))


def normalization_from_points(points: np.ndarray) -> Normalization:
    """Axis-aligned box of (K, 3) points, its circumscribed sphere, and the transform into it.

    Raises :class:`ParameterError` for empty, non-finite, out-of-range (beyond :data:`MAX_COORDINATE`)
    or zero-size input.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ParameterError(f"expected a non-empty (K, 3) point array, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ParameterError("points contain NaN or infinite coordinates")
    if np.abs(p).max() > MAX_COORDINATE:
        raise ParameterError(f"points lie out of range: coordinates must be within ±{MAX_COORDINATE:.0e}")
    lo, hi = p.min(axis=0), p.max(axis=0)
    size = hi - lo
    radius = 0.5 * float(np.linalg.norm(size))
    if radius <= 0.0:
        raise ParameterError("zero-size bounding box: all points coincide")
    return Normalization(center=(lo + hi) / 2.0, radius=radius, rotation=np.eye(3), size=size)


def normalization_from_mesh(mesh) -> Normalization:
    """Normalisation of a mesh (anything with a ``vertices`` (V, 3) array) by its axis-aligned box."""
    return normalization_from_points(np.asarray(mesh.vertices))


def normalization_from_box(center, size, yaw: float = 0.0, rotation=None) -> Normalization:
    """Normalisation from an oriented box as a 3-D detector gives it.

    Parameters
    ----------
    center : (3,) box centre in the source frame (the *geometric* centre, not the bottom).
    size : (3,) (length, width, height) along the box's own x (forward), y (left), z (up).
    yaw : heading in radians about the source z axis (ignored when ``rotation`` is given).
    rotation : optional (3, 3) rotation whose columns are the box axes in the source frame.

    Returns
    -------
    Normalization with R = half the box diagonal.
    """
    size = np.asarray(size, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(size)) or np.any(size < 0) or not np.any(size > 0):
        raise ParameterError(f"box size must be finite, non-negative and not all zero, got {size.tolist()}")
    rot = rotation_z(float(yaw)) if rotation is None else np.asarray(rotation, dtype=np.float64)
    with np.errstate(over="ignore"):  # a huge size gives an infinite radius: Normalization's one-line error
        radius = 0.5 * float(np.linalg.norm(size))
    return Normalization(center=center, radius=radius, rotation=rot, size=size)


def clamp_to_unit_sphere(points: np.ndarray) -> np.ndarray:
    """(K, 3) unit-frame points with every point farther than 1 from the origin moved radially onto
    the unit sphere (the box's circumscribed sphere); float32. SA-Net's depths in [0, 1] keep its
    points inside already; point-set models (PCN, FoldingNet, TopNet, AtlasNet) are not bounded."""
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    # a float32 squared norm below 0.999 is below 1 in any precision (relative rounding ~1e-7): only the points
    # beyond it are measured in float64, as all of them were (the same points move, by the same amounts)
    near = np.flatnonzero(np.einsum("ij,ij->i", p, p) >= np.float32(0.999))
    if len(near) == 0:
        return p
    r = np.zeros(len(p))
    r[near] = np.linalg.norm(p[near].astype(np.float64), axis=1)
    out = r > 1.0
    if not out.any():
        return p
    p = p.copy()
    p[out] = (p[out] / r[out, None]).astype(np.float32)
    # float32 rounding can leave |p| a hair above 1: shrink those by one ulp until inside
    while True:
        over = np.linalg.norm(p.astype(np.float64), axis=1) > 1.0
        if not over.any():
            return p
        p[over] = np.nextafter(p[over], np.float32(0))
