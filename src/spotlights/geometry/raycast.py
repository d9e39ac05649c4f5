"""First-hit ray casting on triangle meshes, behind one small wrapper.

The engine is Intel Embree (through ``embreex``): a BVH built once per mesh,
then all rays of a job in one call. Triangles are hit whatever their winding
(real meshes are not watertight and not consistently oriented). Without
embreex (an unsupported platform), trimesh's pure-numpy engine is used with a
warning; it is ~100x slower. Open3D's ``RaycastingScene`` is an optional engine
(``engine="open3d"``, when ``open3d`` is installed). Another engine is one class with
``first_hit``.

Both cores for one query (``workers=2``)
----------------------------------------
``embreex`` holds the GIL for a whole query, so threads cannot share one. With
``workers > 1`` a :class:`RayCaster` forks ``workers - 1`` helper processes once,
lazily, on the first query of at least :data:`PARALLEL_MIN_RAYS` rays; they
inherit the committed BVH. Each query is one *job* in an anonymous shared
memory map (``mmap``, no named segment: nothing can leak past the processes):
the rays are cut into contiguous segments, one per process, and each segment
into chunks whose sizes halve from its front. Every process takes its own
segment's chunks from the front, then steals its neighbour's chunks from the
back, so both finish together even when one starts late or runs slower. A
chunk's claim is published before it is cast; two processes can at worst cast
the same chunk twice, which writes the same bytes (each result is written once,
as a plain copy of finished values). Rig rays are never copied: a helper rebuilds
a rig's rays once from ``Rig.to_dict()`` and checks them against a CRC. Helpers
poll for the next job for :data:`HELPER_SPIN_S` after each job (yielding the core),
then sleep on a pipe. The parent never waits for a helper that took no part in a job, and
casts itself the chunks a preempted helper claimed but did not finish in time. The
depths are the same bytes whatever ``workers`` (Embree's single-ray query is
deterministic and every element is computed by the same code).

Robustness: helpers ignore SIGINT and exit when the parent closes the caster,
is garbage collected, exits, or dies (checked every second); a process forked
later (a DataLoader worker, a pool worker) never touches the helpers it
inherits and starts its own if it needs them; any failure (fork refused, a
helper dying or timing out) falls back to one process with a warning, with
the same results. Needs Linux on x86-64 (``fork`` and total store order);
elsewhere ``workers`` is ignored.
"""

from __future__ import annotations

import functools
import json
import mmap
import os
import platform
import select
import signal
import sys
import threading
import time
import warnings
import weakref
import zlib

import numpy as np

from ..errors import ParameterError

# Embree works in float32; a ray whose t exceeds this is a miss.
_MISS_T = 1e30
# Rays per engine call: bounds the temporary memory of huge jobs (~0.2 GB at 4M rays).
_CHUNK = 1 << 22
# Below this many rays a query is not shared with helpers: at 2,048 rays (~0.15 ms) the
# hand-over eats the gain (measured: 0.9-1.0x warm in blocks, 1.3-1.5x in long loops, worse cold).
PARALLEL_MIN_RAYS = 4096
# A helper keeps polling for the next job this long (s) after a job, then sleeps on a pipe.
HELPER_SPIN_S = 0.002
# Smallest chunk of a job (rays): ~12 us of work, ~3 us of Python overhead.
_MIN_CHUNK = 128
# Rays per shared-memory job (bigger queries are cut into several jobs).
_WINDOW = 1 << 18
# The parent waits at least this long (s; or half its own share of the job) for chunks a
# helper has claimed before casting them itself: long enough never to duplicate a healthy
# helper's last chunk (which would leave it a job behind, and again at the next job).
_GRACE_S = 3e-4
# Seconds the parent waits for a helper's chunk before killing it and going on alone.
_HELPER_TIMEOUT_S = 20.0
_MAX_PROCS = 8

# Shared memory layout: a header page, then _SLOTS job slots used in turn (a late
# helper may still be finishing job s in one slot while the parent fills job s+1).
_PAGE = 4096
_SLOTS = 4
_JSON_BYTES = 1 << 16
_SLOT_BYTES = _PAGE + _JSON_BYTES + _WINDOW * 28  # ctrl, rig JSON, origins, directions, out
# header (int64 index): job sequence number, stop flag; per process p (8 int64 apart,
# separate cache lines): done (last finished job), error (job that failed), sleeping flag,
# busy (the job it committed to)
_SEQ, _STOP, _DONE, _ERR, _SLEEP, _BUSY = 0, 1, 64, 128, 192, 256
# slot ctrl (int64 index): kind (1 rays in the slot, 2 a rig), rays, rig token, rig JSON
# length, ray offset in the rig, processes, rig CRC; per segment: chunks claimed by its
# owner (front) and its thief (back), chunks they finished (front done, back done)
_KIND, _N, _TOKEN, _JLEN, _OFF, _NPROC, _CRC = 0, 1, 2, 3, 4, 5, 6
_FRONT, _BACK, _FDONE, _BDONE = 64, 128, 192, 256


def _embree_available() -> bool:
    try:
        import embreex.mesh_construction  # noqa: F401
        import embreex.rtcore_scene  # noqa: F401
    except Exception:  # pragma: no cover - platform dependent
        return False
    return True


# Helpers yield the core while polling (free on an idle core; on a shared one it keeps a
# polling helper from starving the parent). A switch for experiments.
_YIELD = True
_FENCE = threading.Lock()


def _fence() -> None:
    """A full memory barrier (a lock's atomic read-modify-write), for the two flag handshakes
    (sleeping/new job, committed/slot reuse) where x86 could reorder a store after a load."""
    _FENCE.acquire()
    _FENCE.release()


def _helpers_supported() -> bool:
    return (sys.platform.startswith("linux") and hasattr(os, "fork")
            and platform.machine().lower() in ("x86_64", "amd64"))


def to_depths(t: np.ndarray, half_chords: np.ndarray, fresh: bool = False) -> np.ndarray:
    """Raw first-hit distances -> Spotlights depths, in place (a new array with ``fresh``).

    ``t`` (K,) float32 unit-frame distances (>= 1e30 on a miss, never negative or NaN);
    ``half_chords`` (K,) float32 largest valid depth per ray. Result: ``min(t / 2, 1)``, and
    exactly 0 for a miss or a hit beyond the ray's chord through the unit sphere.
    """
    t = np.multiply(t, np.float32(0.5), out=None if fresh else t)
    valid = t <= half_chords
    np.minimum(t, np.float32(1.0), out=t)
    return np.multiply(t, valid, out=t)  # x * 1 = x exactly; a miss (finite) * 0 = +0


@functools.lru_cache(maxsize=64)
def _plan(n: int, procs: int) -> tuple:
    """Chunk boundaries of a job of ``n`` rays over ``procs`` processes.

    One contiguous segment per process; within a segment, chunk sizes halve from the
    front (the owner's big first bites) down to ``_MIN_CHUNK`` (the thief's small ones
    at the back, where the two meet). Returns a tuple of tuples of offsets.
    """
    edges = [n * s // procs for s in range(procs + 1)]
    plan = []
    for a, b in zip(edges[:-1], edges[1:]):
        bounds = [a]
        while bounds[-1] < b:
            rest = b - bounds[-1]
            bounds.append(bounds[-1] + min(rest, max(rest // 2, _MIN_CHUNK)))
        plan.append(tuple(bounds))
    return tuple(plan)


def _share(p: int, procs: int, plan: tuple, ctrl: np.ndarray, cast) -> bool:
    """Process ``p``'s part of a job: own segment from the front, then steal the next
    segment's chunks from the back. ``cast(a, b)`` computes and stores rays [a, b).

    Claims are published (``ctrl[_FRONT + 8 s]``, ``ctrl[_BACK + 8 s]``) before the chunk
    is cast, and counted done after; a process stops at the first chunk the other has
    claimed. Returns True when this process cast every chunk of both segments (the other
    one took none).
    """
    own = plan[p]
    m = len(own) - 1
    back = _BACK + 8 * p
    i = 0
    while i < m - ctrl[back]:
        ctrl[_FRONT + 8 * p] = i + 1
        cast(own[i], own[i + 1])
        i += 1
        ctrl[_FDONE + 8 * p] = i
    q = (p + 1) % procs
    other = plan[q]
    m2 = len(other) - 1
    front = _FRONT + 8 * q
    k = 0
    while m2 - 1 - k >= ctrl[front]:
        ctrl[_BACK + 8 * q] = k + 1
        j = m2 - 1 - k
        cast(other[j], other[j + 1])
        k += 1
        ctrl[_BDONE + 8 * q] = k
    return procs == 2 and i == m and k == m2


def _ints(mm: mmap.mmap, base: int) -> memoryview:
    """The int64 words of one page of the map (a memoryview: item access is plain Python ints,
    several times faster than numpy scalars; aligned 8-byte stores are single moves)."""
    return memoryview(mm)[base:base + _PAGE].cast("q")


class _Slot:
    """Views of one job slot of the shared map."""

    def __init__(self, mm: mmap.mmap, base: int):
        self.ctrl = _ints(mm, base)
        self.json = np.frombuffer(mm, dtype=np.uint8, count=_JSON_BYTES, offset=base + _PAGE)
        off = base + _PAGE + _JSON_BYTES
        self.origins = np.frombuffer(mm, dtype=np.float32, count=3 * _WINDOW, offset=off).reshape(-1, 3)
        self.directions = np.frombuffer(mm, dtype=np.float32, count=3 * _WINDOW,
                                        offset=off + 12 * _WINDOW).reshape(-1, 3)
        self.out = np.frombuffer(mm, dtype=np.float32, count=_WINDOW, offset=off + 24 * _WINDOW)


def _helper_main(scene, mm: mmap.mmap, p: int, wake_fd: int, parent: int) -> None:
    """Body of helper process ``p``: wait for a job, take its share, report, repeat."""
    head = _ints(mm, 0)
    slots = [_Slot(mm, _PAGE + i * _SLOT_BYTES) for i in range(_SLOTS)]
    rigs: dict = {}  # token -> (origins32, directions32) or None (unusable)
    last = 0  # helpers are forked before the first job (the parent may post it before we look)
    spin_until = time.monotonic() + HELPER_SPIN_S
    while True:
        # wait for a new job: poll a while after the last one, then sleep. Polling yields the
        # core (free on an idle core): should the parent share it, the parent must not starve
        while head[_SEQ] == last and not head[_STOP]:
            if time.monotonic() < spin_until:
                if _YIELD:
                    os.sched_yield()
                continue
            head[_SLEEP + 8 * p] = 1
            _fence()  # the parent reads our flag after publishing a job: one of us sees the other
            if head[_SEQ] == last and not head[_STOP]:
                ready, _, _ = select.select([wake_fd], [], [], 1.0)
                if ready:
                    if not os.read(wake_fd, 4096):
                        return  # the parent closed its end
                elif os.getppid() != parent:
                    return  # the parent died
            head[_SLEEP + 8 * p] = 0
        if head[_STOP]:
            return
        # commit to the newest job; the parent reuses its slot only once we are done with it
        while True:
            seq = int(head[_SEQ])
            head[_BUSY + 8 * p] = seq
            _fence()
            if head[_SEQ] == seq:
                break
        slot = slots[seq % _SLOTS]
        ctrl = slot.ctrl
        try:
            n, procs, off = int(ctrl[_N]), int(ctrl[_NPROC]), int(ctrl[_OFF])
            if ctrl[_KIND] == 2:
                token = int(ctrl[_TOKEN])
                if token not in rigs:
                    rigs[token] = _rebuild_rig(bytes(slot.json[: int(ctrl[_JLEN])]), int(ctrl[_CRC]))
                    if len(rigs) > 8:
                        del rigs[next(iter(rigs))]
                rays = rigs[token]
                if rays is not None:
                    o, d = rays[0][off:off + n], rays[1][off:off + n]
            else:
                rays = True
                o, d = slot.origins[:n], slot.directions[:n]
            if rays is not None and p < procs:
                out = slot.out

                def cast(a, b):
                    out[a:b] = scene.run(o[a:b], d[a:b], query="DISTANCE")

                _share(p, procs, _plan(n, procs), ctrl, cast)
        except Exception:
            head[_ERR + 8 * p] = seq
        head[_DONE + 8 * p] = seq
        last = seq
        spin_until = time.monotonic() + HELPER_SPIN_S


def _rebuild_rig(rig_json: bytes, crc: int):
    """A helper's copy of a rig's float32 rays, or None when they do not match the parent's."""
    from .rig import Rig

    try:
        rig = Rig.from_dict(json.loads(rig_json.decode()))
        o, d = rig.rays32
        if _rays_crc(o, d) != crc:
            return None
        return o, d
    except Exception:
        return None


def _rays_crc(o: np.ndarray, d: np.ndarray) -> int:
    return zlib.crc32(d.tobytes(), zlib.crc32(o.tobytes()))


def _shutdown(owner: int, pids: list, fds: list, head: np.ndarray) -> None:
    """Stop and reap the helpers (only from the process that forked them)."""
    if os.getpid() != owner:
        for fd in fds:  # a forked copy: close our copies of the pipes, leave the helpers alone
            try:
                os.close(fd)
            except OSError:
                pass
        return
    try:
        head[_STOP] = 1
    except Exception:  # pragma: no cover - map already gone
        pass
    for fd in fds:
        try:
            os.write(fd, b"\0")
        except OSError:
            pass
        try:
            os.close(fd)
        except OSError:
            pass
    deadline = time.monotonic() + 1.0
    for pid in pids:
        while True:
            try:
                done, _ = os.waitpid(pid, os.WNOHANG)
            except ChildProcessError:
                break
            if done:
                break
            if time.monotonic() > deadline:
                try:
                    os.kill(pid, signal.SIGKILL)
                    os.waitpid(pid, 0)
                except (ProcessLookupError, ChildProcessError):
                    pass
                break
            time.sleep(0.001)


class _HelperFailed(RuntimeError):
    pass


class _Helpers:
    """``procs - 1`` forked helper processes sharing one committed Embree scene."""

    def __init__(self, scene, procs: int):
        self.procs = procs
        self.owner = os.getpid()
        self.mm = mmap.mmap(-1, _PAGE + _SLOTS * _SLOT_BYTES)  # MAP_SHARED | MAP_ANONYMOUS
        self.head = _ints(self.mm, 0)
        self.slots = [_Slot(self.mm, _PAGE + i * _SLOT_BYTES) for i in range(_SLOTS)]
        self.seq = 0
        self.pids: list = []
        self.fds: list = []
        self.tokens: dict = {}  # rig -> (token, json bytes, crc); tokens are never reused
        self._last_token = 0
        self._last_rig = self._last_entry = None
        self._finalizer = weakref.finalize(self, _shutdown, self.owner, self.pids, self.fds, self.head)
        for p in range(1, procs):
            r, w = os.pipe()
            pid = os.fork()
            if pid == 0:  # the helper: never returns into the caller's stack
                code = 0
                try:
                    signal.signal(signal.SIGINT, signal.SIG_IGN)
                    os.close(w)
                    for fd in self.fds:
                        os.close(fd)
                    _helper_main(scene, self.mm, p, r, self.owner)
                except BaseException:
                    code = 1
                finally:
                    os._exit(code)
            os.close(r)
            os.set_blocking(w, False)
            self.pids.append(pid)
            self.fds.append(w)

    def close(self) -> None:
        self._finalizer()

    def token(self, rig) -> tuple:
        if rig is self._last_rig:
            return self._last_entry
        entry = self.tokens.get(rig)
        if entry is None:
            o, d = rig.rays32
            js = json.dumps(rig.to_dict(), sort_keys=True).encode()
            if len(js) > _JSON_BYTES:
                raise _HelperFailed("rig description too long for the shared map")
            self._last_token += 1
            entry = (self._last_token, js, _rays_crc(o, d))
            self.tokens[rig] = entry
            if len(self.tokens) > 8:
                del self.tokens[next(iter(self.tokens))]
        self._last_rig, self._last_entry = rig, entry
        return entry

    def run(self, scene, n: int, o: np.ndarray, d: np.ndarray, rig_entry, off: int, post=None) -> np.ndarray:
        """One job of ``n <= _WINDOW`` rays ``o``, ``d`` (rays ``off:off + n`` of a rig when
        ``rig_entry``): (n,) float32 raw distances, or depths (:func:`to_depths`) when
        ``post`` (the half chords) is given; a fresh array."""
        seq = self.seq + 1
        head = self.head
        if self.procs == 2:  # the slot's previous job: wait only for a helper committed to it
            p = 1
            if head[_BUSY + 8 * p] == seq - _SLOTS and head[_DONE + 8 * p] < seq - _SLOTS:
                self._wait(seq - _SLOTS)
        slot = self.slots[seq % _SLOTS]
        ctrl = slot.ctrl
        for q in range(self.procs):
            ctrl[_FRONT + 8 * q] = ctrl[_BACK + 8 * q] = ctrl[_FDONE + 8 * q] = ctrl[_BDONE + 8 * q] = 0
        ctrl[_N], ctrl[_NPROC], ctrl[_OFF] = n, self.procs, off
        if rig_entry is not None:
            token, js, crc = rig_entry
            ctrl[_KIND], ctrl[_TOKEN], ctrl[_JLEN], ctrl[_CRC] = 2, token, len(js), crc
            slot.json[: len(js)] = np.frombuffer(js, dtype=np.uint8)
        else:
            ctrl[_KIND] = 1
            slot.origins[:n] = o
            slot.directions[:n] = d
        out = slot.out

        def cast(a, b):
            out[a:b] = scene.run(o[a:b], d[a:b], query="DISTANCE")

        head[_SEQ] = seq  # published last: the job is complete in memory (x86 store order)
        self.seq = seq
        _fence()
        for p, fd in enumerate(self.fds, start=1):
            if head[_SLEEP + 8 * p]:
                try:
                    os.write(fd, b"\0")
                except BlockingIOError:
                    pass  # the pipe is full of wake-ups already
                except OSError as exc:
                    raise _HelperFailed(f"helper process {self.pids[p - 1]} is gone ({exc})") from None
        plan = _plan(n, self.procs)
        t0 = time.perf_counter()
        alone = _share(0, self.procs, plan, ctrl, cast)
        if alone:  # the helper took no part: is it still there?
            self._check_alive()
        else:
            if self.procs == 2:
                self._finish(seq, plan, ctrl, cast, max(_GRACE_S, 0.5 * (time.perf_counter() - t0)))
            else:
                self._wait(seq)
            if any(head[_ERR + 8 * p] == seq for p in range(1, self.procs)):
                raise _HelperFailed("a helper process failed on a job")
        return out[:n].copy() if post is None else to_depths(out[:n], post, fresh=True)

    def _finish(self, seq: int, plan: tuple, ctrl, cast, grace: float) -> None:
        """Wait up to ``grace`` s for the helper's chunks of job ``seq``, then cast what it has
        claimed but not finished (a preempted helper must not hold the caller up; a chunk
        cast twice gives the same bytes, and the slot is not reused while it is busy)."""
        head = self.head
        done = _DONE + 8
        deadline = time.perf_counter() + grace
        while head[done] < seq:
            if time.perf_counter() > deadline:
                break
            os.sched_yield()
        else:
            return
        seg = plan[1]  # the helper's own segment, from the front
        for i in range(ctrl[_FDONE + 8], ctrl[_FRONT + 8]):
            if head[done] >= seq:
                return
            cast(seg[i], seg[i + 1])
        seg = plan[0]  # the chunks it stole from the parent's segment, from the back
        m = len(seg) - 1
        for k in range(ctrl[_BDONE], ctrl[_BACK]):
            if head[done] >= seq:
                return
            cast(seg[m - 1 - k], seg[m - k])
        self._check_alive()

    def _check_alive(self) -> None:
        for pid in self.pids:
            try:
                if os.waitpid(pid, os.WNOHANG)[0]:
                    raise _HelperFailed(f"helper process {pid} died")
            except ChildProcessError:
                raise _HelperFailed(f"helper process {pid} is gone") from None

    def _wait(self, seq: int) -> None:
        """Until every helper has finished job ``seq``; raises _HelperFailed if one died or hangs."""
        head = self.head
        idx = [_DONE + 8 * p for p in range(1, self.procs)]
        if all(head[i] >= seq for i in idx):
            return
        t0 = time.monotonic()
        check = t0 + 0.005
        while not all(head[i] >= seq for i in idx):
            os.sched_yield()  # a helper preempted on this core gets it back
            now = time.monotonic()
            if now > check:
                check = now + 0.005
                self._check_alive()
                for p, fd in enumerate(self.fds, start=1):
                    if head[_SLEEP + 8 * p]:  # a wake-up lost in a race: send another
                        try:
                            os.write(fd, b"\0")
                        except OSError:
                            pass
                if now - t0 > _HELPER_TIMEOUT_S:
                    raise _HelperFailed(f"helper processes did not answer within {_HELPER_TIMEOUT_S:.0f} s")


class RayCaster:
    """A BVH over one triangle mesh, answering first-hit queries.

    Parameters
    ----------
    vertices : (V, 3) float array.
    faces : (F, 3) int array of vertex indices.
    engine : ``"embree"`` (default when available; ``embreex``), ``"open3d"`` (optional:
        Open3D's ``RaycastingScene``, Embree on TBB threads, when ``open3d`` is installed;
        ``workers`` is its thread count, ``workers >= cores`` its default pool) or
        ``"trimesh"`` (slow fallback). Engines agree to float32 rounding, not bit for bit.
    workers : processes for one query (default 1: everything in this process). With
        ``workers > 1``, queries of at least :data:`PARALLEL_MIN_RAYS` rays are shared
        with ``workers - 1`` helper processes forked lazily with the BVH (see the module
        docstring); results are the same bytes as with ``workers=1``. Linux/x86-64 only,
        ignored elsewhere. Call :meth:`close` (or use ``with``) to stop the helpers early;
        they also stop when the caster is garbage collected or the process exits.

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
        self.workers = min(max(1, int(workers)), _MAX_PROCS)
        self._helpers: _Helpers | None = None
        self._helpers_failed = False
        self._lock = threading.Lock()
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
        elif engine == "open3d":
            try:
                import open3d as o3d
            except ImportError:
                raise ParameterError("the ray engine 'open3d' needs the open3d package (pip install open3d)") from None
            self._o3d = o3d
            self._o3d_rig = None
            self._o3d_threads = 0 if self.workers >= (os.cpu_count() or 1) else self.workers
            self._o3d_scene = o3d.t.geometry.RaycastingScene()
            self._o3d_scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(v, dtype=np.float32)),
                                          o3d.core.Tensor(np.ascontiguousarray(f, dtype=np.uint32)))
        else:
            raise ParameterError(f"unknown ray engine {engine!r} (known: embree, open3d, trimesh)")

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First intersection of each ray with the mesh (in this process).

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
        elif self.engine == "open3d":
            ans = self._o3d_cast(o, d)
            hit = np.isfinite(ans["t_hit"].numpy())
            t[hit] = ans["t_hit"].numpy()[hit]
            face[hit] = ans["primitive_ids"].numpy()[hit]
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
        if self.engine == "open3d":
            return self._o3d_cast(origins, directions)["t_hit"].numpy()  # inf on a miss
        if self.engine != "embree":
            t = self.first_hit(origins, directions)[0].astype(np.float32)
            t[~np.isfinite(t)] = 1e37
            return t
        o32 = np.ascontiguousarray(origins, dtype=np.float32)
        d32 = np.ascontiguousarray(directions, dtype=np.float32)
        if o32.shape != d32.shape or o32.ndim != 2 or o32.shape[1] != 3:
            raise ParameterError(f"origins and directions must both be (K, 3), got {o32.shape} and {d32.shape}")
        return self._query(o32, d32, None, None)

    def rig_distances(self, rig) -> np.ndarray:
        """:meth:`raw_distances` for all rays of a :class:`~spotlights.geometry.rig.Rig`.

        Returns (N*M,) float32 unit-frame distances, >= 1e30 on a miss. With helper
        processes only the job's bounds cross processes (helpers rebuild a rig's rays once).
        """
        if self.engine == "open3d":
            return self._o3d_cast(*rig.rays32, rig=rig)["t_hit"].numpy()  # inf on a miss
        if self.engine != "embree":
            return self.raw_distances(*rig.rays32)
        o32, d32 = rig.rays32
        return self._query(o32, d32, None, rig)

    def rig_depths(self, rig) -> np.ndarray:
        """Spotlights depths of a rig: (N*M,) float32 in [0, 1], 0 = miss or hit beyond the chord.

        :meth:`rig_distances` followed by :func:`to_depths`.
        """
        if self.engine != "embree":
            return to_depths(self.rig_distances(rig), rig.half_chords32)
        o32, d32 = rig.rays32
        return self._query(o32, d32, rig.half_chords32, rig)

    def _query(self, o32: np.ndarray, d32: np.ndarray, post, rig) -> np.ndarray:
        k = len(o32)
        if self.workers > 1 and k >= PARALLEL_MIN_RAYS and not self._helpers_failed and self._lock.acquire(False):
            try:
                helpers = self._ensure_helpers()
                if helpers is not None:
                    try:
                        entry = helpers.token(rig) if rig is not None else None
                        parts = [helpers.run(self._scene, min(_WINDOW, k - s), o32[s:s + _WINDOW],
                                             d32[s:s + _WINDOW], entry, s,
                                             None if post is None else post[s:s + _WINDOW])
                                 for s in range(0, k, _WINDOW)]
                        return parts[0] if len(parts) == 1 else np.concatenate(parts)
                    except _HelperFailed as exc:
                        self._give_up(f"{exc}; continuing in one process")
            finally:
                self._lock.release()
        t = self._run(o32, d32)
        return t if post is None else to_depths(t, post)

    def _o3d_cast(self, origins: np.ndarray, directions: np.ndarray, rig=None) -> dict:
        if rig is not None and self._o3d_rig is not None and self._o3d_rig[0] is rig:
            rays = self._o3d_rig[1]  # the last rig's (K, 6) rays, kept (zero-copy tensor below)
        else:
            o = np.asarray(origins)
            d = np.asarray(directions)
            if o.shape != d.shape or o.ndim != 2 or o.shape[1] != 3:
                raise ParameterError(f"origins and directions must both be (K, 3), got {o.shape} and {d.shape}")
            rays = np.empty((len(o), 6), dtype=np.float32)
            rays[:, :3], rays[:, 3:] = o, d
            if rig is not None:
                self._o3d_rig = (rig, rays)
        return self._o3d_scene.cast_rays(self._o3d.core.Tensor.from_numpy(rays), nthreads=self._o3d_threads)

    def _run(self, o32: np.ndarray, d32: np.ndarray) -> np.ndarray:
        parts = [self._scene.run(o32[s : s + _CHUNK], d32[s : s + _CHUNK], query="DISTANCE")
                 for s in range(0, len(o32), _CHUNK)]
        return np.concatenate(parts) if len(parts) != 1 else parts[0]

    def _ensure_helpers(self) -> _Helpers | None:
        """The helper processes of this process (forked on first use); None where unavailable."""
        h = self._helpers
        if h is not None and h.owner == os.getpid():
            return h
        self._helpers = None  # inherited through a fork: the helpers belong to another process
        if not _helpers_supported():
            self._helpers_failed = True
            return None
        try:
            # commit the BVH before forking, so every process shares the same built scene
            self._scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32), query="DISTANCE")
            self._helpers = _Helpers(self._scene, self.workers)
        except Exception as exc:
            self._give_up(f"could not start helper processes ({exc}); continuing in one process")
            return None
        return self._helpers

    def _give_up(self, why: str) -> None:
        warnings.warn(f"RayCaster(workers={self.workers}): {why}", RuntimeWarning, stacklevel=4)
        self._helpers_failed = True
        self.close()

    def close(self) -> None:
        """Stop this caster's helper processes (if any); later queries run in this process
        until a big one forks new helpers. Idempotent."""
        h, self._helpers = self._helpers, None
        if h is not None:
            h.close()

    def __enter__(self) -> "RayCaster":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def first_hit(mesh, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Convenience: build a :class:`RayCaster` for ``mesh`` (``vertices``/``faces``) and query it once."""
    return RayCaster(mesh.vertices, mesh.faces).first_hit(origins, directions)
