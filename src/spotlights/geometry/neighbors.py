"""The KD-tree for repeated nearest-neighbour queries on one point set, shared by every layer.

``pykdtree`` (about 3x faster than scipy here) when importable, else
``scipy.spatial.cKDTree``. Distances are unsquared Euclidean, in the points' units. The
distance metrics built on it (one-sided and two-sided Chamfer, F-score) are in
:mod:`spotlights.geometry.distances`.
"""

from __future__ import annotations

import numpy as np


def as_points(p, what: str = "points") -> np.ndarray:
    """``p`` as a C-contiguous (K, 3) float32/float64 array (other dtypes become float64); ValueError naming
    ``what`` for another shape."""
    p = np.asarray(p)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{what} must have shape (K, 3), got {p.shape}")
    if p.dtype not in (np.float32, np.float64):
        p = p.astype(np.float64)
    return np.ascontiguousarray(p)


class NearestNeighbors:
    """A KD-tree over a fixed (K, 3) point set, queried for unsquared NN distances.

    Uses ``pykdtree`` (about 3x faster than scipy here) when importable, else
    ``scipy.spatial.cKDTree``. Query points are cast to the tree's dtype.

    Parameters
    ----------
    points : (K, 3) float32 or float64, K >= 1, in any frame (queries must use the same).
    few_queries : the tree will answer few queries (a 256-point partial against a 16k-point completion):
        pykdtree with leaves of 128 points over the points in float64: about 2x cheaper to build and query
        than scipy's ``cKDTree`` built without balancing or node compaction (used before; the 631 fidelities
        of scene-0523's ``real complete``: 0.57 against 1.08 s) and 1.3-1.5x cheaper than leaves of 16, with
        the same distances bit for bit (both compute them in float64; float32 would move them by ~2e-8).
    """

    def __init__(self, points: np.ndarray, few_queries: bool = False):
        pts = as_points(points)
        if len(pts) == 0:
            raise ValueError("cannot build a KD-tree over an empty point set")
        if few_queries:
            pts = pts.astype(np.float64, copy=False)
        self.points = pts
        self.dtype = pts.dtype
        try:
            from pykdtree.kdtree import KDTree
        except ImportError:  # pragma: no cover - pykdtree is a dependency
            from scipy.spatial import cKDTree

            self._tree = cKDTree(pts)
        else:
            self._tree = KDTree(pts, leafsize=128 if few_queries else 16)

    def query(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest neighbour of every query point.

        Parameters
        ----------
        queries : (Q, 3) points in the same frame as the tree.

        Returns
        -------
        distances : (Q,) float64 unsquared Euclidean distances.
        indices : (Q,) int64 row of the nearest tree point.
        """
        q = np.ascontiguousarray(as_points(queries, "queries"), dtype=self.dtype)
        if len(q) == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64)
        dist, idx = self._tree.query(q, k=1)
        return np.asarray(dist, dtype=np.float64).reshape(-1), np.asarray(idx, dtype=np.int64).reshape(-1)

    def distances(self, queries: np.ndarray) -> np.ndarray:
        """(Q,) float64 unsquared distances from each query point to its nearest tree point."""
        return self.query(queries)[0]


def serial_queries():
    """Context manager: KD-tree queries run on one thread inside it.

    pykdtree splits every query over OpenMP threads; for the many small queries of a
    metric loop (a few thousand points each) that split costs more than it saves, and on a
    machine whose cores are busy (a training run beside it) each call can become ten times
    slower (measured: 1.2 s instead of 0.13 s per minimal-matching search). Limits every
    OpenMP pool of the process (threadpoolctl) for the duration; use it around loops of
    small queries, not around torch work. pykdtree is imported first: threadpoolctl limits only the
    OpenMP libraries loaded when it is called, and pykdtree brings its own.
    """
    from threadpoolctl import threadpool_limits

    try:
        import pykdtree.kdtree  # noqa: F401
    except ImportError:  # pragma: no cover - pykdtree is a dependency
        pass
    return threadpool_limits(limits=1, user_api="openmp")
