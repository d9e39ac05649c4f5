"""Ray engines and one query shared by threads (RayCaster/MeshProbe ``workers=2``).

Truth: brute-force Moller-Trumbore for the distances; ``workers=1`` (one thread) for the
byte-for-byte identity. No test here depends on timing.
"""

import multiprocessing as mp
import threading

import numpy as np
import pytest
import trimesh

from spotlights.errors import ParameterError
from spotlights.geometry import MeshProbe, RayCaster, make_rig, raycast

from helpers import brute_force_first_hit

needs_embree = pytest.mark.skipif(not raycast.embree_available(), reason="embreex is not installed")


@pytest.fixture(scope="module")
def annulus():
    return trimesh.creation.annulus(r_min=0.2, r_max=0.6, height=0.5, sections=24)


def _random_rays(n, seed):
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(n, 3))
    o /= np.linalg.norm(o, axis=1, keepdims=True)
    d = -o + 0.3 * rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d


def _check_against_brute_force(mesh, o, d, t, face=None):
    bf, margin = brute_force_first_hit(mesh, o, d)
    # Embree works in float32: rays within ~1e-5 (barycentric) of an edge may fall either side
    clear = ~np.isfinite(bf) | (margin > 1e-5)
    assert clear.mean() > 0.99
    assert np.array_equal(np.isfinite(t[clear]), np.isfinite(bf[clear]))
    hit = clear & np.isfinite(bf)
    assert hit.sum() > 1000
    assert np.allclose(t[hit], bf[hit], atol=1e-5)
    if face is not None:
        assert (face[~np.isfinite(t)] == -1).all() and (face[np.isfinite(t)] >= 0).all()


@needs_embree
@pytest.mark.parametrize("workers", [1, 2, 3])
def test_threads_match_brute_force(annulus, workers):
    o, d = _random_rays(6000, seed=4)  # above SPLIT_MIN_RAYS: cast by several threads
    caster = RayCaster(annulus.vertices, annulus.faces, workers=workers)
    t = caster.distances(o, d)
    assert t.dtype == np.float32
    _check_against_brute_force(annulus, o, d, t.astype(np.float64))
    t64, face = caster.first_hit(o, d)
    assert t64.dtype == np.float64 and face.dtype == np.int64
    _check_against_brute_force(annulus, o, d, t64, face)


@needs_embree
@pytest.mark.parametrize("rays", [(32, 64), (64, 128), (128, 256), (512, 1024)])
def test_same_bytes_whatever_the_workers(rays):
    # 2k rays (one thread), 8k, 32k and 512k (many chunks)
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.7)
    rig = make_rig(*rays, angle=60)
    one = MeshProbe(mesh)
    ref = one.encode(rig)
    ref_t = one.caster.distances(*rig.rays32)
    ref_first = one.caster.first_hit(*rig.rays32)
    for workers in (2, 3, 5):
        probe = MeshProbe(mesh, workers=workers)
        assert probe.encode(rig).tobytes() == ref.tobytes()
        assert probe.encode(rig).tobytes() == ref.tobytes()
        assert probe.caster.distances(*rig.rays32).tobytes() == ref_t.tobytes()
        t, face = probe.caster.first_hit(*rig.rays32)
        assert t.tobytes() == ref_first[0].tobytes() and face.tobytes() == ref_first[1].tobytes()
    assert 0.1 < (ref > 0).mean() < 0.9


@needs_embree
def test_miss_conventions(annulus):
    """One miss value per kind of query: inf (distances), -1 (faces), 0 (depths)."""
    o = np.array([[0.0, 0.0, 5.0], [5.0, 0.0, 0.0]])
    d = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])  # away from the mesh; through the ring
    for engine in ("embree", "trimesh") + (("open3d",) if _has_open3d() else ()):
        caster = RayCaster(annulus.vertices, annulus.faces, engine=engine)
        t = caster.distances(o, d)
        assert t[0] == np.inf and np.isfinite(t[1]) and t[1] == pytest.approx(4.4, abs=1e-4), engine
        t64, face = caster.first_hit(o, d)
        assert t64[0] == np.inf and face[0] == -1 and face[1] >= 0, engine
    rig = make_rig(8, 16, 60)
    depths = MeshProbe(trimesh.creation.box(extents=[0.1, 0.1, 0.1])).encode(rig)
    assert depths.min() == 0 and not np.signbit(depths).any()  # a miss is +0, never -0 or NaN


def _has_open3d():
    try:
        import open3d  # noqa: F401
    except Exception:
        return False
    return True


@needs_embree
def test_empty_and_bad_queries(annulus):
    caster = RayCaster(annulus.vertices, annulus.faces, workers=2)
    assert caster.distances(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)
    t, face = caster.first_hit(np.zeros((0, 3)), np.zeros((0, 3)))
    assert t.shape == face.shape == (0,)
    with pytest.raises(ParameterError, match="must both be"):
        caster.distances(np.zeros((3, 3)), np.zeros((2, 3)))
    with pytest.raises(ParameterError, match="workers"):
        RayCaster(annulus.vertices, annulus.faces, workers=0)
    with pytest.raises(ParameterError, match="unknown ray engine"):
        RayCaster(annulus.vertices, annulus.faces, engine="optix")


def test_split_chunks_cover_every_ray_once():
    for n in (4096, 5000, 32768, 262144, 1 << 20, 7):
        for parts in (2, 3, 8):
            b = raycast.split_bounds(n, parts)
            sizes = np.diff(b)
            assert b[0] == 0 and b[-1] == n and len(b) == parts + 1
            assert (sizes >= 0).all() and sizes.max() - sizes.min() <= 1  # one equal chunk per thread


def test_split_runs_every_chunk_once_and_raises_a_thread_error():
    seen = np.zeros(50000, dtype=np.int64)
    lock = threading.Lock()

    def cast(a, b):
        with lock:
            seen[a:b] += 1

    raycast.run_split(len(seen), 3, cast)
    assert (seen == 1).all()

    def boom(a, b):
        if a > 0:  # fails on whichever thread takes a later chunk
            raise ValueError("chunk failed")

    with pytest.raises(ValueError, match="chunk failed"):
        raycast.run_split(50000, 2, boom)
    raycast.run_split(len(seen), 2, cast)  # the pool is still usable
    assert (seen == 2).all()


@needs_embree
def test_threads_sharing_one_caster(annulus):
    rig = make_rig(64, 128, 60)
    ref = MeshProbe(annulus).encode(rig).tobytes()
    outs = []
    probe = MeshProbe(annulus, workers=2)

    def work():
        outs.extend(probe.encode(rig).tobytes() for _ in range(10))

    threads = [threading.Thread(target=work) for _ in range(3)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(60)
    assert len(outs) == 30 and all(o == ref for o in outs)


def _pool_threads() -> list[threading.Thread]:
    """The live threads of this process's ray pool (named ``spotlights-rays...``)."""
    return [t for t in threading.enumerate() if t.name.startswith("spotlights-rays") and t.is_alive()]


def _child_pool_check(conn):
    """In a forked child: no pool thread came along, and a split starts a new pool thread of this process
    (a child that kept the parent's pool object would hand its chunks to threads that do not exist here)."""
    try:
        fresh = not _pool_threads()
        seen = np.zeros(20000, dtype=np.int64)

        def cast(a, b):
            seen[a:b] += 1

        raycast.run_split(len(seen), 2, cast)
        conn.send((fresh, bool((seen == 1).all()), bool(_pool_threads())))
    except BaseException as exc:  # reported to the parent, never left hanging
        conn.send(repr(exc))
    finally:
        conn.close()


@needs_embree
def test_forked_children_build_their_own_thread_pool(annulus):
    """A process forked after the pool exists (DataLoader workers) gets a fresh pool, not the parent's dead threads.

    The children split a pure-Python job: an Embree scene inherited across a fork is not used here
    (TBB, Embree's task system, is not fork-safe; the project's process pools start from a fork
    server). Children that do not answer in time are killed (SIGKILL), so this test cannot hang."""
    rig = make_rig(64, 128, 60)
    probe = MeshProbe(annulus, workers=2)
    ref = probe.encode(rig).tobytes()  # starts the pool in this process
    assert _pool_threads()  # the pool runs in this process
    ctx = mp.get_context("fork")
    children = []
    for _ in range(2):
        parent, child = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=_child_pool_check, args=(child,))
        proc.start()
        child.close()
        children.append((proc, parent))
    answers = []
    for proc, conn in children:
        answers.append(conn.recv() if conn.poll(120) else "no answer in 120 s")
        proc.join(10)
        if proc.is_alive():
            proc.kill()
            proc.join()
    assert answers == [(True, True, True)] * 2, answers
    assert probe.encode(rig).tobytes() == ref  # the parent's pool still works


@needs_embree
def test_optional_open3d_engine_agrees_with_embree(annulus):
    pytest.importorskip("open3d")
    o, d = _random_rays(3000, seed=7)
    ref_t, ref_face = RayCaster(annulus.vertices, annulus.faces).first_hit(o, d)
    for workers in (1, 2):
        caster = RayCaster(annulus.vertices, annulus.faces, engine="open3d", workers=workers)
        assert isinstance(caster.engine, raycast.Open3DEngine)
        t, face = caster.first_hit(o, d)
        both = np.isfinite(t) & np.isfinite(ref_t)
        assert (np.isfinite(t) != np.isfinite(ref_t)).mean() < 0.002  # float32 edge cases only
        assert np.allclose(t[both], ref_t[both], atol=1e-5)
        assert (face[both] == ref_face[both]).mean() > 0.99
        assert (face[~np.isfinite(t)] == -1).all()
        dist = caster.distances(o, d)
        assert np.array_equal(np.isfinite(dist), np.isfinite(t))
    rig = make_rig(32, 64, 60)
    a = MeshProbe(annulus).encode(rig)
    b = MeshProbe(annulus, engine="open3d", workers=2).encode(rig)
    assert ((a > 0) != (b > 0)).mean() < 0.002 and np.allclose(a, b, atol=1e-5)


def test_engines_share_one_interface():
    for cls in raycast.ENGINES.values():
        assert issubclass(cls, raycast.RayEngine)
        for method in ("distances", "first_hit", "rig_distances"):
            assert callable(getattr(cls, method))
