"""Deterministic point sampling: uniform on mesh surfaces, farthest-point subsets."""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError


def sample_surface(mesh, n: int, seed: int | np.random.Generator = 0) -> np.ndarray:
    """``n`` points uniformly distributed (by area) on a triangle mesh's surface.

    Parameters
    ----------
    mesh : object with ``vertices`` (V, 3) and ``faces`` (F, 3).
    n : number of points.
    seed : int seed or numpy Generator; the same seed gives the same points.

    Returns
    -------
    (n, 3) float64 points, in the mesh's frame.
    """
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    tri = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = area.sum()
    if not (total > 0):
        raise ParameterError("mesh has zero surface area")
    face = rng.choice(len(tri), size=int(n), p=area / total)
    u = rng.random((int(n), 2))
    flip = u.sum(axis=1) > 1.0
    u[flip] = 1.0 - u[flip]
    t = tri[face]
    return t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0])


def farthest_point_sample(points: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """Indices of ``n`` points chosen by farthest-point sampling (vectorised over points).

    Starts from a seeded random point; each step adds the point farthest from the
    chosen set. O(n * K) time, one numpy pass over the K points per step (on the three
    coordinate columns: 5-7x faster than a sum over the (K, 3) axis, the same distances).

    Returns
    -------
    (n,) int64 indices into ``points`` (K, 3); requires ``n <= K``.
    """
    p = np.asarray(points, dtype=np.float64)
    k = len(p)
    if n > k or n < 1:
        raise ParameterError(f"cannot pick {n} of {k} points")
    x, y, z = (np.ascontiguousarray(p[:, i]) for i in range(3))

    def sq_dist(i: int) -> np.ndarray:
        return (x - x[i]) ** 2 + (y - y[i]) ** 2 + (z - z[i]) ** 2

    idx = np.empty(n, dtype=np.int64)
    idx[0] = np.random.default_rng(seed).integers(k)
    dist = sq_dist(idx[0])
    for j in range(1, n):
        idx[j] = int(np.argmax(dist))
        np.minimum(dist, sq_dist(idx[j]), out=dist)
    return idx


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Centroids of the points in each occupied cell of a grid of cubes of side ``voxel`` (aligned with the
    frame's origin): a sampling of the same surface whatever the input density.

    Parameters
    ----------
    points : (K, 3) float points (any frame; ``voxel`` in its units).
    voxel : cell side, > 0.

    Returns
    -------
    (M, 3) float32, one point per occupied cell (M <= K), ordered by cell index (x, then y, then z):
    the same set of points gives the same array whatever its order. K = 0 gives (0, 3).

    A dense and a sparse sampling of one surface give nearly the same cells and centroids, so
    Chamfer distances between downsampled clouds compare shapes at one spatial resolution rather
    than the samplings' densities (unlike a random or farthest-point subset of a fixed count, which
    draws different points from two nearly identical clouds).
    """
    v = float(voxel)
    if not (np.isfinite(v) and v > 0):
        raise ParameterError(f"the voxel size must be > 0, got {voxel}")
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros((0, 3), np.float32)
    if np.abs(p).max() / v >= 2.0**52:  # cell indices beyond exact float64 integers (and int64) would collide
        raise ParameterError(
            f"the voxel size {voxel} is too small for points up to {np.abs(p).max():g} from the origin"
        )
    p = p[canonical_order(p)]  # one summation order per set: bit-identical centroids whatever the input order
    c = np.floor(p / v).astype(np.int64)
    lo = c.min(axis=0)
    span = c.max(axis=0) - lo + 1
    if float(span[0]) * float(span[1]) * float(span[2]) < 2.0**62:
        # one int64 per cell, in the cells' lexicographic order: a 1-D unique (2x cheaper than rows), the same cells
        key = ((c[:, 0] - lo[0]) * span[1] + (c[:, 1] - lo[1])) * span[2] + (c[:, 2] - lo[2])
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    else:
        _, inverse, counts = np.unique(c, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    # each cell's sum added up in the points' (canonical) order, as a loop over them would
    sums = np.stack([np.bincount(inverse, weights=p[:, j], minlength=len(counts)) for j in range(3)], axis=1)
    return (sums / counts[:, None]).astype(np.float32)


def resample(points: np.ndarray, n: int, seed: int | np.random.Generator = 0, method: str = "random") -> np.ndarray:
    """Resample a (K, 3) cloud to exactly ``n`` points.

    ``K > n``: a random subset without replacement (``method="random"``) or farthest-point
    sampling (``method="fps"``). ``K < n``: all points plus a random choice of repeats
    (upsampling by repetition). Returns (n, 3) with the input dtype.
    """
    p = np.asarray(points)
    k = len(p)
    if k == 0:
        raise ParameterError("cannot resample an empty point cloud")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    if k == n:
        return p.copy()
    if k > n:
        if method == "fps":
            return p[farthest_point_sample(p, n, seed=int(rng.integers(2**31)))]
        if method != "random":
            raise ParameterError(f"unknown resampling method {method!r} (random, fps)")
        return p[np.sort(rng.choice(k, size=n, replace=False))]
    extra = rng.choice(k, size=n - k, replace=True)
    return np.concatenate([p, p[extra]], axis=0)


def canonical_order(points: np.ndarray) -> np.ndarray:
    """(K,) int64 indices that sort (K, 3) points by x, then y, then z: an order that depends only on
    the set of points, not on how a file or a crop listed them."""
    p = np.asarray(points)
    return np.lexsort((p[:, 2], p[:, 1], p[:, 0])) if len(p) else np.zeros(0, dtype=np.int64)


def resample_set(points: np.ndarray, n: int, seed: int | np.random.Generator = 0, method: str = "random") -> np.ndarray:
    """:func:`resample` applied to the points in :func:`canonical_order`: (n, 3), the input dtype.

    The result depends only on the *set* of points, ``seed`` and ``method``: one observation
    gives one network input whatever the order of its points (``complete``, ``real complete``
    and ``real extract`` feed a model the same 256 points for the same vehicle).
    """
    p = np.asarray(points)
    return resample(p[canonical_order(p)], n, seed=seed, method=method)
