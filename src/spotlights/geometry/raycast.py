"""First-hit ray casting on triangle meshes: one class per ray engine, one interface.

Engines (every one has the methods of :class:`RayEngine`)
---------------------------------------------------------
* :class:`EmbreeEngine` (default): Intel Embree through ``embreex``; a BVH built once per
  mesh, then single-ray queries. Triangles are hit whatever their winding (real meshes are
  not watertight and not consistently oriented).
* :class:`Open3DEngine` (optional, ``engine="open3d"`` when ``open3d`` is installed): Open3D's
  ``RaycastingScene``, Embree on Open3D's own TBB threads. Agrees with Embree to float32
  rounding, not bit for bit.
* :class:`TrimeshEngine` (fallback where embreex is missing, with a warning): trimesh's
  numpy engine, ~100x slower.

:class:`RayCaster` picks an engine by name and adds the queries built on it (depths of a rig).

Miss conventions: one per kind of query
---------------------------------------
* distances (``distances``, ``first_hit``'s ``t``): ``+inf``;
* triangle indices (``first_hit``'s ``face``): ``-1``;
* Spotlights depths (``rig_depths``, ``MeshProbe.encode``): ``0.0``, the paper's convention
  (also for a hit beyond the ray's chord through the unit sphere).

Both cores for one query (``workers=2``)
---------------------------------------
``embreex`` (4.4) releases the GIL around its loop over rays (``PyEval_SaveThread`` in the
compiled ``rtcore_scene``), and a committed Embree scene answers queries from several threads
at once. So with ``workers > 1`` a query of at least :data:`SPLIT_MIN_RAYS` rays is cut into
``workers`` contiguous chunks of equal size, cast by the calling thread and ``workers - 1``
threads of one shared pool, over the same scene. Chunks are claimed in order by whichever
thread asks next, so the calling thread never waits for a pool thread that has not claimed a
chunk (a busy or slow-to-wake pool only means the caller casts more itself). One chunk per
thread is what pays: every engine call costs a fixed ~15-20 us with the GIL held, and finer
(guided) chunking measured 0.1-0.2x slower at 8,192 rays (``benchmarks/encode.py``). Every ray
is cast by the same single-ray code whatever the thread, so the results are the same bytes
whatever ``workers``. Below :data:`SPLIT_MIN_RAYS` a query stays on one thread: there,
handing work over costs about what it saves (measured: ``benchmarks/encode.py``,
docs/benchmarks.md). Two threads stay short of two processes (measured here at 32,768 rays:
1.7x against 1.94x for two independent processes): part of each ``embreex`` call runs with
the GIL held.
"""

from __future__ import annotations

import os
import threading
import warnings
from collections.abc import Callable

import numpy as np

from ..errors import ParameterError
from ..processes import shared_thread_pool

# Queries with fewer rays run on one thread: below this, splitting does not pay (measured in
# benchmarks/encode.py: 2,048 rays, ~0.12 ms, gain nothing or lose; 4,096 rays gain a little).
SPLIT_MIN_RAYS = 4096
# Rays per engine call without threads (bounds the temporaries of first_hit on huge queries).
_CALL_RAYS = 1 << 22
_MAX_THREADS = 64


def embree_available() -> bool:
    """Whether Embree's Python binding (``embreex``) imports here: the default ``"embree"`` engine is usable."""
    try:
        import embreex.mesh_construction  # noqa: F401
        import embreex.rtcore_scene  # noqa: F401
    except Exception:  # pragma: no cover - platform dependent
        return False
    return True


def to_depths(t: np.ndarray, half_chords: np.ndarray, fresh: bool = False) -> np.ndarray:
    """Raw first-hit distances -> Spotlights depths, in place (a new array with ``fresh``).

    ``t`` (K,) float32 unit-frame distances (``inf`` on a miss, never negative or NaN);
    ``half_chords`` (K,) float32 largest valid depth per ray. Result: ``min(t / 2, 1)``, and
    exactly 0 (positive zero) for a miss or a hit beyond the ray's chord through the unit sphere.
    """
    t = np.multiply(t, np.float32(0.5), out=None if fresh else t)
    valid = np.less_equal(t, half_chords)
    np.minimum(t, np.float32(1.0), out=t)  # a miss (inf) becomes 1 here, then 1 * 0 = +0
    return np.multiply(t, valid, out=t)


def _as_rays(origins, directions) -> tuple[np.ndarray, np.ndarray]:
    """C-contiguous float32 (K, 3) copies (or the arrays themselves when they already are)."""
    o = np.ascontiguousarray(origins, dtype=np.float32)
    d = np.ascontiguousarray(directions, dtype=np.float32)
    if o.shape != d.shape or o.ndim != 2 or o.shape[1] != 3:
        raise ParameterError(f"origins and directions must both be (K, 3), got {o.shape} and {d.shape}")
    return o, d


def split_bounds(n: int, parts: int) -> list[int]:
    """Boundaries of ``parts`` contiguous chunks of ``n`` rays whose sizes differ by at most one.

    ``n`` rays, ``parts`` >= 1 chunks. Returns ``parts + 1`` ints from 0 to ``n``, non-decreasing:
    chunk ``i`` is ``[b[i], b[i + 1])``.
    """
    return [n * i // parts for i in range(parts + 1)]


class _Job:
    """One query's chunks, claimed in order by whichever thread asks next."""

    __slots__ = ("cast", "bounds", "claimed", "left", "lock", "done", "error")

    def __init__(self, cast, bounds: list[int]):
        self.cast = cast
        self.bounds = bounds
        self.claimed = 0
        self.left = len(bounds) - 1
        self.lock = threading.Lock()
        self.done = threading.Event()
        self.error: BaseException | None = None

    def work(self) -> None:
        bounds, lock = self.bounds, self.lock
        m = len(bounds) - 1
        while True:
            with lock:
                i = self.claimed
                if i >= m or self.error is not None:
                    return
                self.claimed = i + 1
            try:
                self.cast(bounds[i], bounds[i + 1])
            except BaseException as exc:  # handed to the calling thread
                self.error = exc
                self.done.set()
                return
            with lock:
                self.left -= 1
                if self.left == 0:
                    self.done.set()


def run_split(n: int, threads: int, cast: Callable[[int, int], object]) -> None:
    r"""``cast(a, b)`` once for each of :func:`split_bounds`\ ``(n, threads)``'s chunks ``[a, b)`` of ``[0, n)``,
    on the calling thread and ``threads - 1`` threads of the process's shared ray pool; returns when
    every chunk is done. The first exception of any chunk is raised here (later chunks are not
    started); the pool stays usable. A process forked after the pool exists builds its own."""
    job = _Job(cast, split_bounds(n, threads))
    pool = shared_thread_pool("rays", threads - 1)  # one for every caster of the process; a forked child's own
    for _ in range(threads - 1):
        try:
            pool.submit(job.work)
        except RuntimeError:  # interpreter shutting down: the caller casts everything
            break
    try:
        job.work()
        job.done.wait()
    except BaseException as exc:  # Ctrl-C while waiting: the pool threads stop claiming chunks
        if job.error is None:
            job.error = exc
        raise
    if job.error is not None:
        raise job.error


# ---------------------------------------------------------------------------- engines


class RayEngine:
    """The interface of a ray engine: a BVH over one triangle mesh, answering first-hit queries.

    Parameters
    ----------
    vertices : (V, 3) float array.
    faces : (F, 3) int array of vertex indices (validated by :class:`RayCaster`).
    threads : threads one query may use (engines that cannot use threads ignore it).

    Methods are safe to call from several threads at once.
    """

    name = "abstract"

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int = 1):
        self.threads = max(1, min(int(threads), _MAX_THREADS))

    def distances(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(K,) float32 distance along each ray to its first hit, ``inf`` on a miss.

        ``origins``, ``directions``: (K, 3) arrays (float32 C-contiguous input avoids a copy),
        directions of unit length; distances are then in the mesh's units.
        """
        raise NotImplementedError

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(t, face)``: (K,) float64 first-hit distances (``inf`` on a miss) and (K,) int64
        indices of the hit triangles (``-1`` on a miss)."""
        raise NotImplementedError

    def rig_distances(self, rig) -> np.ndarray:
        """:meth:`distances` for every ray of a :class:`~spotlights.geometry.rig.Rig` (its cached float32 rays)."""
        return self.distances(*rig.rays32)


class EmbreeEngine(RayEngine):
    """Intel Embree through ``embreex``; ``threads > 1`` shares big queries between threads
    over the one committed scene (see the module docstring). Same bytes whatever ``threads``."""

    name = "embree"

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int = 1):
        super().__init__(vertices, faces, threads)
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self._scene = rtcore_scene.EmbreeScene()
        # Embree wants (F, 3, 3) float32 triangles; keep a reference alive.
        self._triangles = np.ascontiguousarray(np.asarray(vertices, dtype=np.float64)[faces], dtype=np.float32)
        TriangleMesh(self._scene, self._triangles)
        # Commit the BVH now, on this thread: embreex commits on the first query without a lock.
        self._scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32), query="DISTANCE")

    def distances(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        return self._distances(*_as_rays(origins, directions))

    def rig_distances(self, rig) -> np.ndarray:
        return self._distances(*rig.rays32)  # already C-contiguous float32 (K, 3): no check, no copy

    def _distances(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        n = len(o)
        out = np.empty(n, dtype=np.float32)
        out.fill(np.inf)  # Embree keeps tfar (the initial value) on a miss
        run = self._scene.run
        if self.threads > 1 and n >= SPLIT_MIN_RAYS:

            def cast(a, b):
                run(o[a:b], d[a:b], dists=out[a:b], query="DISTANCE")

            run_split(n, self.threads, cast)
        elif n:
            run(o, d, dists=out, query="DISTANCE")
        return out

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o, d = _as_rays(origins, directions)
        n = len(o)
        t = np.full(n, np.inf)
        face = np.full(n, -1, dtype=np.int64)
        run = self._scene.run

        def cast(a, b):
            for s in range(a, b, _CALL_RAYS):
                e = min(b, s + _CALL_RAYS)
                res = run(o[s:e], d[s:e], dists=np.full(e - s, np.inf, np.float32), output=1)
                hit = (res["geomID"] >= 0) & np.isfinite(res["tfar"])
                t[s:e][hit] = res["tfar"][hit]
                face[s:e][hit] = res["primID"][hit]

        if self.threads > 1 and n >= SPLIT_MIN_RAYS:
            run_split(n, self.threads, cast)
        elif n:
            cast(0, n)
        return t, face


class Open3DEngine(RayEngine):
    """Open3D's ``RaycastingScene`` (optional ``open3d`` package): Embree on Open3D's TBB
    threads; ``threads`` is its thread count (0 or at least the number of cores: its default pool)."""

    name = "open3d"

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int = 1):
        super().__init__(vertices, faces, threads)
        try:
            import open3d as o3d
        except ImportError:
            raise ParameterError("the ray engine 'open3d' needs the open3d package (pip install open3d)") from None
        self._o3d = o3d
        self._nthreads = 0 if self.threads >= (os.cpu_count() or 1) else self.threads
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)),
        )
        self._rig_rays: tuple | None = None  # (rig, (K, 6) float32): the last rig's rays, kept

    def _cast(self, rays: np.ndarray) -> dict:
        return self._scene.cast_rays(self._o3d.core.Tensor.from_numpy(rays), nthreads=self._nthreads)

    @staticmethod
    def _rays(origins, directions) -> np.ndarray:
        o, d = _as_rays(origins, directions)
        rays = np.empty((len(o), 6), dtype=np.float32)
        rays[:, :3], rays[:, 3:] = o, d
        return rays

    def distances(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        return self._cast(self._rays(origins, directions))["t_hit"].numpy()  # inf on a miss

    def rig_distances(self, rig) -> np.ndarray:
        cached = self._rig_rays
        if cached is None or cached[0] is not rig:
            cached = self._rig_rays = (rig, self._rays(*rig.rays32))
        return self._cast(cached[1])["t_hit"].numpy()

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ans = self._cast(self._rays(origins, directions))
        t = ans["t_hit"].numpy().astype(np.float64)
        hit = np.isfinite(t)
        face = np.where(hit, ans["primitive_ids"].numpy().astype(np.int64), -1)
        return t, face


class TrimeshEngine(RayEngine):
    """trimesh's pure-numpy engine: the slow fallback where embreex is missing (one thread)."""

    name = "trimesh"

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int = 1):
        super().__init__(vertices, faces, threads)
        import trimesh
        from trimesh.ray.ray_triangle import RayMeshIntersector

        self._intersector = RayMeshIntersector(trimesh.Trimesh(vertices, faces, process=False))

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        o, d = _as_rays(origins, directions)
        o, d = o.astype(np.float64), d.astype(np.float64)
        t = np.full(len(o), np.inf)
        face = np.full(len(o), -1, dtype=np.int64)
        if len(o):
            tri, ray, loc = self._intersector.intersects_id(o, d, multiple_hits=False, return_locations=True)
            if len(ray):
                t[ray] = np.einsum("ij,ij->i", loc - o[ray], d[ray])
                face[ray] = tri
        return t, face

    def distances(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        return self.first_hit(origins, directions)[0].astype(np.float32)


ENGINES: dict[str, type[RayEngine]] = {"embree": EmbreeEngine, "open3d": Open3DEngine, "trimesh": TrimeshEngine}
"""Ray engines by name; another engine is one :class:`RayEngine` subclass added here."""


class RayCaster:
    """A BVH over one triangle mesh, answering first-hit queries with one of the :data:`ENGINES`.

    Parameters
    ----------
    vertices : (V, 3) float array.
    faces : (F, 3) int array of vertex indices.
    engine : ``"embree"`` (default when available), ``"open3d"`` (optional) or ``"trimesh"``
        (slow fallback); see the module docstring. Engines agree to float32 rounding.
    workers : threads for one query (default 1). Embree: queries of at least
        :data:`SPLIT_MIN_RAYS` rays are shared by ``workers`` threads over the one scene, with
        the same bytes as ``workers=1``. Open3D: its thread count. trimesh: ignored.

    The BVH is built once; query it as often as needed, from any thread. ``close()`` and
    ``with`` are accepted (nothing to release: the threads belong to a process-wide pool).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, engine: str | None = None, workers: int = 1):
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise ParameterError(f"expected vertices (V, 3) and faces (F>0, 3), got {v.shape} and {f.shape}")
        if f.min() < 0 or f.max() >= len(v):
            raise ParameterError("face indices out of range")
        if int(workers) < 1:
            raise ParameterError(f"workers must be >= 1, got {workers}")
        if engine is None:
            engine = "embree" if embree_available() else "trimesh"
            if engine == "trimesh":  # pragma: no cover - platform dependent
                warnings.warn("embreex is not installed: using trimesh's slow ray engine", RuntimeWarning, stacklevel=2)
        if engine not in ENGINES:
            raise ParameterError(f"unknown ray engine {engine!r} (known: {', '.join(ENGINES)})")
        self.engine: RayEngine = ENGINES[engine](v, f, threads=int(workers))
        self.workers = self.engine.threads
        self.n_faces = len(f)

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First intersection of each ray with the mesh.

        Parameters
        ----------
        origins : (K, 3) float ray origins.
        directions : (K, 3) float unit directions (same frame as the mesh).

        Returns
        -------
        t : (K,) float64 distance along the ray to the first hit (``inf`` on a miss).
        face : (K,) int64 index of the hit triangle (``-1`` on a miss).
        """
        return self.engine.first_hit(origins, directions)

    def distances(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """First-hit distance only (the fast path).

        Parameters
        ----------
        origins, directions : (K, 3) arrays; float32 C-contiguous input avoids a copy.

        Returns
        -------
        (K,) float32 distances, ``inf`` on a miss.
        """
        return self.engine.distances(origins, directions)

    def rig_distances(self, rig) -> np.ndarray:
        """:meth:`distances` for all rays of a :class:`~spotlights.geometry.rig.Rig`:
        (N*M,) float32 unit-frame distances, ``inf`` on a miss."""
        return self.engine.rig_distances(rig)

    def rig_depths(self, rig) -> np.ndarray:
        """Spotlights depths of a rig: (N*M,) float32 in [0, 1], 0 = miss or hit beyond the chord.

        :meth:`rig_distances` followed by :func:`to_depths`.
        """
        return to_depths(self.engine.rig_distances(rig), rig.half_chords32)

    def close(self) -> None:
        """Nothing to release (kept so ``with RayCaster(...)`` and older code keep working)."""

    def __enter__(self) -> RayCaster:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def first_hit(mesh, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Convenience: build a :class:`RayCaster` for ``mesh`` (``vertices``/``faces``) and query it once."""
    return RayCaster(mesh.vertices, mesh.faces).first_hit(origins, directions)
