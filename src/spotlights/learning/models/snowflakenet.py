"""SnowflakeNet (Xiang et al., ICCV 2021): seed generation, then snowflake point deconvolution (SPD).

Written from the paper (no code of the authors' is used). The decoder grows the cloud coarse to
fine, every child point being its parent moved by a learned displacement:

* **Seed generator**: the shape code goes through a point-wise splitting (the paper's transposed
  convolution of the 1 x C code into ``n_seeds`` point features: a Linear C -> n_seeds * dim),
  each seed feature, with the code, through a shared MLP to a seed point. The seeds and the
  partial input are merged and farthest-point sampled to ``n_start`` points, P0.
* **SPD stage i** (one per ``up_factors`` entry r_i): per-point features Q from each parent's
  coordinates and the code (shared MLP); the **skip-transformer** attends, for every parent, over
  its ``k`` nearest parents (vector attention: weights from MLP(q_i - k_j + pos_ij), softmax over
  the neighbours per channel; values MLP([Q; K_prev]) + pos_ij, pos_ij = MLP(p_i - p_j)), keys
  K_prev being the previous stage's child features (Q itself in the first stage), with a residual
  to Q: the shape context H; **point splitting**: a Linear dim -> r * dim per parent (a
  transposed convolution of kernel and stride r) gives r child features, joined with the
  parent's H in a shared MLP to K_i; the displacement tanh(MLP(ReLU(K_i))) moves each of the r
  copies of its parent: P_i = repeat(P_{i-1}, r) + dP_i.
* **Loss**: the sum over the seeds and every stage of the Chamfer distance to the ground truth cut
  to the stage's count (its first n points: the dataset's uniform samples are i.i.d., so a prefix is
  a uniform subset; the paper samples by FPS; the whole ground truth where the stage has more
  points), plus the paper's partial-matching term: the one-sided distance from the partial input
  to the final cloud (``partial_weight``).

Deviations (docs/learning.md, "SnowflakeNet"): the PCN encoder replaces the PointNet++ /
point-transformer extractor (as for every baseline), so the code is 1024-d; the splitting of
the code into seed features goes through a 1024 -> ``seed_code`` Linear first (the paper's
512 -> 256 x 128 transposed convolution would be 33M parameters from a 1024-d code);
feature width ``dim`` 32 and ``k`` 8 neighbours instead of 128 and 16, and attention hidden
widths of ``dim`` instead of 4 * dim (CPU step time); the ground truth of a training batch is the
dataset's 2,048 uniform points, so the last stage (16,384 points) is trained against those.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from ..losses import chamfer_distance, nearest_squared_distances
from .base import MLP, CompletionModel, PCNEncoder
from .pointops import farthest_point_sample, gather, knn


class SkipTransformer(nn.Module):
    """Vector attention of each parent over its ``k`` nearest parents, with keys from the previous stage.

    forward(points (B, N, 3), q_feat (B, N, dim), k_feat (B, N, dim)) -> H (B, N, dim).
    """

    def __init__(self, dim: int, k: int, pos_hidden: int = 32, attn_hidden: int | None = None):
        super().__init__()
        self.k = int(k)
        self.value = MLP([2 * dim, dim, dim])
        self.to_q = nn.Linear(dim, dim)
        self.to_k = nn.Linear(dim, dim)
        self.pos = MLP([3, pos_hidden, dim])
        self.attn = MLP([dim, attn_hidden or dim, dim])
        self.out = nn.Linear(dim, dim)

    def forward(self, points: torch.Tensor, q_feat: torch.Tensor, k_feat: torch.Tensor) -> torch.Tensor:
        idx = knn(points, points, min(self.k, points.shape[1]))  # (B, N, k), itself first
        value = self.value.forward_concat([q_feat, k_feat])  # (B, N, dim)
        q, key = self.to_q(q_feat), self.to_k(k_feat)
        pos = self.pos(points.unsqueeze(2) - gather(points, idx))  # (B, N, k, dim)
        weights = torch.softmax(self.attn(q.unsqueeze(2) - gather(key, idx) + pos), dim=2)
        h = (weights * (gather(value, idx) + pos)).sum(dim=2)
        return self.out(h) + q_feat


class SPD(nn.Module):
    """One snowflake point deconvolution: parents (B, N, 3) -> children (B, N * r, 3) and their features."""

    def __init__(self, code_size: int, dim: int, up_factor: int, k: int, attn_hidden: int | None = None):
        super().__init__()
        self.r = int(up_factor)
        self.dim = int(dim)
        self.query = MLP([3 + code_size, 2 * dim, dim])
        self.transformer = SkipTransformer(dim, k, attn_hidden=attn_hidden)
        self.split = nn.Linear(dim, self.r * dim)  # transposed convolution, kernel = stride = r
        self.child = MLP([2 * dim, dim, dim])
        self.delta = MLP([dim, dim // 2, 3])

    def forward(self, points: torch.Tensor, code: torch.Tensor, k_prev: torch.Tensor | None):
        """points (B, N, 3), code (B, 1, C), k_prev (B, N, dim) or None -> (children (B, N*r, 3), K (B, N*r, dim))."""
        b, n = points.shape[:2]
        q = self.query.forward_concat([points, code])
        h = self.transformer(points, q, q if k_prev is None else k_prev)
        children = self.split(torch.relu(h)).reshape(b, n, self.r, self.dim)
        k_new = self.child.forward_concat([children, h.unsqueeze(2)]).reshape(b, n * self.r, self.dim)
        delta = torch.tanh(self.delta(torch.relu(k_new)))
        return points.repeat_interleave(self.r, dim=1) + delta, k_new


class SnowflakeNet(CompletionModel):
    """SnowflakeNet with the PCN encoder.

    forward: partial (B, K, 3) unit frame -> {"seeds": (B, n_seeds, 3), "p0": (B, n_start, 3),
    "stage1".. : (B, n_start * r_1 * .. , 3), "points": the last stage}; the default config gives
    512 -> 512 -> 2,048 -> 16,384 points (up factors 1, 4, 8).
    """

    name = "snowflakenet"
    target = "points"

    def __init__(
        self,
        code_size: int = 1024,
        encoder_widths: Sequence[int] = (128, 256, 512),
        n_seeds: int = 256,
        seed_code: int = 256,
        n_start: int = 512,
        up_factors: Sequence[int] = (1, 4, 8),
        dim: int = 32,
        k: int = 8,
        attn_hidden: int | None = None,
        partial_weight: float = 1.0,
        chamfer: str = "l1",
        chamfer_method: str = "auto",
    ):
        super().__init__()
        self.n_seeds, self.n_start, self.dim = int(n_seeds), int(n_start), int(dim)
        self.up_factors = [int(r) for r in up_factors]
        if min(self.up_factors, default=0) < 1:
            raise ValueError(f"up_factors must be >= 1, got {list(up_factors)}")
        self.n_points = self.n_start
        for r in self.up_factors:
            self.n_points *= r
        self.partial_weight = float(partial_weight)
        self.chamfer, self.chamfer_method = chamfer, chamfer_method
        self.encoder = PCNEncoder(code_size, encoder_widths)
        self.seed_split = MLP([code_size, int(seed_code), self.n_seeds * self.dim])
        self.seed_mlp = MLP([self.dim + code_size, 2 * self.dim, self.dim, 3])
        self.stages = nn.ModuleList(SPD(code_size, self.dim, r, k, attn_hidden) for r in self.up_factors)

    def forward(self, partial: torch.Tensor) -> dict[str, torch.Tensor]:
        b = partial.shape[0]
        code = self.encoder(partial).unsqueeze(1)  # (B, 1, C)
        seed_feat = torch.relu(self.seed_split(code).reshape(b, self.n_seeds, self.dim))
        seeds = self.seed_mlp.forward_concat([seed_feat, code])  # (B, n_seeds, 3)
        merged = torch.cat([seeds, partial.to(seeds.dtype)], dim=1)
        p = gather(merged, farthest_point_sample(merged, min(self.n_start, merged.shape[1])))
        out = {"seeds": seeds, "p0": p}
        k_feat = None
        for i, stage in enumerate(self.stages):
            p, k_feat = stage(p, code, k_feat)
            out[f"stage{i + 1}"] = p
        out["points"] = p
        return out

    def loss(self, outputs, batch, progress: float = 1.0):
        gt = batch["gt_points"]
        terms, total = {}, 0.0
        for key in ["seeds", *(f"stage{i + 1}" for i in range(len(self.stages)))]:
            pred = outputs[key]
            target = gt[:, : pred.shape[1]]  # uniform i.i.d. surface samples: a prefix is a uniform subset
            cd = chamfer_distance(pred, target, self.chamfer, self.chamfer_method)
            terms[f"cd_{key}"] = float(cd.detach())
            total = total + cd
        if self.partial_weight:
            _, d_partial = nearest_squared_distances(outputs["points"], batch["partial"], self.chamfer_method)
            pm = torch.sqrt(d_partial + 1e-12).mean() if self.chamfer == "l1" else d_partial.mean()
            terms["partial"] = float(pm.detach())
            total = total + self.partial_weight * pm
        return total, terms
