"""Rotations: about +z (yaw), from quaternions, and the nearest proper rotation.

One owner for each: every module that turns a heading, a quaternion or an
almost-rotation into a (3, 3) matrix calls these.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ParameterError


def rotation_z(yaw: float) -> np.ndarray:
    """(3, 3) float64 rotation by ``yaw`` radians about +z (counter-clockwise seen from above).

    Its columns are the rotated x, y, z axes: a box with heading ``yaw`` has its
    forward (x) axis at angle ``yaw`` from the frame's x axis.
    """
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def orthonormalize(m: np.ndarray) -> np.ndarray:
    """Nearest proper rotation (3, 3) float64 to ``m`` (polar decomposition via SVD).

    Calibration chains (e.g. KITTI's ``R0_rect`` times ``Tr_velo_to_cam``) are
    rotations only up to rounding; boxes need an exact one. A matrix with a NaN or
    infinite entry has no nearest rotation: :class:`ParameterError` (readers refuse
    such numbers first, naming their file; this keeps LAPACK's "SVD did not converge" out).
    """
    m = np.asarray(m, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        raise ParameterError("cannot make a rotation of a matrix with NaN or infinite entries")
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    if np.linalg.det(r) < 0:  # improper: flip the weakest axis
        u[:, -1] = -u[:, -1]
        r = u @ vt
    return r


def quaternion_to_matrix(qw, qx, qy, qz) -> np.ndarray:
    """Rotation matrices from scalar-first unit quaternions (w, x, y, z), as Argoverse 2 and nuScenes store them.

    Inputs are scalars or arrays of shape (n,); returns (3, 3) or (n, 3, 3)
    float64. The quaternions are normalised first; one that cannot be (a NaN or infinite
    component, a zero norm, or a norm that overflows float64, such as [1e300, 1e300, 0, 0],
    which became the identity) raises :class:`ParameterError`.
    """
    q = np.stack(np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (qw, qx, qy, qz))), axis=-1)
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.linalg.norm(q, axis=-1, keepdims=True)
    bad = ~(np.isfinite(norm) & (norm > 0))
    if np.any(bad):
        first = q[np.unravel_index(int(np.argmax(bad)), bad.shape)[:-1]] if q.ndim > 1 else q
        raise ParameterError(
            f"quaternion (w, x, y, z) {np.asarray(first).tolist()} cannot be normalised (NaN, infinite, zero or "
            "overflowing norm)"
        )
    q = q / norm
    w, x, y, z = np.moveaxis(q, -1, 0)
    m = np.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return m.reshape(q.shape[:-1] + (3, 3))


def rigid_transform(rotation, translation) -> np.ndarray:
    """(4, 4) float64 homogeneous transform from a (3, 3) rotation and a (3,) translation."""
    t = np.eye(4)
    t[:3, :3] = np.asarray(rotation, dtype=np.float64)
    t[:3, 3] = np.asarray(translation, dtype=np.float64).reshape(3)
    return t


def is_rotation(m, atol: float = 1e-3) -> bool:
    """True when ``m`` (3, 3) is finite, orthonormal within ``atol`` and proper (det > 0)."""
    m = np.asarray(m, dtype=np.float64)
    return bool(
        m.shape == (3, 3)
        and np.all(np.isfinite(m))
        and np.allclose(m.T @ m, np.eye(3), atol=atol)
        and np.linalg.det(m) > 0
    )
