"""PCN baseline (Yuan et al., 3DV 2018): coarse points from fully connected layers, then folding.

Decoder as in the original (``pcn_cd.py``/``pcn_emd.py``): the code goes through
fully connected 1024 -> 1024 -> 1024 -> ``num_coarse * 3`` (ReLU, no batch norm)
to a coarse cloud; each coarse point is refined by ``grid_size**2`` points: a
shared MLP 1029 -> 512 -> 512 -> 3 on [2-D grid offset (2), coarse point (3),
code (1024)] whose output is added to the coarse point. Grid offsets span
``[-grid_scale, grid_scale]^2`` (0.05 as in PCN).

Deviations from the original (documented in docs/learning.md):
* 2048 output points instead of 16384: 512 coarse points x a 2x2 grid (the
  original: 1024 x 4x4).
* The coarse loss is a Chamfer distance, not EMD (no EMD kernel on CPU); the
  total loss is ``CD(coarse) + alpha * CD(fine)`` with PCN's alpha schedule
  (0.01, 0.1, 0.5, 1.0 after 10k, 20k, 50k of its 300k steps), expressed as
  shares of the training run.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from ..losses import chamfer_distance
from .base import MLP, CompletionModel, PCNEncoder, regular_grid

DEFAULT_ALPHA_SCHEDULE = ((0.0, 0.01), (10 / 300, 0.1), (20 / 300, 0.5), (50 / 300, 1.0))


class PCN(CompletionModel):
    """PCN with the PCN encoder; forward: (B, K, 3) -> {"coarse": (B, C, 3), "points": (B, C*g*g, 3)}."""

    name = "pcn"
    target = "points"

    def __init__(
        self,
        code_size: int = 1024,
        encoder_widths: Sequence[int] = (128, 256, 512),
        num_coarse: int = 512,
        grid_size: int = 2,
        grid_scale: float = 0.05,
        coarse_hidden: Sequence[int] = (1024, 1024),
        folding_hidden: Sequence[int] = (512, 512),
        chamfer: str = "l1",
        chamfer_method: str = "auto",
        alpha_schedule: Sequence[Sequence[float]] = DEFAULT_ALPHA_SCHEDULE,
    ):
        super().__init__()
        self.num_coarse = int(num_coarse)
        self.grid_size = int(grid_size)
        self.n_points = self.num_coarse * self.grid_size**2
        self.chamfer, self.chamfer_method = chamfer, chamfer_method
        self.alpha_schedule = [(float(a), float(b)) for a, b in alpha_schedule]
        self.encoder = PCNEncoder(code_size, encoder_widths)
        self.coarse_mlp = MLP([code_size, *coarse_hidden, self.num_coarse * 3])
        self.folding = MLP([2 + 3 + code_size, *folding_hidden, 3])
        self.register_buffer(
            "grid", regular_grid(self.grid_size, self.grid_size, grid_scale, grid_scale), persistent=False
        )

    def forward(self, partial: torch.Tensor) -> dict[str, torch.Tensor]:
        code = self.encoder(partial)
        b = code.shape[0]
        coarse = self.coarse_mlp(code).reshape(b, self.num_coarse, 3)
        g2 = self.grid_size**2
        grid_feat = self.grid.repeat(self.num_coarse, 1).unsqueeze(0)  # (1, C*g2, 2)
        point_feat = coarse.repeat_interleave(g2, dim=1)  # (B, C*g2, 3)
        global_feat = code.unsqueeze(1)  # (B, 1, code), replicated by broadcasting
        fine = self.folding.forward_concat([grid_feat, point_feat, global_feat]) + point_feat
        return {"coarse": coarse, "points": fine}

    def alpha(self, progress: float) -> float:
        """Weight of the fine loss at ``progress`` (share of training done)."""
        a = self.alpha_schedule[0][1]
        for start, value in self.alpha_schedule:
            if progress >= start:
                a = value
        return a

    def loss(self, outputs, batch, progress: float = 1.0):
        gt = batch["gt_points"]
        lc = chamfer_distance(outputs["coarse"], gt, self.chamfer, self.chamfer_method)
        lf = chamfer_distance(outputs["points"], gt, self.chamfer, self.chamfer_method)
        alpha = self.alpha(progress)
        return lc + alpha * lf, {"cd_coarse": float(lc.detach()), "cd_fine": float(lf.detach()), "alpha": alpha}
