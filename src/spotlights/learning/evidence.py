"""Per-ray evidence for a batch of scans, in torch: the definitions of :mod:`spotlights.geometry.evidence`.

:func:`ray_evidence` computes, for B scans at once and without a Python loop over rays or scans,
the near-ray candidates and the carved depth bins of every ray of a rig (the geometry layer's
:func:`~spotlights.geometry.evidence.near_ray_evidence` and
:func:`~spotlights.geometry.evidence.carved_depths` for one scan; tests check all three against a
brute-force loop). Angular grids are dense tensors filled with ``scatter_reduce`` (B x N x G x G
cells for the viewpoints, B x G x G for the LiDAR). No gradients flow through the evidence.
:func:`free_space_decode` is the geometry layer's decoding constraint on tensors.
"""

from __future__ import annotations

import torch

from ..geometry.evidence import NEAR_CANDIDATES, EvidenceParams

FEATURES_PER_CANDIDATE = 3
"""(depth, distance / radius, valid) of each near-ray candidate."""


def feature_count(params: EvidenceParams) -> int:
    """Per-ray features of :func:`evidence_features`: 4 candidates x 3, the count, T carved bins."""
    return NEAR_CANDIDATES * FEATURES_PER_CANDIDATE + 1 + int(params.carve_samples)


def _stereo_of(comp: torch.Tensor, length: torch.Tensor) -> torch.Tensor:
    """Stereographic coordinates (..., 2) of vectors whose components in a frame are comp (..., 3) and whose
    lengths are ``length`` (...): ``(x.u, x.v) / (|x| + x.w)`` (the direction's, scale-free); inf for ``-w``."""
    den = (length + comp[..., 2]).unsqueeze(-1)
    ok = den > 1e-12 * length.unsqueeze(-1).clamp(min=1e-30)
    return torch.where(ok, comp[..., :2] / torch.where(ok, den, 1.0), float("inf"))


def _norm3(x: torch.Tensor) -> torch.Tensor:
    """(...) Euclidean length of x (..., 3), summed in numpy's order (the geometry layer's ``np.linalg.norm``)."""
    sq = x * x
    return torch.sqrt(sq[..., 0] + sq[..., 1] + sq[..., 2])


def stereo_frames_torch(centres: torch.Tensor) -> torch.Tensor:
    """:func:`spotlights.geometry.evidence.stereo_frames` on tensors: (..., 3, 3) frames (rows u, v, w;
    ``w = -c / |c|``) of centres of projection ``c`` (..., 3), in the dtype and on the device of ``centres``
    (float64 in :func:`ray_evidence`: numpy's frames to the last bit or two)."""
    n = _norm3(centres).unsqueeze(-1)
    w = -(centres / torch.where(n > 0, n, torch.ones_like(n)))
    near_z = (w[..., 2].abs() > 0.9).unsqueeze(-1)
    ex = torch.tensor([1.0, 0.0, 0.0], dtype=w.dtype, device=w.device)
    ez = torch.tensor([0.0, 0.0, 1.0], dtype=w.dtype, device=w.device)
    u = torch.linalg.cross(torch.where(near_z, ex, ez).expand_as(w), w)
    u = u / _norm3(u).unsqueeze(-1)
    return torch.stack([u, torch.linalg.cross(w, u), w], -2)


def sensor_extent_torch(sensor: torch.Tensor) -> torch.Tensor:
    """:func:`spotlights.geometry.evidence.sensor_extent` of B sensors (B, 3) at once: (B,) ``tan(alpha / 2)``,
    ``sin alpha = 1 / |S|``, 1 where ``|S| <= 1`` (or NaN), in the dtype of ``sensor``."""
    r = torch.linalg.vector_norm(sensor, dim=-1)  # numpy's norm of a vector, bit for bit
    outside = r > 1.0
    return torch.where(outside, torch.tan(0.5 * torch.asin(1.0 / torch.where(outside, r, 2.0))), 1.0)


def _wide(device: torch.device) -> torch.dtype:
    """The dtype the frames and extents are computed in: float64 (as numpy), float32 on Apple's MPS (no float64)."""
    return torch.float32 if device.type == "mps" else torch.float64


def _cells(s: torch.Tensor, extent: torch.Tensor, cells: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Grid cells (..., 2) int64 and inside mask (...) of stereographic coordinates s (..., 2); extent broadcasts
    against s[..., 0]."""
    q = (s + extent.unsqueeze(-1)) * (cells / (2.0 * extent.unsqueeze(-1)))
    inside = ((q >= 0) & (q < cells)).all(-1)
    q = torch.where(inside.unsqueeze(-1), q, -1.0)
    return torch.floor(q).long(), inside


def _nearest_per_cell(
    keys: torch.Tensor, ranges: torch.Tensor, n_keys: int, ids: torch.Tensor | None = None
) -> torch.Tensor:
    """(n_keys,) entry index (or its ``ids``) of the smallest range per key (ties: the lowest index), -1 if none;
    int32 (int64 from 2**31 entries on). keys (E,) int64, -1 = no cell; ranges (E,), not NaN where keys >= 0;
    ids (E,) int64 in [0, E), increasing with the entry index among the entries of any one key (default: the entry
    index)."""
    ok = keys >= 0
    k = torch.where(ok, keys, n_keys)  # the entries in no cell go to one more key, dropped at the end
    best = torch.full((n_keys + 1,), float("inf"), dtype=ranges.dtype, device=ranges.device)
    best = best.scatter_reduce(0, k, ranges, "amin")
    small = len(keys) < 2**31 - 1
    itype = torch.int32 if small else torch.int64  # half the memory traffic of the (n_keys,) table
    e = torch.arange(len(keys), device=keys.device, dtype=itype) if ids is None else ids.to(itype)
    # a key's entries include its nearest (their ranges are not NaN), so only the keys without entries keep the -1
    # they start with: no pass over every key after the scatter
    first = torch.full((n_keys + 1,), -1, dtype=itype, device=keys.device)
    first = first.scatter_reduce(0, k, torch.where(ranges == best[k], e, len(keys)), "amin", include_self=False)
    return first[:n_keys]


@torch.no_grad()
def ray_evidence(
    points: torch.Tensor,
    origins: torch.Tensor,
    directions: torch.Tensor,
    sensor: torch.Tensor | None,
    n_secondary: int,
    params: EvidenceParams,
) -> dict:
    """Near-ray and free-space evidence of B scans (definitions: :mod:`spotlights.geometry.evidence`).

    Parameters
    ----------
    points : (B, K, 3) observed points, unit frame. origins : (R, 3) ray origins (viewpoint ``r // M``).
    directions : (B, R, 3) or (R, 3) unit ray directions, unit frame. sensor : (B, 3) LiDAR origins,
        unit frame (NaN rows, or None: nothing carved). n_secondary : M, rays per viewpoint.

    Returns (dtype of ``points``, on its device): ``depth``, ``distance`` (B, R, 4), ``valid`` (B, R, 4) bool,
    ``count`` (B, R) int64, ``carved`` (B, R, T) bool, ``half_chord`` (B, R).
    """
    dev, dt = points.device, points.dtype
    b, k = points.shape[0], points.shape[1]
    o = origins.to(dt)
    r, m = o.shape[0], int(n_secondary)
    d = directions.to(dt).expand(b, r, 3)
    n = r // m
    g = int(params.near_cells)
    views = o[::m]  # (N, 3)
    ft = stereo_frames_torch(views.detach().to(_wide(dev))).to(dt).transpose(1, 2)  # (N, 3, 3)
    comp = torch.matmul(d.reshape(b, n, m, 3), ft).reshape(b, r, 3)  # ray directions in their viewpoint's frame
    s_ray = _stereo_of(comp, torch.ones_like(comp[..., 0]))  # (B, R, 2)
    extent = s_ray.abs().flatten(1).amax(1).clamp(min=1e-6)  # (B,)
    rel = points[:, None] - views[None, :, None]  # (B, N, K, 3)
    rho = rel.norm(dim=-1)
    cell, inside = _cells(_stereo_of(torch.matmul(rel, ft), rho), extent[:, None, None], g)
    bn = torch.arange(b * n, device=dev).reshape(b, n, 1)
    keys = torch.where(inside, (bn * g + cell[..., 0]) * g + cell[..., 1], -1).reshape(-1)
    # the entries of one cell share their scan and viewpoint, so the lowest point index is the lowest entry:
    # the cells keep their point's index into (B*K) directly (no integer division over every cell)
    ids = (torch.arange(b, device=dev)[:, None, None] * k + torch.arange(k, device=dev)).expand(b, n, k)
    first = _nearest_per_cell(keys, rho.reshape(-1), b * n * g * g, ids.reshape(-1))  # index into (B*K) or -1
    q = (s_ray + extent[:, None, None]) * (g / (2.0 * extent[:, None, None]))
    base = torch.floor(q - 0.5).long()
    row = (torch.arange(b, device=dev)[:, None] * n + torch.arange(r, device=dev)[None] // m) * g
    cands = []
    for dx, dy in ((0, 0), (0, 1), (1, 0), (1, 1)):  # the 4 cells, not the rays
        cx, cy = base[..., 0] + dx, base[..., 1] + dy
        ok = (cx >= 0) & (cx < g) & (cy >= 0) & (cy < g)
        cands.append(torch.where(ok, first[(row + cx.clamp(0, g - 1)) * g + cy.clamp(0, g - 1)], -1))
    cand = torch.stack(cands, -1)  # (B, R, 4) into (B*K)
    has = cand >= 0
    if k:
        x = points.reshape(-1, 3)[cand.clamp(min=0)]  # (B, R, 4, 3)
    else:
        x = torch.zeros(b, r, NEAR_CANDIDATES, 3, dtype=dt, device=dev)
    relx = x - o[None, :, None]
    t = 0.5 * (relx * d.unsqueeze(2)).sum(-1)
    dist = (relx - (2.0 * t).unsqueeze(-1) * d.unsqueeze(2)).norm(dim=-1)
    valid = has & (t > 0) & (dist <= params.radius)
    t = torch.where(has, t, 0.0)
    dist = torch.where(has, dist, 0.0)
    key = dist + (~valid).to(dt) * (4.0 + 4.0 * float(params.radius))  # distances are < 4 (inside the sphere)
    order = torch.sort(key, dim=-1, stable=True).indices
    out = {
        "depth": t.gather(-1, order),
        "distance": dist.gather(-1, order),
        "valid": valid.gather(-1, order),
        "count": valid.sum(-1),
    }
    out.update(_carve(points, o, d, sensor, params))
    return out


def _carve(points, o, d, sensor, params: EvidenceParams) -> dict:
    """The carved bins of every ray of B scans (see :func:`ray_evidence`)."""
    dev, dt = points.device, points.dtype
    b, k = points.shape[0], points.shape[1]
    n_t, g = int(params.carve_samples), int(params.carve_cells)
    h = (-(o[None] * d).sum(-1)).clamp(min=0.0)  # (B, R)
    depth = (torch.arange(n_t, device=dev, dtype=dt) + 0.5) / n_t * h.unsqueeze(-1)  # (B, R, T)
    if sensor is None or k == 0:
        return {"carved": torch.zeros(depth.shape, dtype=torch.bool, device=dev), "half_chord": h}
    # all in torch (no host round trip, no Python float per scan): torch.compile traces it once for every batch
    s64 = sensor.detach().to(dev, _wide(dev)).reshape(b, 3)
    # (B,) an unknown sensor's rows carve nothing, nor one at the box's centre (no direction to look from; numpy's)
    known = torch.isfinite(s64).all(-1) & (s64.norm(dim=-1) > 0)
    s_safe = torch.where(known[:, None], s64, 2.0)  # a place outside the sphere: its rows are masked out
    ft = stereo_frames_torch(s_safe).to(dt).transpose(1, 2)  # (B, 3, 3)
    extent = sensor_extent_torch(s_safe).to(dt)  # (B,)
    s = s_safe.to(dt)
    rel = points - s[:, None]
    rho = rel.norm(dim=-1)  # (B, K)
    cell, inside = _cells(_stereo_of(torch.bmm(rel, ft), rho), extent[:, None], g)
    keys = torch.where(
        inside & known[:, None], (torch.arange(b, device=dev)[:, None] * g + cell[..., 0]) * g + cell[..., 1], -1
    )
    flat = _nearest_per_cell(keys.reshape(-1), rho.reshape(-1), b * g * g)
    limit = torch.where(flat >= 0, rho.reshape(-1)[flat.clamp(min=0)], -float("inf"))  # nearest range per cell
    # y = o + 2 t d, seen from S: y - S = (o - S) + 2 t d, in the sensor's frame A + 2 t Bv
    os_ = o[None] - s[:, None]  # (B, R, 3)
    a_ = torch.bmm(os_, ft)
    bv = torch.bmm(d.contiguous(), ft)
    two_t = 2.0 * depth  # (B, R, T)
    dist = (
        ((os_ * os_).sum(-1).unsqueeze(-1) + two_t * (2.0 * (os_ * d).sum(-1).unsqueeze(-1) + two_t))
        .clamp(min=0)
        .sqrt()
    )
    # the samples' cells, one (B, R, T) component at a time (the arithmetic of _stereo_of and _cells, without
    # their (B, R, T, 3) and (B, R, T, 2) copies): 4 million samples at batch 32, the evidence's largest tensors
    cu, cv, cw = (a_[..., c].unsqueeze(-1) + two_t * bv[..., c].unsqueeze(-1) for c in range(3))
    den = dist + cw
    ok = den > 1e-12 * dist.clamp(min=1e-30)
    den = torch.where(ok, den, 1.0)
    e = extent[:, None, None]
    scale = g / (2.0 * e)
    qu = (torch.where(ok, cu / den, float("inf")) + e) * scale
    qv = (torch.where(ok, cv / den, float("inf")) + e) * scale
    iny = (qu >= 0) & (qu < g) & (qv >= 0) & (qv < g)
    # a cell inside the grid: q >= 0, so truncation is the floor; outside: cell (0, 0), masked by iny
    cx, cy = torch.where(iny, qu, 0.0).int(), torch.where(iny, qv, 0.0).int()
    key = (torch.arange(b, device=dev, dtype=torch.int32)[:, None, None] * g + cx) * g + cy
    carved = iny & (dist < limit[key] - params.margin) & known[:, None, None]
    return {"carved": carved, "half_chord": h}


def evidence_features(ev: dict, params: EvidenceParams) -> torch.Tensor:
    """(B, R, F) float features of :func:`ray_evidence` (F = :func:`feature_count`): per candidate (depth,
    distance / radius, valid), the count / 4, the T carved bins as 0 / 1."""
    v = ev["valid"].to(ev["depth"].dtype)
    cand = torch.stack([ev["depth"] * v, ev["distance"] / float(params.radius) * v, v], -1).flatten(-2)
    count = (ev["count"].to(cand.dtype) / NEAR_CANDIDATES).unsqueeze(-1)
    return torch.cat([cand, count, ev["carved"].to(cand.dtype)], -1)


def free_space_decode(depth: torch.Tensor, keep: torch.Tensor, carved: torch.Tensor, half_chord: torch.Tensor):
    """:func:`spotlights.geometry.evidence.free_space_decode` on tensors: depth, keep, half_chord (B, R),
    carved (B, R, T) bool -> (depth, keep) (B, R)."""
    n_t = carved.shape[-1]
    h = half_chord.to(depth.dtype)
    dd = torch.minimum(depth.clamp(min=0.0), h)
    frac = torch.where(h > 0, dd / torch.where(h > 0, h, 1.0), 0.0)
    j = torch.floor(frac * n_t).long().clamp(max=n_t - 1)
    inside = carved.gather(-1, j.unsqueeze(-1)).squeeze(-1)
    # only the rays whose surface lies in a carved bin move: the first bin at or after j that is not carved (n_t:
    # none, the ray is dropped), by one masked minimum over their T bins (over every ray, a reversed running
    # minimum (flip, cummin, flip, gather) cost as much as the default model's whole forward pass)
    c, ji = carved[inside], j[inside]  # (A, T), (A,)
    bins = torch.arange(n_t, device=depth.device)
    i = torch.where(~c & (bins >= ji.unsqueeze(-1)), bins, n_t).amin(-1)
    new_depth, new_keep = dd.clone(), keep.clone()
    new_depth[inside] = i.to(dd.dtype) * h[inside] / n_t
    new_keep[inside] = keep[inside] & (i < n_t)
    return new_depth, new_keep
