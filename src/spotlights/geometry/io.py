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
from ..inputs import check_npz_members
from ..outputs import atomic_output, check_regular_file
from .frames import MAX_COORDINATE

MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")
POINT_SUFFIXES = (".ply", ".pcd", ".npy", ".npz", ".xyz", ".txt", ".las", ".laz")
LAS_INSTALL_HINT = "pip install 'spotlights[las]'"
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
    InputFileError : missing/unreadable file, not a regular file (folder, FIFO), not a mesh, empty, non-finite
        vertices or vertices beyond :data:`~spotlights.geometry.frames.MAX_COORDINATE`, only degenerate faces,
        zero-size bounding box.
    """
    import trimesh

    p = check_regular_file(path, "mesh file")  # not a FIFO: reading one would block for ever
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
    if np.abs(v).max() > MAX_COORDINATE:  # refused before any size or area: no overflow warnings
        raise InputFileError(p, f"mesh has vertex coordinates out of range (beyond ±{MAX_COORDINATE:.0e})")
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


def load_points(path: str | os.PathLike, drop_nonfinite: bool = False) -> np.ndarray:
    """Load a point cloud as a (K, 3) float64 array (extra columns such as intensity dropped).

    Formats: ``.ply`` (vertices), ``.pcd`` (x, y, z fields), ``.npy`` ((K, >=3)),
    ``.npz`` (key ``points``, else ``partial``, else the only array), ``.xyz``/``.txt``
    (whitespace or comma separated, first three columns), ``.las``/``.laz`` (scaled x, y, z
    in float64; needs the optional ``laspy`` extra, ``pip install 'spotlights[las]'``).
    Raises :class:`InputFileError` for missing, unreadable, empty or non-finite clouds
    (``drop_nonfinite=True``: rows with NaN or infinite coordinates, the "no return" points of
    organised scans, are dropped instead; a cloud with none left is still an error), and for a
    path that is not a regular file (a folder; a FIFO, which reading would block on).
    """
    p = check_regular_file(path, "point-cloud file")  # not a FIFO: reading one would block for ever
    suffix = p.suffix.lower()
    reader = _POINT_READERS.get(suffix)
    try:
        if reader is None:
            raise InputFileError(p, f"unknown point-cloud format {suffix!r} (use {', '.join(POINT_SUFFIXES)})")
        pts = reader(p)
    except InputFileError:
        raise
    except Exception as exc:
        raise InputFileError(
            p, f"cannot read point cloud ({type(exc).__name__}: {str(exc).splitlines()[0][:100] if str(exc) else ''})"
        ) from None
    return _checked_xyz(p, pts, drop_nonfinite)


def _read_pcd_points(p: Path) -> np.ndarray:
    """x, y, z of a PCD file (pypcd4), checked for the fields and for truncation."""
    from pypcd4 import PointCloud

    pc = PointCloud.from_path(p)
    if not all(k in pc.fields for k in ("x", "y", "z")):
        raise InputFileError(p, f"PCD has no x, y, z fields (fields: {', '.join(pc.fields)})")
    if len(pc.pc_data) != pc.metadata.points:
        raise InputFileError(
            p,
            f"truncated PCD: its header declares {pc.metadata.points} points, the file holds {len(pc.pc_data)}",
        )
    return pc.numpy(("x", "y", "z"))


def _read_ply_points(p: Path) -> np.ndarray:
    """The vertices of a PLY file (trimesh), checked against the header's vertex count."""
    import trimesh

    obj = trimesh.load(str(p), process=False)
    pts = getattr(obj, "vertices", None)
    if pts is None:
        raise InputFileError(p, "PLY holds no vertices")
    declared = _ply_vertex_count(p)
    if declared is not None and declared != len(pts):
        raise InputFileError(p, f"truncated PLY: its header declares {declared} vertices, the file holds {len(pts)}")
    return pts


def _read_npy_points(p: Path) -> np.ndarray:
    """The array of an NPY file (no pickles)."""
    return np.load(p, allow_pickle=False)


def _read_npz_points(p: Path) -> np.ndarray:
    """The ``points`` array of an NPZ file, else ``partial``, else its only array."""
    check_npz_members(p, "NPZ point cloud")  # a zip bomb is refused from the zip directory, unopened
    with np.load(p, allow_pickle=False) as z:
        key = next((k for k in ("points", "partial") if k in z.files), None)
        if key is None and len(z.files) == 1:
            key = z.files[0]
        if key is None:
            raise InputFileError(p, f"NPZ has no 'points' array (keys: {', '.join(z.files)})")
        return z[key]


def _read_text_points(p: Path) -> np.ndarray:
    """The first three columns of a whitespace- or comma-separated text file (``#`` lines are comments)."""
    with open(p) as fh:
        text = fh.read().replace(",", " ")
    rows = [ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    return np.array([r[:3] for r in rows], dtype=np.float64) if rows else np.zeros((0, 3))


def _checked_xyz(p: Path, pts: object, drop_nonfinite: bool) -> np.ndarray:
    """The (K, 3) float64 coordinates of a cloud just read from ``p`` (extra columns dropped), checked for
    dtype, shape, emptiness and finiteness (non-finite rows dropped first when ``drop_nonfinite``)."""
    pts = np.asarray(pts)
    if pts.dtype.kind not in "fiu":  # text, bytes, records, dates, complex numbers, booleans: not coordinates
        raise InputFileError(p, f"points must be real numbers (float or integer), got dtype {pts.dtype}")
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise InputFileError(p, f"expected (K, 3) points, got shape {pts.shape}")
    pts = pts[:, :3].astype(np.float64)
    if drop_nonfinite:
        pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        raise InputFileError(p, "point cloud is empty" + (" (no finite point)" if drop_nonfinite else ""))
    if not np.all(np.isfinite(pts)):
        raise InputFileError(p, "point cloud has NaN or infinite coordinates")
    return pts


#: The fewest bytes a LAZ file spends per point: 2 million identical points compress to 0.007-0.012
#: bytes each (lazrs, point formats 0, 3, 6); a real scan takes 1-4. A header claiming more points
#: than its data could hold at 0.004 bytes each is refused before anything is allocated.
LAZ_MIN_BYTES_PER_POINT = 0.004


def _check_las_size(p: Path, header) -> None:
    """Refuse a LAS/LAZ header whose point count the file is too small to hold (a damaged or hostile
    header would make the reader allocate gigabytes for minutes): LAS, count x record length must fit
    after the header; LAZ, the compressed data must hold at least LAZ_MIN_BYTES_PER_POINT per point."""
    n, record = int(header.point_count), int(header.point_format.size)
    stored = p.stat().st_size - int(header.offset_to_point_data)
    if header.are_points_compressed:
        fits = n * LAZ_MIN_BYTES_PER_POINT <= stored
    else:
        fits = n * record <= stored
    if not fits:
        raise InputFileError(
            p,
            f"header declares {n:,} points but the file holds {max(stored, 0):,} bytes of point data "
            "(truncated or damaged)",
        )


#: Points decompressed at a time from a LAS/LAZ file: only their x, y, z (24 bytes a point) are kept, so the reader's
#: memory beyond the result stays under ~100 MB whatever the point record's size.
LAS_CHUNK_POINTS = 1 << 20

#: Smallest size of a VLR (its 54-byte header) and of an extended VLR (60 bytes), LAS 1.0-1.4.
_VLR_HEADER_BYTES, _EVLR_HEADER_BYTES = 54, 60

#: The LAS header's own size by minor version (1.0-1.2, 1.3, 1.4).
_LAS_HEADER_BYTES = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}


def _check_las_header(p: Path) -> None:
    """Refuse a LAS/LAZ file whose fixed header cannot be true for a file of its size, before laspy reads it.

    laspy trusts the header's counts: 4 KB of ``LASF`` and random bytes declared ~1e9 VLRs, which it read one
    empty record at a time, growing by 15 MB/s for as long as it ran. Checked here (LAS 1.0-1.4 header layout):
    the version, the header size, the offset of the point data within the file, every declared VLR (54 bytes
    at least) between the header and the points, the point format (0-10, compressed or not), and the extended
    VLRs of LAS 1.4 within the file.
    """
    import struct

    size = p.stat().st_size
    with open(p, "rb") as fh:
        head = fh.read(375)

    def bad(problem: str) -> InputFileError:
        return InputFileError(p, f"not a readable LAS/LAZ file ({problem})")

    if len(head) < 227 or head[:4] != b"LASF":
        raise bad("no LAS header: it must start with LASF and hold 227 bytes at least")
    major, minor = head[24], head[25]
    if major != 1 or minor not in _LAS_HEADER_BYTES:
        raise bad(f"unknown LAS version {major}.{minor} (1.0-1.4 are read)")
    header_size, offset, n_vlrs = struct.unpack_from("<HII", head, 94)
    point_format, record = struct.unpack_from("<BH", head, 104)
    if not _LAS_HEADER_BYTES[minor] <= header_size <= size:
        raise bad(f"header size {header_size} does not fit LAS 1.{minor} or the file's {size:,} bytes")
    if not header_size <= offset <= size:
        raise bad(f"points start at byte {offset:,}, outside the file's {header_size}-{size:,}")
    if n_vlrs * _VLR_HEADER_BYTES > offset - header_size:
        raise bad(f"header declares {n_vlrs:,} VLRs, more than its {offset - header_size:,} bytes before the points")
    if (point_format & 0x3F) > 10:
        raise bad(f"unknown point format {point_format & 0x3F}")
    if minor >= 4 and len(head) >= 375:
        first_evlr, n_evlrs = struct.unpack_from("<QI", head, 235)
        if n_evlrs and (first_evlr > size or n_evlrs * _EVLR_HEADER_BYTES > size - first_evlr):
            raise bad(f"header declares {n_evlrs:,} extended VLRs beyond the file's {size:,} bytes")


def _read_las(p: Path) -> np.ndarray:
    """x, y, z (K, 3) float64 of a LAS/LAZ file (scale and offset applied) via laspy, bounded in memory: the
    header is checked against the file's size first (:func:`_check_las_header`, :func:`_check_las_size`), then the
    points are decompressed :data:`LAS_CHUNK_POINTS` at a time."""
    try:
        import laspy
    except ImportError:
        raise InputFileError(p, f"reading LAS/LAZ needs laspy: {LAS_INSTALL_HINT}") from None
    _check_las_header(p)
    try:
        with laspy.open(str(p)) as reader:
            _check_las_size(p, reader.header)
            parts = [
                np.stack(
                    [
                        np.asarray(chunk.x, dtype=np.float64),
                        np.asarray(chunk.y, dtype=np.float64),
                        np.asarray(chunk.z, dtype=np.float64),
                    ],
                    axis=1,
                )
                for chunk in reader.chunk_iterator(LAS_CHUNK_POINTS)
            ]
    except laspy.errors.LaspyException as exc:
        msg = str(exc).splitlines()[0][:100] if str(exc) else type(exc).__name__
        if p.suffix.lower() == ".laz" and "backend" in msg.lower():
            raise InputFileError(p, f"reading LAZ needs a decompressor (lazrs): {LAS_INSTALL_HINT}") from None
        raise InputFileError(p, f"not a readable LAS/LAZ file ({msg})") from None
    return np.concatenate(parts) if parts else np.zeros((0, 3))


#: The point-cloud reader of each file suffix (each returns the raw array; :func:`load_points` checks it).
_POINT_READERS = {
    ".pcd": _read_pcd_points,
    ".ply": _read_ply_points,
    ".npy": _read_npy_points,
    ".npz": _read_npz_points,
    ".las": _read_las,
    ".laz": _read_las,
    ".xyz": _read_text_points,
    ".txt": _read_text_points,
    ".csv": _read_text_points,
}


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


def save_ply(
    path: str | os.PathLike,
    points: np.ndarray,
    fields: dict[str, np.ndarray] | None = None,
    comments: list[str] | None = None,
    precision: str = "auto",
) -> Path:
    """Write a binary little-endian PLY point cloud with extra per-point fields (atomic).

    Parameters
    ----------
    points : (K, 3) coordinates, written as ``x y z``.
    fields : name -> (K,) array of extra vertex properties; the PLY type follows the dtype
        (uint8 -> uchar, int32 -> int, float32 -> float, ...; int64/float64 are narrowed to int/double).
    comments : header ``comment`` lines (one line each; newlines are replaced by spaces, ``end_header`` by
        ``end-header``).
    precision : ``"float"`` (float32), ``"double"`` (float64) or ``"auto"``: double when a
        coordinate's magnitude exceeds 1e4 (float32 would round georeferenced scans to cm or worse).

    Returns the path. Readable by trimesh, Open3D, CloudCompare, plyfile.
    """
    p = Path(path)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if precision == "auto":
        precision = "double" if (len(pts) and float(np.abs(pts).max()) > 1e4) else "float"
    if precision not in ("float", "double"):
        raise ParameterError(f"precision must be 'float', 'double' or 'auto', got {precision!r}")
    ply_types = {
        "u1": "uchar",
        "i1": "char",
        "u2": "ushort",
        "i2": "short",
        "u4": "uint",
        "i4": "int",
        "f4": "float",
        "f8": "double",
    }
    narrow = {"i8": "<i4", "u8": "<u4", "b1": "u1"}
    cdt = "<f8" if precision == "double" else "<f4"
    dtype = [("x", cdt), ("y", cdt), ("z", cdt)]
    cols = {}
    for name, v in (fields or {}).items():
        a = np.asarray(v).reshape(-1)
        if len(a) != len(pts):
            raise ParameterError(f"PLY field {name!r} has {len(a)} values for {len(pts)} points")
        code = a.dtype.str[1:]
        a = a.astype(narrow.get(code, "<" + code) if code not in ("u1", "i1") else code)
        if a.dtype.str[1:] not in ply_types:
            raise ParameterError(f"PLY field {name!r}: unsupported dtype {v.dtype}")
        cols[name] = a
        dtype.append((name, a.dtype.newbyteorder("<").str))
    rec = np.empty(len(pts), dtype=dtype)
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    for name, a in cols.items():
        rec[name] = a
    head = ["ply", "format binary_little_endian 1.0"]
    # one line each, and never the word that ends a header (readers split the file at its first occurrence)
    head += ["comment " + " ".join(str(c).split()).replace("end_header", "end-header") for c in (comments or [])]
    head.append(f"element vertex {len(pts)}")
    head += [f"property {ply_types[rec.dtype[n].str[1:]]} {n}" for n in rec.dtype.names]
    head.append("end_header")
    with atomic_output(p) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(("\n".join(head) + "\n").encode("ascii", "replace"))
            fh.write(rec.tobytes())
    return p


def load_ply_fields(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every vertex property of a PLY file as name -> (K,) array (e.g. ``x``, ``y``, ``z``, ``source``, ``object``).

    Reads what :func:`save_ply` writes (binary little-endian or ASCII vertex-only PLYs) with ``plyfile``; a file
    holding fewer vertices than its header declares is a one-line :class:`InputFileError`.
    """
    from plyfile import PlyData

    p = Path(path)
    if not p.is_file():
        raise InputFileError(p, "no such file")
    declared = _ply_vertex_count(p)
    try:
        ply = PlyData.read(str(p))
    except Exception as exc:  # noqa: BLE001 - whatever the parser trips on is the file's fault
        if declared is not None and "end-of-file" in str(exc).lower():
            raise InputFileError(
                p, f"truncated PLY: its header declares {declared} vertices, the file holds fewer"
            ) from None
        raise InputFileError(p, f"cannot read PLY ({type(exc).__name__}: {str(exc)[:100]})") from None
    if "vertex" not in ply:
        raise InputFileError(p, "PLY holds no vertex element")
    data = ply["vertex"].data
    fields = {n: np.asarray(data[n]) for n in data.dtype.names}
    held = {len(a) for a in fields.values()}
    if declared is not None and held != {declared}:
        raise InputFileError(p, f"truncated PLY: its header declares {declared} vertices, the file holds {min(held)}")
    return fields


def _ply_vertex_count(path: Path) -> int | None:
    """The vertex count a PLY's header declares (``element vertex N``), None when it declares none or is no PLY."""
    with open(path, "rb") as fh:
        lines, _, _ = _ply_header(fh)
    for words in lines or []:
        if words[:2] == ["element", "vertex"] and len(words) == 3 and words[2].isdigit():
            return int(words[2])
    return None


#: Bytes of each PLY scalar type (the names of the PLY specification and their aliases).
_PLY_TYPE_BYTES = {
    "char": 1, "uchar": 1, "int8": 1, "uint8": 1,
    "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
    "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4,
    "double": 8, "float64": 8,
}  # fmt: skip


# a PLY header is read line by line up to this many bytes (ply_is_whole reads a longer one whole)
_PLY_HEADER_MAX = 1 << 20


def _ply_header(fh) -> tuple[list[list[str]] | None, int, int]:
    """The header of the PLY open in ``fh`` (binary, at its start), read line by line up to its own ``end_header``
    line (not a comment holding the word) and at most :data:`_PLY_HEADER_MAX` bytes.

    Returns ``(lines, body, read)``: the whitespace-split lines between ``ply`` and ``end_header`` (None when the
    first line is not ``ply``), the body's byte offset (-1: no ``end_header`` line within the file or the window),
    and the bytes read."""
    first = fh.readline(_PLY_HEADER_MAX)
    read = len(first)
    if first.rstrip(b"\r\n") != b"ply":
        return None, -1, read
    lines: list[list[str]] = []
    while read < _PLY_HEADER_MAX:
        line = fh.readline(_PLY_HEADER_MAX - read)
        read += len(line)
        if not line.endswith(b"\n"):  # the file or the window ends inside the header
            break
        if line.rstrip(b"\r\n") == b"end_header":
            return lines, read, read
        lines.append(line.decode("ascii", "replace").split())
    return lines, -1, read


def ply_is_whole(path: str | os.PathLike) -> bool:
    """True when a binary vertex-only PLY (what :func:`save_ply` writes) holds exactly the bytes its header declares.

    Reads the header only (one stat, its lines up to ``end_header``, at most 1 MiB): a file cut short by a crash
    or a full disk, or with bytes appended, is False, as is a missing file or a header that is not PLY. Other
    PLYs (ASCII, faces, list properties, a longer header) are read whole with :func:`load_ply_fields`, which
    checks the vertex count.
    """
    p = Path(path)
    try:
        size = p.stat().st_size
        with open(p, "rb") as fh:
            lines, body, read = _ply_header(fh)
    except OSError:
        return False
    if lines is None:
        return False
    if body < 0:
        if read < _PLY_HEADER_MAX:
            return False  # no end_header before the end of the file
        lines = [["header", "too", "long"]]  # not judged from the window: read whole below
    elements = [line for line in lines if line and line[0] == "element"]
    props = [line for line in lines if line and line[0] == "property"]
    if not _is_binary_vertex_ply(lines, elements, props):
        try:
            load_ply_fields(p)
        except InputFileError:
            return False
        return True
    row = sum(_PLY_TYPE_BYTES[q[1]] for q in props)
    return size == body + int(elements[0][2]) * row


def _is_binary_vertex_ply(lines: list[list[str]], elements: list[list[str]], props: list[list[str]]) -> bool:
    """True when a PLY header's split ``lines`` (with its ``element`` and ``property`` lines) declare a binary
    little-endian file of one ``vertex`` element with scalar properties only: its size follows from the header."""
    fmt = next((line[1] for line in lines if len(line) >= 2 and line[0] == "format"), "")
    return (
        fmt == "binary_little_endian"
        and len(elements) == 1
        and len(elements[0]) == 3
        and elements[0][1] == "vertex"
        and elements[0][2].isdigit()
        and all(len(q) == 3 and q[1] in _PLY_TYPE_BYTES for q in props)
    )


def ply_has_faces(path: str | os.PathLike) -> bool:
    """True when a PLY file's header declares at least one face (a mesh, not a point cloud)."""
    with open(path, "rb") as fh:
        lines, _, _ = _ply_header(fh)
    for parts in lines or []:
        if len(parts) == 3 and parts[0] == "element" and parts[1] == "face":
            return parts[2].isdigit() and int(parts[2]) > 0
    return False
