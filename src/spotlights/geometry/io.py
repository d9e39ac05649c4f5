"""Reading and writing meshes and point clouds, with validation.

Meshes: OBJ, PLY, OFF, STL, GLB/GLTF (scenes are flattened with their node
transforms), through trimesh. Point clouds: PLY, PCD (pypcd4), NPY, NPZ,
XYZ/TXT. Every problem is raised as :class:`InputFileError` naming the file.
Writers are atomic (temporary name, then rename).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputFileError, ParameterError
from ..utils import atomic_output

MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")
POINT_SUFFIXES = (".ply", ".pcd", ".npy", ".npz", ".xyz", ".txt")
_AXES = {"x": 0, "y": 1, "z": 2}


def axis_vector(spec: str) -> np.ndarray:
    """(3,) float64 unit vector for an axis name such as ``"x"``, ``"-y"``, ``"+z"``."""
    s = str(spec).strip().lower()
    sign = -1.0 if s.startswith("-") else 1.0
    s = s.lstrip("+-")
    if s not in _AXES:
        raise ParameterError(f"axis must be one of x, y, z, -x, -y, -z; got {spec!r}")
    v = np.zeros(3)
    v[_AXES[s]] = sign
    return v


def axes_rotation(up: str = "z", forward: str = "x") -> np.ndarray:
    """(3, 3) float64 rotation taking source coordinates into the object frame.

    The object frame is x forward, y left, z up: ``p_obj = R @ p_src`` where the rows
    of ``R`` are the source's forward, left (= up x forward) and up vectors.
    """
    u, f = axis_vector(up), axis_vector(forward)
    if abs(float(u @ f)) > 0.5:
        raise ParameterError(f"up ({up}) and forward ({forward}) must be different axes")
    return np.stack([f, np.cross(u, f), u])


def load_mesh(path: str | os.PathLike, up: str = "z", forward: str = "x"):
    """Load and validate a triangle mesh, returned in the object frame.

    Parameters
    ----------
    path : OBJ/PLY/OFF/STL/GLB/GLTF file. Scenes are flattened into one mesh.
    up, forward : the source file's up and forward axes (e.g. glTF: ``up="y"``);
        the mesh is rotated so that forward is +x, left +y and up +z.

    Returns
    -------
    trimesh.Trimesh with float64 vertices (V, 3) and int64 faces (F, 3); faces of zero
    area are kept (they are harmless to ray casting) unless every face is degenerate.

    Raises
    ------
    InputFileError : missing/unreadable file, not a mesh, empty, non-finite
        vertices, only degenerate faces, zero-size bounding box.
    """
    import trimesh

    p = Path(path)
    if not p.exists():
        raise InputFileError(p, "no such file")
    if p.is_dir():
        raise InputFileError(p, "is a folder, expected a mesh file")
    rot = axes_rotation(up, forward)
    try:
        loaded = trimesh.load(str(p), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for bad files
        msg = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise InputFileError(p, f"cannot read as a mesh ({msg})") from None
    if isinstance(loaded, list):  # pragma: no cover - old trimesh
        loaded = trimesh.util.concatenate(loaded)
    if not isinstance(loaded, trimesh.Trimesh):
        raise InputFileError(p, f"not a triangle mesh (got {type(loaded).__name__})")
    v = np.asarray(loaded.vertices, dtype=np.float64)
    f = np.asarray(loaded.faces, dtype=np.int64)
    if len(v) == 0 or len(f) == 0:
        raise InputFileError(p, "empty mesh (no faces)")
    if not np.all(np.isfinite(v)):
        raise InputFileError(p, "mesh has NaN or infinite vertex coordinates")
    if f.min() < 0 or f.max() >= len(v):
        raise InputFileError(p, "mesh has face indices out of range")
    used = v[np.unique(f)]
    if np.all(np.ptp(used, axis=0) == 0):
        raise InputFileError(p, "mesh has a zero-size bounding box (all vertices coincide)")
    tri = v[f]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not np.any(area2 > 0):
        raise InputFileError(p, "mesh has only degenerate (zero-area) faces")
    if not np.allclose(rot, np.eye(3)):
        v = v @ rot.T
    return trimesh.Trimesh(vertices=v, faces=f, process=False, validate=False)


def load_points(path: str | os.PathLike) -> np.ndarray:
    """Load a point cloud as a (K, 3) float64 array (extra columns such as intensity dropped).

    Formats: ``.ply`` (vertices), ``.pcd`` (x, y, z fields), ``.npy`` ((K, >=3)),
    ``.npz`` (key ``points``, else ``partial``, else the only array), ``.xyz``/``.txt``
    (whitespace or comma separated, first three columns).
    Raises :class:`InputFileError` for missing, unreadable, empty or non-finite clouds.
    """
    p = Path(path)
    if not p.exists():
        raise InputFileError(p, "no such file")
    suffix = p.suffix.lower()
    try:
        if suffix == ".pcd":
            from pypcd4 import PointCloud

            pc = PointCloud.from_path(p)
            if not all(k in pc.fields for k in ("x", "y", "z")):
                raise InputFileError(p, f"PCD has no x, y, z fields (fields: {', '.join(pc.fields)})")
            pts = pc.numpy(("x", "y", "z"))
        elif suffix == ".ply":
            import trimesh

            obj = trimesh.load(str(p), process=False)
            pts = getattr(obj, "vertices", None)
            if pts is None:
                raise InputFileError(p, "PLY holds no vertices")
        elif suffix == ".npy":
            pts = np.load(p, allow_pickle=False)
        elif suffix == ".npz":
            with np.load(p, allow_pickle=False) as z:
                key = next((k for k in ("points", "partial") if k in z.files), None)
                if key is None and len(z.files) == 1:
                    key = z.files[0]
                if key is None:
                    raise InputFileError(p, f"NPZ has no 'points' array (keys: {', '.join(z.files)})")
                pts = z[key]
        elif suffix in (".xyz", ".txt", ".csv"):
            with open(p) as fh:
                text = fh.read().replace(",", " ")
            rows = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
            pts = np.array([r[:3] for r in rows], dtype=np.float64) if rows else np.zeros((0, 3))
        else:
            raise InputFileError(p, f"unknown point-cloud format {suffix!r} (use {', '.join(POINT_SUFFIXES)})")
    except InputFileError:
        raise
    except Exception as exc:
        raise InputFileError(p, f"cannot read point cloud ({type(exc).__name__}: {str(exc).splitlines()[0][:100] if str(exc) else ''})") from None
    pts = np.asarray(pts)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise InputFileError(p, f"expected (K, 3) points, got shape {pts.shape}")
    pts = pts[:, :3].astype(np.float64)
    if len(pts) == 0:
        raise InputFileError(p, "point cloud is empty")
    if not np.all(np.isfinite(pts)):
        raise InputFileError(p, "point cloud has NaN or infinite coordinates")
    return pts


def save_points(path: str | os.PathLike, points: np.ndarray) -> Path:
    """Write (K, 3) points atomically; the format follows the suffix (.ply .pcd .npy .xyz .txt).

    PLY is binary little-endian float32; PCD is binary float32 x, y, z; XYZ is text.
    """
    p = Path(path)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    suffix = p.suffix.lower()
    if suffix not in (".ply", ".pcd", ".npy", ".xyz", ".txt"):
        raise InputFileError(p, f"unknown output format {suffix!r} (use .ply, .pcd, .npy, .xyz or .txt)")
    with atomic_output(p) as tmp:
        if suffix == ".ply":
            import trimesh

            data = trimesh.PointCloud(pts.astype(np.float32)).export(file_type="ply", encoding="binary")
            tmp.write_bytes(data)
        elif suffix == ".pcd":
            from pypcd4 import PointCloud

            PointCloud.from_xyz_points(pts.astype(np.float32)).save(tmp)
        elif suffix == ".npy":
            with open(tmp, "wb") as fh:
                np.save(fh, pts.astype(np.float32))
        else:
            np.savetxt(tmp, pts, fmt="%.6f")
    return p


def ply_has_faces(path: str | os.PathLike) -> bool:
    """True when a PLY file's header declares at least one face (a mesh, not a point cloud)."""
    with open(path, "rb") as fh:
        head = fh.read(4096).split(b"end_header")[0].decode("ascii", "replace")
    for line in head.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0] == "element" and parts[1] == "face":
            return parts[2].isdigit() and int(parts[2]) > 0
    return False
