"""Spotlights encoding (mesh -> depth array) and decoding (depth array -> ordered points).

Depth convention (paper Sections 3.2 and 4): the first-hit distance along ray
``i*M + k`` in the unit frame, divided by 2 (i.e. by ``2R``), in ``[0, 1]``;
exactly 0 marks a miss. Only hits inside the unit sphere count (a ray's chord
through the sphere); with the paper's normalisation the whole object is inside.

Decoding is ``P = P1 + 2 * depth * d`` (the paper's ``P = P1 + r d`` in unit
frame units), an ordered point cloud with a validity mask.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import InputFileError, ParameterError
from ..inputs import check_npz_members
from ..outputs import atomic_output
from .frames import Normalization, normalization_from_mesh
from .io import load_mesh
from .raycast import RayCaster
from .rig import Rig, RigSpec, extents_from_normalization, parse_rig


def check_mesh_arrays(mesh) -> None:
    """Refuse what is not a triangle mesh: ``mesh`` needs ``vertices`` (V, 3) real numbers and ``faces`` (F, 3)
    integer indices (what :func:`~spotlights.geometry.io.load_mesh` returns: a ``trimesh.Trimesh``).

    Raises :class:`~spotlights.errors.ParameterError` naming what was given (a path, None, a point array or a
    ``trimesh.Scene`` gave an AttributeError deep in the ray caster).
    """
    hint = "a triangle mesh with vertices (V, 3) and faces (F, 3), e.g. spotlights.load_mesh(path)"
    if isinstance(mesh, (str, os.PathLike)):
        raise ParameterError(f"mesh must be {hint}, got the path {str(mesh)!r}: load it first")
    vertices, faces = getattr(mesh, "vertices", None), getattr(mesh, "faces", None)
    if vertices is None or faces is None:
        raise ParameterError(f"mesh must be {hint}, got {type(mesh).__name__}")
    v, f = np.asarray(vertices), np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or v.dtype.kind not in "iuf":
        raise ParameterError(f"mesh vertices must be (V, 3) real numbers, got {v.shape} of {v.dtype}")
    if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu" or (f.size and (f.min() < 0 or f.max() >= len(v))):
        raise ParameterError(f"mesh faces must be (F, 3) indices of its {len(v)} vertices, got {f.shape} of {f.dtype}")


class MeshProbe:
    """A mesh normalised into the unit sphere with its BVH built once, ready to be encoded.

    Parameters
    ----------
    mesh : object with ``vertices`` (V, 3) and ``faces`` (F, 3), in its own (source) frame.
    normalization : source -> unit transform; default: the mesh's axis-aligned box
        and its circumscribed sphere (the paper's step 1).
    engine : ray engine name (see :class:`~spotlights.geometry.raycast.RayCaster`).
    workers : threads sharing each query (default 1). With 2, rigs of at least
        ``raycast.SPLIT_MIN_RAYS`` rays are cast by two threads over the one BVH; the depths
        are the same bytes (see :class:`~spotlights.geometry.raycast.RayCaster`).
    """

    def __init__(self, mesh, normalization: Normalization | None = None, engine: str | None = None, workers: int = 1):
        check_mesh_arrays(mesh)
        self.normalization = normalization if normalization is not None else normalization_from_mesh(mesh)
        unit_vertices = self.normalization.to_unit(np.asarray(mesh.vertices))
        self.caster = RayCaster(unit_vertices, np.asarray(mesh.faces), engine=engine, workers=workers)

    def hit_distances(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(K,) float64 unit-frame first-hit distances inside the unit sphere, 0 on a miss.

        ``origins`` (K, 3) on the unit sphere, ``directions`` (K, 3) unit vectors pointing inward.
        """
        t = self.caster.distances(origins, directions).astype(np.float64)
        chord = np.clip(-2.0 * np.einsum("ij,ij->i", origins, directions), 0.0, 2.0)
        inside = np.isfinite(t) & (t <= chord + 1e-6)
        return np.where(inside, np.minimum(t, 2.0), 0.0)

    @property
    def box_extents(self) -> np.ndarray:
        """(3,) float64 half-extents of the object's box in the unit frame (``size / 2R``)."""
        return extents_from_normalization(self.normalization)

    def rig_for(self, rig: Rig | RigSpec | str) -> Rig:
        """The concrete rig to cast: ``rig`` itself, or a spec resolved for this object's box (a rig name such as
        ``"cap-32x64-60"`` or ``"box-128x128-ellipsoid-s1"`` is read by :func:`~spotlights.geometry.rig.parse_rig`)."""
        if isinstance(rig, str):
            rig = parse_rig(rig)
        if not isinstance(rig, (Rig, RigSpec)):
            raise ParameterError(f"rig must be a Rig, a RigSpec or a rig name (see make_rig), got {type(rig).__name__}")
        return rig.for_normalization(self.normalization) if isinstance(rig, RigSpec) else rig

    def encode(self, rig: Rig | RigSpec | str) -> np.ndarray:
        """(N*M,) float32 normalised depths for ``rig`` (0 = miss).

        A :class:`RigSpec` is resolved for this object's box first (:meth:`rig_for`);
        keep that rig (``rig_for(spec)``) to decode the depths.
        """
        # half the first-hit distance; misses, and hits beyond the ray's chord through the
        # unit sphere, become 0 (raycast.to_depths)
        return self.caster.rig_depths(self.rig_for(rig))

    def close(self) -> None:
        """Nothing to release (kept for ``with MeshProbe(...)`` and older code)."""
        self.caster.close()

    def __enter__(self) -> MeshProbe:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def encode_mesh(mesh, rig: Rig | RigSpec | str, normalization: Normalization | None = None) -> np.ndarray:
    """Encode one mesh with one rig.

    Parameters
    ----------
    mesh : object with ``vertices`` (V, 3) and ``faces`` (F, 3) in its own frame (anything else:
        :class:`~spotlights.errors.ParameterError`, :func:`check_mesh_arrays`).
    rig : the ray rig, a :class:`RigSpec` (box specs: resolved for the mesh's box;
        ``spec.for_normalization(norm)`` gives the rig that decodes the result), or a rig name
        (``"cap-32x64-60"``, ``"64x32@60"``, ``"box-128x128-ellipsoid-s1"``: :func:`~spotlights.geometry.rig.parse_rig`).
    normalization : source -> unit transform (default: the mesh's bounding-box sphere).

    Returns
    -------
    (N*M,) float32 depths in [0, 1], 0 = miss, in the rig's ray order.
    """
    return MeshProbe(mesh, normalization).encode(rig)


def encode_meshes(meshes: Iterable, rigs: Rig | RigSpec | Sequence, normalizations=None) -> dict[str, np.ndarray]:
    """Encode many meshes with one or several rigs, building each BVH once.

    Box specs (:class:`RigSpec`) are resolved per mesh for its own box; their rows
    decode with ``spec.for_box(extents of that mesh)``.

    Returns
    -------
    dict ``rig.name -> (n_meshes, N*M) float32`` depth arrays, meshes in input order.
    """
    rigs = [rigs] if isinstance(rigs, (Rig, RigSpec, str)) else list(rigs)
    rigs = [parse_rig(r) if isinstance(r, str) else r for r in rigs]
    meshes = list(meshes)
    norms = list(normalizations) if normalizations is not None else [None] * len(meshes)
    out = {r.name: np.zeros((len(meshes), r.n_rays), dtype=np.float32) for r in rigs}
    for j, (mesh, norm) in enumerate(zip(meshes, norms)):
        probe = MeshProbe(mesh, norm)
        for r in rigs:
            out[r.name][j] = probe.encode(r)
    return out


# Default threads of encode_mesh_files (measured: docs/benchmarks.md, benchmarks/encode.py).
FILE_WORKERS = 2


def _encode_file(job):
    path, rigs, up, forward = job
    probe = MeshProbe(load_mesh(path, up=up, forward=forward))
    return [probe.encode(r) for r in rigs]


def encode_mesh_files(
    paths: Sequence, rigs: Rig | RigSpec | Sequence, workers: int | None = None, up: str = "z", forward: str = "x"
) -> dict[str, np.ndarray]:
    """Load and encode mesh files, over meshes with ``workers`` threads.

    Each mesh is normalised by its own bounding box (box specs are resolved for it).
    The result does not depend on ``workers`` (files are processed independently and
    returned in input order). Threads, not processes: Embree releases the GIL while it
    casts, so one thread encodes while another loads, with no process to start and no
    ``if __name__ == "__main__":`` guard needed. Default ``workers``: :data:`FILE_WORKERS`
    (the faster choice measured on the 79 ApolloScape cars, docs/benchmarks.md).

    Returns
    -------
    dict ``rig.name -> (n_files, N*M) float32`` depth arrays.
    """
    rigs = [rigs] if isinstance(rigs, (Rig, RigSpec, str)) else list(rigs)
    rigs = [parse_rig(r) if isinstance(r, str) else r for r in rigs]
    jobs = [(os.fspath(p), rigs, up, forward) for p in paths]
    workers = min(FILE_WORKERS if workers is None else int(workers), len(jobs))
    if workers < 1 and jobs:
        raise ParameterError(f"workers must be >= 1, got {workers}")
    if workers > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(workers, thread_name_prefix="spotlights-encode") as pool:
            results = list(pool.map(_encode_file, jobs))
    else:
        results = [_encode_file(j) for j in jobs]
    return {
        r.name: np.stack([res[j] for res in results]) if results else np.zeros((0, r.n_rays), np.float32)
        for j, r in enumerate(rigs)
    }


def hit_ratio(depths: np.ndarray) -> float:
    """Share of rays with a hit (depth > 0) over all entries of ``depths``."""
    d = np.asarray(depths)
    return float(np.count_nonzero(d > 0) / d.size) if d.size else 0.0


def decode(
    depths: np.ndarray, rig: Rig | RigSpec, clip: float | None = None, extents: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Ordered point cloud from depths: ``P = P1 + 2 * depth * d`` (unit frame).

    Parameters
    ----------
    depths : (..., N*M) float depths in [0, 1] (any batch shape).
    rig : the rig that produced (or that a model predicted for) the depths; or a
        :class:`RigSpec` with ``extents`` (box specs: each depth array decodes with
        the rig of its own box); or a rig name (``"cap-32x64-60"``, read by :func:`parse_rig`).
    clip : optional threshold in [0, 1]; depths below it count as misses (the paper uses
        0.2 on predicted arrays). A depth of exactly 0 is always a miss.
    extents : with a box spec, (..., 3) float box half-extents in the unit frame,
        one per depth array (batch shape of ``depths``).

    Returns
    -------
    points : (..., N*M, 3) float32, unit frame; misses are placed at their ray origin.
    mask : (..., N*M) bool, True where the ray hit (and passed the clip).

    Kept depths are clamped to half their ray's chord through the unit sphere, so every point
    lies in the sphere (predicted depths can exceed it; encoded ones cannot).
    :class:`~spotlights.errors.ParameterError` for a ``rig`` that is none of these (None), depths that are NaN,
    infinite, negative or above 1, or a ``clip`` that is NaN or outside [0, 1].
    """
    if isinstance(rig, str):
        rig = parse_rig(rig)
    if not isinstance(rig, (Rig, RigSpec)):
        raise ParameterError(f"rig must be a Rig, a RigSpec or a rig name (see make_rig), got {type(rig).__name__}")
    try:
        d = np.asarray(depths, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"depths must be an array of numbers, got {type(depths).__name__}") from None
    if d.size and not (np.all(np.isfinite(d)) and d.min() >= 0.0 and d.max() <= 1.0):
        bad = int(np.count_nonzero(~((d >= 0.0) & (d <= 1.0))))  # NaN fails both comparisons
        raise ParameterError(
            f"depths must be finite numbers in [0, 1] (0 = miss), got {bad} of {d.size} outside "
            f"(NaN, infinite, negative or above 1)"
        )
    if clip is not None:
        if isinstance(clip, (bool, str)) or not isinstance(clip, (int, float, np.number)):
            raise ParameterError(f"clip must be a depth threshold in [0, 1] or None, got {clip!r:.60}")
        if not 0.0 <= float(clip) <= 1.0:  # NaN fails too
            raise ParameterError(f"clip must be a depth threshold in [0, 1] or None, got {clip}")
    if d.shape[-1:] != (rig.n_rays,):
        raise ParameterError(
            f"depth array has {d.shape[-1] if d.ndim else 0} entries, the rig {rig.name} has {rig.n_rays} rays"
        )
    if isinstance(rig, RigSpec) and rig.needs_box:
        if extents is None:
            raise ParameterError(
                f"decoding with the box spec {rig.name} needs the box half-extents of each depth array"
            )
        e = np.asarray(extents, dtype=np.float64)
        if e.shape != d.shape[:-1] + (3,):
            raise ParameterError(
                f"extents must have shape {d.shape[:-1] + (3,)} for depths of shape {d.shape}, got {e.shape}"
            )
        origins = rig.origins
        directions = rig.directions_for_boxes(e.reshape(-1, 3)).reshape(d.shape + (3,))
    else:
        rig = rig.for_box(None) if isinstance(rig, RigSpec) else rig
        origins, directions = rig.origins, rig.directions
    mask = d > 0.0
    if clip is not None:
        mask &= d >= float(clip)
    # A depth is clamped to half the ray's chord through the unit sphere (<= 1): no decoded point
    # leaves the sphere, whatever a network predicted; encoded depths never exceed it (a ray from
    # the sphere meets the object, which lies inside it, before leaving the sphere).
    half_chord = np.maximum(-np.einsum("...j,...j->...", np.broadcast_to(origins, directions.shape), directions), 0.0)
    dist = np.where(mask, 2.0 * np.minimum(d, half_chord), 0.0)[..., None]
    points = origins + dist * directions
    return points.astype(np.float32), mask


@dataclass
class Encoding:
    """An encoding as stored in an ``.npz`` file (see :func:`save_encoding`).

    depths : (N*M,) float32; rig : the rig; normalization : source -> unit transform.
    """

    depths: np.ndarray
    rig: Rig
    normalization: Normalization

    def points(self, frame: str = "unit", clip: float | None = None) -> np.ndarray:
        """(H, 3) float64 hit points (misses dropped, ray order kept), in the ``"unit"`` or ``"original"`` frame."""
        pts, mask = decode(self.depths, self.rig, clip)
        pts = pts[mask].astype(np.float64)
        if frame == "original":
            return self.normalization.from_unit(pts)
        if frame != "unit":
            raise ParameterError(f"frame must be 'unit' or 'original', got {frame!r}")
        return pts


def save_encoding(path: str | os.PathLike, depths: np.ndarray, rig: Rig, normalization: Normalization) -> None:
    """Write an encoding ``.npz`` atomically.

    Keys: ``depths`` float32 (N*M,); ``origins``, ``directions`` float32 (N*M, 3) unit frame;
    ``center`` float64 (3,), ``radius`` float64 (), ``rotation`` float64 (3, 3) of the
    normalisation; ``primary``, ``secondary`` int64, ``angle`` float64 (degrees);
    ``rig`` (JSON string of ``Rig.to_dict()``).
    """
    if not isinstance(rig, Rig):
        raise ParameterError("save_encoding needs the concrete rig (RigSpec.for_box / MeshProbe.rig_for), not a spec")
    depths = np.asarray(depths, dtype=np.float32)
    if depths.shape != (rig.n_rays,):
        raise ParameterError(f"depths must have shape ({rig.n_rays},), got {depths.shape}")
    with atomic_output(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(
                fh,
                depths=depths,
                origins=rig.origins.astype(np.float32),
                directions=rig.directions.astype(np.float32),
                center=normalization.center.astype(np.float64),
                radius=np.float64(normalization.radius),
                rotation=normalization.rotation.astype(np.float64),
                primary=np.int64(rig.n_primary),
                secondary=np.int64(rig.n_secondary),
                angle=np.float64(rig.angle),
                rig=np.array(json.dumps(rig.to_dict())),
            )


def load_encoding(path: str | os.PathLike) -> Encoding:
    """Read an encoding ``.npz`` written by :func:`save_encoding` (validated; a zip bomb refused unopened:
    :func:`~spotlights.inputs.check_npz_members`)."""
    check_npz_members(path, ".npz encoding")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise InputFileError(path, "no such file") from None
    except Exception as exc:
        raise InputFileError(path, f"not a readable .npz encoding ({type(exc).__name__})") from None
    _check_encoding_arrays(path, data)
    rig, norm = _encoding_rig(path, data)
    depths = np.asarray(data["depths"], dtype=np.float32)
    if depths.shape != (rig.n_rays,):
        raise InputFileError(path, f"depths has shape {depths.shape}, expected ({rig.n_rays},) for {rig.name}")
    if not np.all(np.isfinite(depths)) or depths.min() < 0 or depths.max() > 1:
        raise InputFileError(path, "depths must be finite and within [0, 1]")
    return Encoding(depths=depths, rig=rig, normalization=norm)


def _check_encoding_arrays(path: str | os.PathLike, data: dict[str, np.ndarray]) -> None:
    """Refuse an encoding's arrays that miss a key, or whose scalars or real-valued arrays have the wrong kind."""
    missing = [k for k in ("depths", "center", "radius", "primary", "secondary", "angle") if k not in data]
    if missing:
        raise InputFileError(path, f"not a Spotlights encoding: missing key(s) {', '.join(missing)}")
    for key, kinds in (("primary", "iu"), ("secondary", "iu"), ("angle", "fiu"), ("radius", "fiu")):
        if data[key].shape != () or data[key].dtype.kind not in kinds:
            what = "a whole number" if kinds == "iu" else "a real number"
            raise InputFileError(
                path, f"{key} must be {what}, got a {data[key].dtype} array of shape {data[key].shape}"
            )
    for key in ("depths", "center", *(["rotation"] if "rotation" in data else [])):
        if data[key].dtype.kind not in "fiu":
            raise InputFileError(path, f"{key} holds {data[key].dtype} values, expected real numbers")


def _encoding_rig(path: str | os.PathLike, data: dict[str, np.ndarray]) -> tuple[Rig, Normalization]:
    """The rig (from its JSON when stored, else from primary, secondary, angle) and the normalisation of an
    encoding's arrays; their own checks' errors name the file."""
    try:
        rig = (
            Rig.from_dict(json.loads(str(data["rig"])))
            if "rig" in data
            else Rig(int(data["primary"]), int(data["secondary"]), float(data["angle"]))
        )
        norm = Normalization(
            center=data["center"], radius=float(data["radius"]), rotation=data.get("rotation", np.eye(3))
        )
    except (ParameterError, ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        msg = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        raise InputFileError(path, f"invalid rig or normalisation: {msg}") from None
    return rig, norm
