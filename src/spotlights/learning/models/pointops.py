"""Pure-torch point operations for the point-set models: k nearest neighbours and farthest-point sampling.

Batched tensor code (no CUDA extension, no Python loop over points), on any device, each
beside a naive brute-force reference (``*_reference``: numpy, loops over batch and points)
that the tests compare against. Indices carry no gradient; gather with :func:`gather` to
differentiate through the neighbours' coordinates or features.
"""

from __future__ import annotations

import numpy as np
import torch


@torch.no_grad()
def knn(query: torch.Tensor, ref: torch.Tensor, k: int, block: int = 1 << 22) -> torch.Tensor:
    """Indices of the ``k`` nearest points of ``ref`` to each point of ``query``, nearest first.

    Parameters
    ----------
    query : (B, M, D) points (any frame, the same as ``ref``); ref : (B, N, D), N >= k.
    k : neighbours per query (a query that is also in ``ref`` finds itself first).
    block : distance-block size in elements: queries go in chunks of ``block // (B * N)`` (at least 1), which
        bounds memory and keeps the block near the cache (4M: 4x faster than one block at B 32, N 2,048 on a CPU).

    Returns (B, M, k) int64 rows of ``ref``, ordered by increasing distance. Ranks by
    |r|^2 - 2 q.r (the squared distance less the query's constant |q|^2), in float32.
    """
    n = ref.shape[1]
    if not 1 <= int(k) <= n:
        raise ValueError(f"k must be in 1..{n} (the reference points), got {k}")
    with torch.autocast(device_type=query.device.type, enabled=False):
        q, r = query.float(), ref.float()
        r2 = (r * r).sum(-1).unsqueeze(1)  # (B, 1, N)
        rt = r.transpose(1, 2)
        chunk = max(1, int(block) // max(1, r.shape[0] * n))
        out = [
            torch.baddbmm(r2, q[:, s : s + chunk], rt, alpha=-2.0).topk(int(k), dim=-1, largest=False).indices
            for s in range(0, q.shape[1], chunk)
        ]
    return torch.cat(out, dim=1)


def knn_reference(query: np.ndarray, ref: np.ndarray, k: int) -> np.ndarray:
    """Brute-force :func:`knn`: query (B, M, D), ref (B, N, D) -> (B, M, k) int64, loops over every pair."""
    b, m = query.shape[:2]
    out = np.zeros((b, m, k), dtype=np.int64)
    for i in range(b):
        for j in range(m):
            d = [float(np.sum((query[i, j].astype(np.float64) - p.astype(np.float64)) ** 2)) for p in ref[i]]
            out[i, j] = sorted(range(len(d)), key=lambda t: d[t])[:k]
    return out


@torch.no_grad()
def farthest_point_sample(points: torch.Tensor, m: int) -> torch.Tensor:
    """Farthest-point sampling: indices of ``m`` points spread over each cloud.

    Starts at point 0, then repeatedly takes the point farthest from those taken (ties: the
    lowest index). The loop runs over the ``m`` picks, each a batched (B, N) update: none over points.

    points (B, N, D), 1 <= m <= N -> (B, m) int64 row indices (distinct).
    """
    b, n = points.shape[:2]
    if not 1 <= int(m) <= n:
        raise ValueError(f"can only sample 1..{n} points, got {m}")
    with torch.autocast(device_type=points.device.type, enabled=False):
        cols = [c.contiguous() for c in points.float().unbind(-1)]  # D columns (B, N): cheaper than (B, N, D)
        idx = torch.zeros(b, int(m), dtype=torch.int64, device=points.device)
        nearest = torch.full((b, n), float("inf"), device=points.device)
        last = torch.zeros(b, 1, dtype=torch.int64, device=points.device)
        for t in range(1, int(m)):
            d = sum((c - c.gather(1, last)) ** 2 for c in cols)
            torch.minimum(nearest, d, out=nearest)
            last = nearest.argmax(dim=1, keepdim=True)
            idx[:, t] = last[:, 0]
    return idx


def farthest_point_sample_reference(points: np.ndarray, m: int) -> np.ndarray:
    """Brute-force :func:`farthest_point_sample`: (B, N, D) -> (B, m) int64, point by point in Python."""
    out = np.zeros((points.shape[0], m), dtype=np.int64)
    for i, cloud in enumerate(points.astype(np.float64)):
        chosen = [0]
        while len(chosen) < m:
            best, best_d = -1, -1.0
            for j, p in enumerate(cloud):
                d = min(float(np.sum((p - cloud[c]) ** 2)) for c in chosen)
                if d > best_d:
                    best, best_d = j, d
            chosen.append(best)
        out[i] = chosen
    return out


def gather(values: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Rows of ``values`` per batch: values (B, N, C), idx (B, ...) int64 -> (B, ..., C) (differentiable in values)."""
    b = values.shape[0]
    flat = idx.reshape(b, -1)
    out = torch.gather(values, 1, flat.unsqueeze(-1).expand(-1, -1, values.shape[-1]))
    return out.reshape(*idx.shape, values.shape[-1])
