"""The guard behind "two ray-casting threads are never slower than one", without timing anything.

The speed-up target (2 threads >= 1.85x one at 8k rays) is retired (measured: 1.4-1.5x at 8k and
1.7x at 32k rays is what this binding allows, docs/benchmarks.md; benchmarks/encode.py still
measures it). What must hold on any machine, however loaded, is structural:

- below ``raycast.SPLIT_MIN_RAYS`` a ``workers=2`` query hands nothing to another thread (there the
  hand-over costs what it saves);
- above it the query is cut into one chunk per thread, and the calling thread never waits for a
  pool thread that has not claimed a chunk: with every pool thread busy (here: never started) it
  casts all the chunks itself, so a busy second core costs no more than one thread does.

Truth: ``workers=1``'s bytes. The pool is simulated by patching ``ThreadPoolExecutor.submit``.
"""

from __future__ import annotations

import concurrent.futures
import threading

import numpy as np
import pytest
import trimesh

from spotlights.geometry import RayCaster
from spotlights.geometry.raycast import SPLIT_MIN_RAYS

pytest.importorskip("embreex")


def _rays(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(n, 3))
    o /= np.linalg.norm(o, axis=1, keepdims=True)
    d = -o + 0.3 * rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def mesh():
    return trimesh.creation.annulus(r_min=0.2, r_max=0.6, height=0.5, sections=24)


def test_small_queries_stay_on_one_thread_and_large_ones_use_one_chunk_per_thread(mesh, monkeypatch):
    handed = []
    real_submit = concurrent.futures.ThreadPoolExecutor.submit

    def recording_submit(self, fn, *args, **kwargs):
        handed.append(fn)
        return real_submit(self, fn, *args, **kwargs)

    monkeypatch.setattr(concurrent.futures.ThreadPoolExecutor, "submit", recording_submit)
    one = RayCaster(mesh.vertices, mesh.faces, workers=1)
    for workers in (2, 3):
        caster = RayCaster(mesh.vertices, mesh.faces, workers=workers)
        for n in (1024, SPLIT_MIN_RAYS - 1):
            handed.clear()
            o, d = _rays(n)
            assert caster.distances(o, d).tobytes() == one.distances(o, d).tobytes()
            assert handed == [], (workers, n)  # below the split size: the calling thread alone
        handed.clear()
        o, d = _rays(4 * SPLIT_MIN_RAYS)
        assert caster.distances(o, d).tobytes() == one.distances(o, d).tobytes()
        assert len(handed) == workers - 1  # the caller takes one chunk, each pool thread at most one


def test_the_caller_never_waits_for_a_pool_thread_that_did_not_start(mesh, monkeypatch):
    """Every pool thread busy elsewhere: a 2-thread query still finishes, on the calling thread, with the same bytes."""
    monkeypatch.setattr(concurrent.futures.ThreadPoolExecutor, "submit", lambda self, fn, *a, **k: None)
    o, d = _rays(8 * SPLIT_MIN_RAYS, seed=1)
    want = RayCaster(mesh.vertices, mesh.faces, workers=1).distances(o, d)
    caster = RayCaster(mesh.vertices, mesh.faces, workers=2)
    got = {}
    runner = threading.Thread(target=lambda: got.setdefault("t", caster.distances(o, d)), daemon=True)
    runner.start()
    runner.join(timeout=60)
    assert not runner.is_alive(), "the calling thread waited for a pool thread that never started"
    assert got["t"].tobytes() == want.tobytes()
