"""AtlasNet baseline (Groueix et al., CVPR 2018): several learned patches (2-D -> 3-D maps).

Decoder as in the original ("PointGenCon"): per patch, a shared MLP on
[code, 2-D point] with bottleneck b = code + 2: b -> b -> b/2 -> b/4 -> 3, batch
norm + ReLU hidden, tanh output. Training samples the 2-D points uniformly in
[0, 1]^2 afresh at every forward (as the original); evaluation uses a regular
grid per patch (as the original's inference), so predictions are deterministic.

Default: 4 patches x 512 points (16 x 32 grid) = 2048 points, which puts the
parameter count near the paper's 8.3M. Deviations: the PCN encoder (as in the
paper's comparison); trained with the same Chamfer loss as the other baselines.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from ..losses import chamfer_distance
from .base import MLP, CompletionModel, PCNEncoder, regular_grid


class AtlasNet(CompletionModel):
    """AtlasNet with the PCN encoder; forward: (B, K, 3) -> {"points": (B, patches * rows * cols, 3)}."""

    name = "atlasnet"
    target = "points"

    def __init__(
        self,
        code_size: int = 1024,
        encoder_widths: Sequence[int] = (128, 256, 512),
        n_patches: int = 4,
        patch_grid: Sequence[int] = (16, 32),
        batch_norm: bool = True,
        chamfer: str = "l1",
        chamfer_method: str = "auto",
    ):
        super().__init__()
        self.n_patches = int(n_patches)
        rows, cols = int(patch_grid[0]), int(patch_grid[1])
        self.points_per_patch = rows * cols
        self.n_points = self.n_patches * self.points_per_patch
        self.chamfer, self.chamfer_method = chamfer, chamfer_method
        self.encoder = PCNEncoder(code_size, encoder_widths)
        b = code_size + 2
        self.patches = nn.ModuleList(
            MLP([b, b, b // 2, b // 4, 3], batch_norm=batch_norm) for _ in range(self.n_patches)
        )
        # Regular grid in [0, 1]^2 (cell centres), used at evaluation.
        g = regular_grid(rows, cols, 0.5 - 0.5 / rows, 0.5 - 0.5 / cols) + 0.5
        self.register_buffer("grid", g, persistent=False)

    def forward(self, partial: torch.Tensor) -> dict[str, torch.Tensor]:
        code = self.encoder(partial).unsqueeze(1)  # (B, 1, code): replicated by broadcasting
        b = code.shape[0]
        outs = []
        for patch in self.patches:
            if self.training:
                uv = torch.rand(b, self.points_per_patch, 2, device=code.device, dtype=code.dtype)
            else:
                uv = self.grid.unsqueeze(0)
            outs.append(torch.tanh(patch.forward_concat([code, uv])))  # (B, P, 3): the code broadcasts
        return {"points": torch.cat(outs, dim=1)}

    def loss(self, outputs, batch, progress: float = 1.0):
        loss = chamfer_distance(outputs["points"], batch["gt_points"], self.chamfer, self.chamfer_method)
        return loss, {"cd": float(loss.detach())}
