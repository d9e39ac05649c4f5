"""Raw LiDAR scan files of every supported kind, read into (N, 3) points.

| kind | files | layout |
|---|---|---|
| ``kitti`` | ``*.bin`` | N x 4 float32 (x, y, z, reflectance), KITTI / KITTI-360 Velodyne |
| ``nuscenes`` | ``*.pcd.bin`` | N x 5 float32 (x, y, z, intensity, ring index), nuScenes LIDAR_TOP |
| ``av2`` | ``*.feather`` | Arrow table with x, y, z columns (float16), Argoverse 2 sweeps |
| ``points`` | ``.ply .pcd .npy .npz .xyz .txt .las .laz`` | :func:`spotlights.geometry.io.load_points` |

The kind follows the file name (``auto``); a file whose bytes do not fit its
name (a nuScenes sweep renamed ``.bin``, a truncated file) is an
:class:`~spotlights.errors.InputFileError` naming the file and the fix.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ...errors import InputFileError, ParameterError
from ...geometry.io import POINT_SUFFIXES, load_points
from ...outputs import check_regular_file
from .av2 import read_av2_sweep
from .base import finite_rows

SCAN_KINDS = ("auto", "kitti", "nuscenes", "av2", "points")
MIN_SCAN_POINTS = 10
"""Fewest points a scan (or an object's crop) must hold to be completed: fewer cannot show a
vehicle's shape (the default of ``real extract --min-points`` and ``complete --min-points``)."""


def scan_kind(path: str | os.PathLike) -> str:
    """The kind of a scan file from its name: ``kitti``, ``nuscenes``, ``av2`` or ``points``."""
    p = Path(path)
    name = p.name.lower()
    if name.endswith(".pcd.bin"):
        return "nuscenes"
    suffix = p.suffix.lower()
    if suffix == ".bin":
        return "kitti"
    if suffix == ".feather":
        return "av2"
    if suffix in POINT_SUFFIXES:
        return "points"
    raise InputFileError(
        p,
        f"unknown scan format {suffix or name!r} (KITTI .bin, nuScenes .pcd.bin, AV2 .feather, "
        f"or {', '.join(POINT_SUFFIXES)})",
    )


def _looks_like_nuscenes(raw: np.ndarray) -> bool:
    """True when float32 values read as N x 5 have a ring-index 5th column (integers 0..255)."""
    if raw.size == 0 or raw.size % 5:
        return False
    ring = raw.reshape(-1, 5)[:, 4]
    return bool(np.all(np.isfinite(ring)) and np.all(ring == np.round(ring)) and ring.min() >= 0 and ring.max() <= 255)


def read_float_bin(path: str | os.PathLike, columns: int, what: str) -> np.ndarray:
    """An N x ``columns`` float32 little-endian file as an array; errors name the file and the layout."""
    p = check_regular_file(path, "scan file")  # missing, a folder, a FIFO (reading one would block): one line
    size = p.stat().st_size
    width = 4 * columns
    if size == 0:
        raise InputFileError(p, "scan file is empty")
    if size % width:
        hint = ""
        if columns == 4 and size % 20 == 0:
            hint = "; its size fits N x 5 float32: a nuScenes sweep? name it *.pcd.bin"
        elif columns == 5 and size % 16 == 0:
            hint = "; its size fits N x 4 float32: a KITTI scan? name it *.bin"
        raise InputFileError(p, f"size {size} bytes is not a multiple of {width} ({what}: N x {columns} float32){hint}")
    return np.fromfile(p, dtype="<f4").reshape(-1, columns)


def read_kitti_bin(path: str | os.PathLike) -> np.ndarray:
    """Read a KITTI Velodyne ``.bin`` scan: (N, 3) float32 x, y, z in metres (sensor frame), rows with NaN or
    infinite coordinates dropped (:func:`~spotlights.data.real.base.finite_rows`).

    Raises :class:`InputFileError` if the file is missing, empty, its size not a multiple
    of 16 bytes (4 float32 per point), or its bytes are those of a nuScenes N x 5 sweep.
    """
    data = read_float_bin(path, 4, "KITTI scan")
    if len(data) >= 8 and os.path.getsize(path) % 20 == 0 and _looks_like_nuscenes(data.reshape(-1)):
        raise InputFileError(
            path,
            "holds N x 5 float32 with a ring-index column: a nuScenes sweep, not a KITTI N x 4 scan; name it *.pcd.bin",
        )
    return finite_rows(np.ascontiguousarray(data[:, :3]))


def read_nuscenes_bin(path: str | os.PathLike) -> np.ndarray:
    """Read a nuScenes ``.pcd.bin`` sweep: (N, 3) float32 x, y, z in metres (LIDAR_TOP sensor frame), rows with
    NaN or infinite coordinates dropped (:func:`~spotlights.data.real.base.finite_rows`).

    The file is N x 5 float32 (x, y, z, intensity, ring index). Raises :class:`InputFileError`
    when the size is not a multiple of 20 bytes or the 5th column is not a ring index.
    """
    data = read_float_bin(path, 5, "nuScenes sweep")
    if not _looks_like_nuscenes(data.reshape(-1)):
        raise InputFileError(path, "5th column is not a ring index (integers 0-255): not a nuScenes N x 5 sweep")
    return finite_rows(np.ascontiguousarray(data[:, :3]))


def read_scan(path: str | os.PathLike, kind: str = "auto") -> np.ndarray:
    """Read any supported scan file (see the module table): (N, 3) points, metres, the file's frame.

    dtype: float32 for the sensor formats (``kitti``, ``nuscenes``, ``av2``, stored in float32
    or less), float64 for point files (LAS/LAZ and text may hold georeferenced coordinates).
    Rows with NaN or infinite coordinates (no-return points of organised scans) are dropped.
    """
    p = Path(path)
    if kind == "auto":
        kind = scan_kind(p)
    if kind not in SCAN_KINDS:
        raise ParameterError(f"unknown scan kind {kind!r}; choose one of {', '.join(SCAN_KINDS)}")
    if not p.exists():
        raise InputFileError(p, "scan file not found")
    if p.is_dir():
        raise InputFileError(p, "is a folder, expected a scan file")
    if kind == "kitti":
        pts = read_kitti_bin(p)
    elif kind == "nuscenes":
        pts = read_nuscenes_bin(p)
    elif kind == "av2":
        pts = read_av2_sweep(p)
    else:
        return load_points(p, drop_nonfinite=True)
    if len(pts) == 0:  # every row dropped as not finite by the format's reader
        raise InputFileError(p, "scan holds no finite point")
    return pts
