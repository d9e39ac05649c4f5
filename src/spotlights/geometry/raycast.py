"""First-hit ray casting on triangle meshes, behind one small wrapper.

The engine is Intel Embree (through ``embreex``): a BVH built once per mesh,
then all rays of a job in one call. Triangles are hit whatever their winding
(real meshes are not watertight and not consistently oriented). Without
embreex (an unsupported platform), trimesh's pure-numpy engine is used with a
warning; it is ~100x slower. Another engine is one class with ``first_hit``.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..errors import ParameterError

# Embree works in float32; a ray whose t exceeds this is a miss.
_MISS_T = 1e30
# Rays per engine call: bounds the temporary memory of huge jobs (~0.2 GB at 4M rays).
_CHUNK = 1 << 22
# Below this many rays a query is not split over processes (the hand-over costs more).
PARALLEL_MIN_RAYS = 16384
# Casters handed to forked worker processes, by key (children inherit the BVH by fork).
_FORKED: dict = {}


def _worker_loop(conn, key) -> None:
    """A forked helper process: answers ray queries on the parent's BVH until told to stop.

    Jobs: ``("rays", o32, d32)`` or ``("rig", rig_json, start, stop)`` (the rig's rays are
    rebuilt once per rig, so only slice bounds and results cross the pipe); ``None`` stops.
    """
    import json

    from .rig import Rig

    caster, rigs = _FORKED[key], {}
    while True:
        try:
            job = conn.recv()
        except EOFError:
            return
        if job is None:
            return
        if job[0] == "rig":
            _, rig_json, start, stop = job
            if rig_json not in rigs:
                rigs[rig_json] = Rig.from_dict(json.loads(rig_json))
            o32, d32 = rigs[rig_json].rays32
            conn.send(caster._run(o32[start:stop], d32[start:stop]))
        else:
            conn.send(caster._run(job[1], job[2]))


def _stop_workers(conns, procs) -> None:
    for c in conns:
        try:
            c.send(None)
        except (OSError, ValueError):
            pass
    for p in procs:
        p.join(timeout=1)
        if p.is_alive():
            p.terminate()


def _embree_available() -> bool:
    try:
        import embreex.mesh_construction  # noqa: F401
        import embreex.rtcore_scene  # noqa: F401
    except Exception:  # pragma: no cover - platform dependent
        return False
    return True


class RayCaster:
    """A BVH over one triangle mesh, answering first-hit queries.

    Parameters
    ----------
    vertices : (V, 3) float array.
    faces : (F, 3) int array of vertex indices.
    engine : ``"embree"`` (default when available) or ``"trimesh"``.
    workers : processes for one query (default 1). ``embreex`` holds the GIL, so a query
        of at least :data:`PARALLEL_MIN_RAYS` rays is split over ``workers`` processes
        forked once (lazily) with the BVH; results are identical to ``workers=1``.
        Needs the ``fork`` start method (Linux); elsewhere queries stay in-process.

    The BVH is built once; query it as often as needed.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, engine: str | None = None, workers: int = 1):
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise ParameterError(f"expected vertices (V, 3) and faces (F>0, 3), got {v.shape} and {f.shape}")
        if f.min() < 0 or f.max() >= len(v):
            raise ParameterError("face indices out of range")
        if engine is None:
            engine = "embree" if _embree_available() else "trimesh"
            if engine == "trimesh":  # pragma: no cover - platform dependent
                warnings.warn("embreex is not installed: using trimesh's slow ray engine", RuntimeWarning, stacklevel=2)
        self.engine = engine
        self.n_faces = len(f)
        self.workers = max(1, int(workers))
        self._conns = None
        if engine == "embree":
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh

            self._scene = rtcore_scene.EmbreeScene()
            # Embree wants (F, 3, 3) float32 triangles; keep a reference alive.
            self._triangles = np.ascontiguousarray(v[f], dtype=np.float32)
            TriangleMesh(self._scene, self._triangles)
        elif engine == "trimesh":
            import trimesh
            from trimesh.ray.ray_triangle import RayMeshIntersector

            self._intersector = RayMeshIntersector(trimesh.Trimesh(v, f, process=False))
        else:
            raise ParameterError(f"unknown ray engine {engine!r} (known: embree, trimesh)")

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
        o = np.asarray(origins)
        d = np.asarray(directions)
        if o.shape != d.shape or o.ndim != 2 or o.shape[1] != 3:
            raise ParameterError(f"origins and directions must both be (K, 3), got {o.shape} and {d.shape}")
        k = len(o)
        t = np.full(k, np.inf)
        face = np.full(k, -1, dtype=np.int64)
        if k == 0:
            return t, face
        if self.engine == "embree":
            o32 = np.ascontiguousarray(o, dtype=np.float32)
            d32 = np.ascontiguousarray(d, dtype=np.float32)
            for s in range(0, k, _CHUNK):
                res = self._scene.run(o32[s : s + _CHUNK], d32[s : s + _CHUNK], output=1)
                prim = res["primID"].astype(np.int64)
                hit = (res["geomID"] >= 0) & (res["tfar"] < _MISS_T)
                t[s : s + _CHUNK][hit] = res["tfar"][hit]
                face[s : s + _CHUNK][hit] = prim[hit]
        else:
            tri, ray, loc = self._intersector.intersects_id(o, d, multiple_hits=False, return_locations=True)
            if len(ray):
                t[ray] = np.einsum("ij,ij->i", loc - o[ray], d[ray])
                face[ray] = tri
        return t, face

    def distances(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """First-hit distance only (the fast path used by encoding).

        Parameters
        ----------
        origins, directions : (K, 3) arrays; float32 C-contiguous input avoids a copy.

        Returns
        -------
        (K,) float32 distances, ``inf`` on a miss.
        """
        t = self.raw_distances(origins, directions)
        t[t >= _MISS_T] = np.inf
        return t

    def raw_distances(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Like :meth:`distances` but a miss is any value >= 1e30 (no clean-up pass)."""
        if self.engine != "embree":
            t = self.first_hit(origins, directions)[0].astype(np.float32)
            t[~np.isfinite(t)] = 1e37
            return t
        o32 = np.ascontiguousarray(origins, dtype=np.float32)
        d32 = np.ascontiguousarray(directions, dtype=np.float32)
        if o32.shape != d32.shape or o32.ndim != 2 or o32.shape[1] != 3:
            raise ParameterError(f"origins and directions must both be (K, 3), got {o32.shape} and {d32.shape}")
        if self.workers > 1 and len(o32) >= PARALLEL_MIN_RAYS and self._ensure_pool():
            bounds = np.linspace(0, len(o32), self.workers + 1).astype(np.int64)
            for conn, a, b in zip(self._conns, bounds[1:-1], bounds[2:]):
                conn.send(("rays", o32[a:b], d32[a:b]))  # sent now, from this thread: no GIL wait
            first = self._run(o32[: bounds[1]], d32[: bounds[1]])  # the parent takes the first share
            return np.concatenate([first, *(conn.recv() for conn in self._conns)])
        return self._run(o32, d32)

    def rig_distances(self, rig) -> np.ndarray:
        """:meth:`raw_distances` for all rays of a :class:`~spotlights.geometry.rig.Rig`.

        With ``workers > 1`` and a big rig, each worker process rebuilds the rig's rays
        once (from ``rig.to_dict()``) and only slice bounds and results cross processes,
        so the split costs little. Returns (N*M,) float32, >= 1e30 on a miss.
        """
        o32, d32 = rig.rays32
        if self.engine != "embree" or self.workers == 1 or len(o32) < PARALLEL_MIN_RAYS or not self._ensure_pool():
            return self.raw_distances(o32, d32)
        import json

        rig_json = json.dumps(rig.to_dict(), sort_keys=True)
        bounds = np.linspace(0, len(o32), self.workers + 1).astype(np.int64)
        for conn, a, b in zip(self._conns, bounds[1:-1], bounds[2:]):
            conn.send(("rig", rig_json, int(a), int(b)))
        first = self._run(o32[: bounds[1]], d32[: bounds[1]])
        return np.concatenate([first, *(conn.recv() for conn in self._conns)])

    def _run(self, o32: np.ndarray, d32: np.ndarray) -> np.ndarray:
        parts = [self._scene.run(o32[s : s + _CHUNK], d32[s : s + _CHUNK], query="DISTANCE")
                 for s in range(0, len(o32), _CHUNK)]
        return np.concatenate(parts) if len(parts) != 1 else parts[0]

    def _ensure_pool(self) -> bool:
        """Fork ``workers - 1`` helper processes holding this BVH (once); False where fork is unavailable."""
        if self._conns is not None:
            return True
        import multiprocessing as mp
        import weakref

        if "fork" not in mp.get_all_start_methods():  # pragma: no cover - not Linux
            self.workers = 1
            return False
        ctx = mp.get_context("fork")
        conns, procs = [], []
        _FORKED[id(self)] = self
        try:
            for _ in range(self.workers - 1):
                parent, child = ctx.Pipe()
                proc = ctx.Process(target=_worker_loop, args=(child, id(self)), daemon=True)
                proc.start()
                child.close()
                conns.append(parent)
                procs.append(proc)
        finally:
            del _FORKED[id(self)]  # the children have their copy; the parent must not keep self alive
        self._conns = conns
        weakref.finalize(self, _stop_workers, conns, procs)
        return True


def first_hit(mesh, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Convenience: build a :class:`RayCaster` for ``mesh`` (``vertices``/``faces``) and query it once."""
    return RayCaster(mesh.vertices, mesh.faces).first_hit(origins, directions)
