"""Boxes read from JSON (the generic box format of ``complete``, ``real`` and the viewer): the one parser,
:func:`box_from_dict`, and :func:`load_box` for a one-box file."""

from __future__ import annotations

import math
import os

import numpy as np
from numpy.typing import ArrayLike

from ..errors import InputFileError, ParameterError
from ..inputs import read_json
from .boxes import Box, box_range_problem, holds_non_numbers
from .rotations import is_rotation, orthonormalize, quaternion_to_matrix, rotation_z

#: How far a box file's quaternion may be from unit length: files store unit quaternions rounded (float32: ~1e-7),
#: while a norm far from 1 (or one that overflows) is a corrupt number, not a rotation to normalise silently.
QUATERNION_TOLERANCE = 1e-3

SIZE_KEYS = ("size", "dimensions", "extent")


LABEL_KEYS = ("label", "category", "class", "detection_name")


ID_KEYS = ("track_id", "id", "instance_token", "tracking_id")


SCORE_KEYS = ("score", "detection_score", "tracking_score")


def _vector(value: object, n: int | tuple[int, ...], src: str | os.PathLike, what: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if isinstance(value, (str, bytes, bool)) or (isinstance(value, (list, tuple)) and holds_non_numbers(value)):
        a = None  # a boolean or a string is not a number in a box file (numpy reads true as 1, "1.5" as 1.5)
    shape = (n,) if isinstance(n, int) else tuple(n)
    if a is None or a.shape != shape or not np.all(np.isfinite(a)):
        desc = "three" if shape == (3,) else "x".join(map(str, shape))
        got = f"shape {a.shape}" if a is not None and a.shape != shape else repr(value)[:60]
        raise InputFileError(src, f"{what} must be {desc} finite numbers, got {got}")
    return a


def _quaternion_rotation(rot_value: object, src: str | os.PathLike, what: str) -> np.ndarray:
    """The (3, 3) rotation of a scalar-first unit quaternion given in a box file (checked)."""
    q = _vector(rot_value, 4, src, f"{what} quaternion")
    with np.errstate(over="ignore"):
        norm = float(np.linalg.norm(q))
    if norm < 1e-6:
        raise InputFileError(src, f"{what} quaternion is zero")
    if not abs(norm - 1.0) <= QUATERNION_TOLERANCE:  # an overflowing norm is inf: refused too
        raise InputFileError(
            src,
            f"{what} quaternion must be a unit quaternion (norm 1 within {QUATERNION_TOLERANCE:g}), "
            f"got norm {norm:.6g}",
        )
    return quaternion_to_matrix(*q)


def _matrix_rotation(rot_value: object, src: str | os.PathLike, what: str) -> np.ndarray:
    """The (3, 3) rotation matrix given in a box file (checked, then re-orthonormalised)."""
    rot = _vector(rot_value, (3, 3), src, f"{what} rotation")
    if not is_rotation(rot):
        raise InputFileError(src, f"{what} rotation is not a proper rotation matrix (orthonormal, det +1)")
    return orthonormalize(rot)


def _yaw_rotation(d: dict, src: str | os.PathLike, what: str, a: np.ndarray) -> np.ndarray:
    """The (3, 3) rotation of a box's ``yaw`` (radians) or ``yaw_deg`` about the scan's up axis
    (``a``: the scan-to-object axes rotation)."""
    key = "yaw" if "yaw" in d else "yaw_deg"
    try:
        if isinstance(d[key], (str, bool)):  # "0.5" and true are not numbers in a box file
            raise TypeError(key)
        yaw = float(d[key])
    except (TypeError, ValueError):
        raise InputFileError(src, f"{what} {key} must be a number, got {d[key]!r}") from None
    if not math.isfinite(yaw):
        raise InputFileError(src, f"{what} {key} must be finite")
    return a.T @ rotation_z(math.radians(yaw) if key == "yaw_deg" else yaw)


def _heading(d: dict, src: str | os.PathLike, what: str, a: np.ndarray) -> np.ndarray:
    """The box's (3, 3) rotation from exactly one of its heading keys (rotation, quaternion, yaw, yaw_deg)."""
    rot_value = d.get("rotation", d.get("quaternion"))
    has_yaw = "yaw" in d or "yaw_deg" in d
    if rot_value is not None:
        if has_yaw:
            raise InputFileError(src, f"{what} has both a yaw and a rotation: give one")
        flat = np.asarray(rot_value, dtype=object).reshape(-1) if isinstance(rot_value, list) else None
        if flat is not None and flat.size == 4:
            return _quaternion_rotation(rot_value, src, what)
        return _matrix_rotation(rot_value, src, what)
    if has_yaw:
        return _yaw_rotation(d, src, what, a)
    raise InputFileError(src, f"{what} needs 'yaw' or 'rotation' (a box's heading is never assumed)")


def _label(d: dict, src: str | os.PathLike, what: str, require_label: bool) -> str:
    """The box's label (``""`` when absent and not required)."""
    label_key = next((k for k in LABEL_KEYS if k in d), None)
    if label_key is None and require_label:
        raise InputFileError(src, f"{what} has no 'label' (e.g. \"car\")")
    if label_key is not None and not isinstance(d[label_key], str):
        raise InputFileError(src, f"{what} {label_key} must be a string, got {d[label_key]!r:.60}")
    return "" if label_key is None else d[label_key]


def _track_id(d: dict, src: str | os.PathLike, what: str) -> str:
    """The box's track identity as a string (``""`` when absent or null; a whole float becomes an integer)."""
    id_key = next((k for k in ID_KEYS if k in d), None)
    track = "" if id_key is None else d[id_key]
    if isinstance(track, float) and track.is_integer():
        track = int(track)
    if track is not None and (isinstance(track, bool) or not isinstance(track, (str, int))):
        raise InputFileError(src, f"{what} {id_key} must be a string or a whole number, got {track!r:.60}")
    return "" if track is None else str(track)


def _score(d: dict, src: str | os.PathLike, what: str) -> float | None:
    """The box's optional confidence in [0, 1] (``None`` when absent)."""
    score = next((d[k] for k in SCORE_KEYS if k in d), None)
    if score is not None and (isinstance(score, bool) or not isinstance(score, (int, float)) or not 0 <= score <= 1):
        raise InputFileError(src, f"{what} score must be a number in [0, 1], got {score!r:.40}")
    return score


def box_from_dict(
    d: object,
    src: str | os.PathLike = "box",
    what: str = "box",
    require_label: bool = False,
    axes: ArrayLike | None = None,
) -> Box:
    """A :class:`Box` from a JSON object (the generic box format of ``complete`` and ``real``).

    Keys
    ----
    center : [x, y, z] metres, the geometric centre, in the scan's frame.
    size : [length, width, height] metres (``dimensions`` or ``extent`` also accepted).
    heading, one of: ``yaw`` (radians about the scan's up axis, 0 = box forward along the
        scan's forward axis), ``yaw_deg`` (degrees), ``rotation`` (3x3 nested list, row-major,
        whose columns are the box's forward, left, up axes; or 4 numbers, a scalar-first
        quaternion w, x, y, z), ``quaternion`` (w, x, y, z).
    label : the object's label (``category``, ``class`` or ``detection_name`` also accepted);
        required when ``require_label``.
    track_id : optional identity across frames (``id``, ``instance_token``, ``tracking_id``
        also accepted), a string or an integer.
    score : optional confidence, a number in [0, 1] (``detection_score``, ``tracking_score`` also accepted).

    ``axes``: optional (3, 3) rotation taking the scan's coordinates to the object convention
    (x forward, y left, z up), as :func:`spotlights.geometry.io.axes_rotation` gives for
    ``--up/--forward``: a ``yaw`` then turns about the scan's up axis. The box returned is in
    the scan's own coordinates. Errors are :class:`InputFileError` naming ``src`` and ``what``, among them
    a centre or size out of range (:func:`box_range_problem`: :data:`MAX_BOX_CENTER_M`, :data:`MAX_BOX_SIZE_M`).
    """
    if not isinstance(d, dict):
        raise InputFileError(src, f"{what} is not a JSON object with center, size and a heading")
    if "center" not in d:
        raise InputFileError(src, f"{what} has no 'center' [x, y, z]")
    size_key = next((k for k in SIZE_KEYS if k in d), None)
    if size_key is None:
        raise InputFileError(src, f"{what} has no 'size' [length, width, height]")
    center = _vector(d["center"], 3, src, f"{what} center")
    size = _vector(d[size_key], 3, src, f"{what} size")
    problem = box_range_problem(center, size)
    if problem:
        raise InputFileError(src, f"{what} {problem}")
    a = np.eye(3) if axes is None else np.asarray(axes, dtype=np.float64)
    rot = _heading(d, src, what, a)
    label = _label(d, src, what, require_label)
    track = _track_id(d, src, what)
    score = _score(d, src, what)
    try:
        return Box(center, size, rot, label, None, track, score)
    except ParameterError as exc:  # the box's own checks (one owner), here naming the file
        raise InputFileError(src, f"{what}: {exc}") from None


def load_box(path: str | os.PathLike) -> Box:
    """Read a one-box JSON file (see :func:`box_from_dict`; the label is optional here)."""
    from pathlib import Path

    p = Path(path)
    if not p.is_file():
        raise InputFileError(p, "no such box file")
    return box_from_dict(read_json(p, "box file"), p)
