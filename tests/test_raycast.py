"""One query shared by helper processes (RayCaster/MeshProbe ``workers=2``).

Truth: brute-force Moller-Trumbore for the distances; ``workers=1`` (no process
ever forked) for the byte-for-byte identity; /proc for leaked processes.
"""

import gc
import multiprocessing as mp
import os
import signal
import threading
import time
import warnings

import numpy as np
import pytest
import trimesh

from helpers import brute_force_first_hit

from spotlights.geometry import MeshProbe, RayCaster, make_rig
from spotlights.geometry import raycast

pytestmark = pytest.mark.skipif(not raycast._helpers_supported() or not raycast._embree_available(),
                                reason="helper processes need Linux on x86-64 and embreex")


def _alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


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


def test_two_processes_match_brute_force(annulus):
    o, d = _random_rays(6000, seed=4)  # above PARALLEL_MIN_RAYS: shared with a helper
    with RayCaster(annulus.vertices, annulus.faces, workers=2) as caster:
        t = caster.distances(o, d).astype(np.float64)
        assert caster._helpers is not None and len(caster._helpers.pids) == 1
    bf, margin = brute_force_first_hit(annulus, o, d)
    # Embree works in float32: rays within ~1e-5 (barycentric) of an edge may fall either side
    clear = ~np.isfinite(bf) | (margin > 1e-5)
    assert clear.mean() > 0.99
    assert np.array_equal(np.isfinite(t[clear]), np.isfinite(bf[clear]))
    hit = clear & np.isfinite(bf)
    assert hit.sum() > 1000
    assert np.allclose(t[hit], bf[hit], atol=1e-5)


@pytest.mark.parametrize("rays", [(32, 64), (64, 128), (128, 256), (512, 1024)])
def test_depths_same_bytes_whatever_the_workers(rays):
    # 2k, 8k, 32k rays, and 512k: several shared-memory jobs (raycast._WINDOW rays each)
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.7)
    rig = make_rig(*rays, angle=60)
    one = MeshProbe(mesh).encode(rig)
    with MeshProbe(mesh, workers=2) as two:
        first, again = two.encode(rig), two.encode(rig)
        raw = two.caster.raw_distances(*rig.rays32)  # rays copied through shared memory
    assert one.tobytes() == first.tobytes() == again.tobytes()
    assert raw.tobytes() == MeshProbe(mesh).caster.raw_distances(*rig.rays32).tobytes()
    assert 0.1 < (one > 0).mean() < 0.9


def test_many_jobs_and_rigs_in_a_row(annulus):
    rigs = [make_rig(32, 64, 60), make_rig(64, 128, 45), make_rig(16, 256, 80)]
    ref = [MeshProbe(annulus).encode(r) for r in rigs]
    with MeshProbe(annulus, workers=2) as probe:
        for i in range(60):
            assert probe.encode(rigs[i % 3]).tobytes() == ref[i % 3].tobytes()
        time.sleep(0.05)  # the helper goes to sleep on its pipe: a job must wake it
        assert probe.encode(rigs[0]).tobytes() == ref[0].tobytes()


def test_workers_1_never_forks(annulus):
    caster = RayCaster(annulus.vertices, annulus.faces)
    caster.raw_distances(*_random_rays(40000, seed=1))
    assert caster._helpers is None


def test_no_leaked_process_after_close_or_collection(annulus):
    o, d = _random_rays(4096, seed=2)
    shm = set(os.listdir("/dev/shm")) if os.path.isdir("/dev/shm") else set()
    caster = RayCaster(annulus.vertices, annulus.faces, workers=2)
    caster.distances(o, d)
    pid = caster._helpers.pids[0]
    assert _alive(pid)
    caster.close()
    assert not _alive(pid)
    caster.distances(o, d)  # usable after close: a new helper
    pid = caster._helpers.pids[0]
    del caster
    gc.collect()
    assert not _alive(pid)
    assert not os.path.exists(f"/proc/{pid}")  # reaped, no zombie
    if os.path.isdir("/dev/shm"):  # the shared map is anonymous: no named segment, ever
        assert not {n for n in set(os.listdir("/dev/shm")) - shm if "spotlights" in n or n.startswith("psm_")}


def test_falls_back_to_one_process_when_the_helper_dies(annulus):
    o, d = _random_rays(8192, seed=5)
    ref = RayCaster(annulus.vertices, annulus.faces).distances(o, d)
    caster = RayCaster(annulus.vertices, annulus.faces, workers=2)
    assert caster.distances(o, d).tobytes() == ref.tobytes()
    pid = caster._helpers.pids[0]
    os.kill(pid, signal.SIGKILL)
    time.sleep(0.05)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(3):  # the death is noticed when the parent waits for the helper
            assert caster.distances(o, d).tobytes() == ref.tobytes()
    assert any("one process" in str(w.message) for w in caught)
    assert caster._helpers is None and caster._helpers_failed
    assert not os.path.exists(f"/proc/{pid}")


def test_no_helpers_where_fork_is_unsupported(annulus, monkeypatch):
    monkeypatch.setattr(raycast, "_helpers_supported", lambda: False)
    o, d = _random_rays(4096, seed=6)
    caster = RayCaster(annulus.vertices, annulus.faces, workers=2)
    assert caster.distances(o, d).tobytes() == RayCaster(annulus.vertices, annulus.faces).distances(o, d).tobytes()
    assert caster._helpers is None


_INHERITED = {}


def _encode_inherited(i):
    probe = _INHERITED["probe"]
    out = probe.encode(_INHERITED["rig"])
    mine = probe.caster._helpers
    return out.tobytes(), os.getpid(), None if mine is None else mine.owner


def test_safe_in_forked_workers(annulus):
    """A pool worker forked after the helper exists must not use the parent's helper."""
    rig = make_rig(64, 128, 60)
    ref = MeshProbe(annulus).encode(rig).tobytes()
    probe = MeshProbe(annulus, workers=2)
    assert probe.encode(rig).tobytes() == ref
    parent_helper = probe.caster._helpers.pids[0]
    _INHERITED.update(probe=probe, rig=rig)
    try:
        with mp.get_context("fork").Pool(2) as pool:  # daemonic workers, like DataLoader's
            results = pool.map(_encode_inherited, range(4))
    finally:
        _INHERITED.clear()
    for out, pid, owner in results:
        assert out == ref and owner == pid  # each worker forked its own helper
    assert probe.encode(rig).tobytes() == ref and probe.caster._helpers.pids[0] == parent_helper
    probe.close()
    assert not _alive(parent_helper)


def test_threads_sharing_one_caster(annulus):
    rig = make_rig(64, 128, 60)
    ref = MeshProbe(annulus).encode(rig).tobytes()
    outs = []
    with MeshProbe(annulus, workers=2) as probe:
        def work():
            outs.extend(probe.encode(rig).tobytes() for _ in range(10))
        threads = [threading.Thread(target=work) for _ in range(3)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
    assert len(outs) == 30 and all(o == ref for o in outs)


def test_job_plan_covers_every_ray_once():
    for n in (2048, 5000, 32768, raycast._WINDOW):
        for procs in (2, 3):
            plan = raycast._plan(n, procs)
            flat = [b for seg in plan for b in seg]
            assert flat[0] == 0 and flat[-1] == n
            for seg in plan:
                sizes = np.diff(seg)
                assert (sizes > 0).all() and (sizes[:-1] >= sizes[1:]).all()  # halving from the front


def test_optional_open3d_engine_agrees_with_embree(annulus):
    pytest.importorskip("open3d")
    o, d = _random_rays(3000, seed=7)
    ref_t, ref_face = RayCaster(annulus.vertices, annulus.faces).first_hit(o, d)
    for workers in (1, 2):
        caster = RayCaster(annulus.vertices, annulus.faces, engine="open3d", workers=workers)
        t, face = caster.first_hit(o, d)
        both = np.isfinite(t) & np.isfinite(ref_t)
        assert (np.isfinite(t) != np.isfinite(ref_t)).mean() < 0.002  # float32 edge cases only
        assert np.allclose(t[both], ref_t[both], atol=1e-5)
        assert (face[both] == ref_face[both]).mean() > 0.99
        dist = caster.distances(o, d)
        assert np.array_equal(np.isfinite(dist), np.isfinite(t))
    rig = make_rig(32, 64, 60)
    a = MeshProbe(annulus).encode(rig)
    b = MeshProbe(annulus, engine="open3d", workers=2).encode(rig)
    assert ((a > 0) != (b > 0)).mean() < 0.002 and np.allclose(a, b, atol=1e-5)


def test_three_processes_same_bytes():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.7)
    rig = make_rig(128, 256, angle=60)
    ref = MeshProbe(mesh).encode(rig).tobytes()
    with MeshProbe(mesh, workers=3) as probe:
        assert all(probe.encode(rig).tobytes() == ref for _ in range(10))
        assert len(probe.caster._helpers.pids) == 2
