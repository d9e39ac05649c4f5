"""FoldingNet baseline (Yang et al., CVPR 2018): two folding stages of a fixed 2-D grid.

Decoder as in the original: the code is replicated on every point of a regular
2-D grid; fold 1 is a shared MLP (code + 2) -> 512 -> 512 -> 3 on [code, grid];
fold 2 is a shared MLP (code + 3) -> 512 -> 512 -> 3 on [code, fold-1 output].
ReLU between layers, linear outputs, no batch norm.

Deviations (documented in docs/learning.md): the PCN encoder replaces the graph
encoder (code 1024 instead of 512, as in the paper's comparison); the grid is
32 x 64 = exactly 2048 points (the original: 45 x 45 = 2025) on
[-0.3, 0.3] x [-0.6, 0.6] (equal spacing, the original's 0.3 half-extent);
trained with a Chamfer loss (as the original).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from ..losses import chamfer_distance
from .base import MLP, CompletionModel, PCNEncoder, regular_grid


class FoldingNet(CompletionModel):
    """FoldingNet with the PCN encoder; forward: (B, K, 3) -> {"fold1": (B, R*C, 3), "points": (B, R*C, 3)}."""

    name = "foldingnet"
    target = "points"

    def __init__(
        self,
        code_size: int = 1024,
        encoder_widths: Sequence[int] = (128, 256, 512),
        grid: Sequence[int] = (32, 64),
        grid_scale: float = 0.3,
        hidden: Sequence[int] = (512, 512),
        chamfer: str = "l1",
        chamfer_method: str = "auto",
    ):
        super().__init__()
        rows, cols = int(grid[0]), int(grid[1])
        self.n_points = rows * cols
        self.chamfer, self.chamfer_method = chamfer, chamfer_method
        self.encoder = PCNEncoder(code_size, encoder_widths)
        self.fold1 = MLP([code_size + 2, *hidden, 3])
        self.fold2 = MLP([code_size + 3, *hidden, 3])
        h = float(grid_scale)
        self.register_buffer("grid", regular_grid(rows, cols, h, h * (cols - 1) / max(rows - 1, 1)), persistent=False)

    def forward(self, partial: torch.Tensor) -> dict[str, torch.Tensor]:
        code = self.encoder(partial).unsqueeze(1)  # (B, 1, code): replicated by broadcasting
        f1 = self.fold1.forward_concat([code, self.grid.unsqueeze(0)])  # (B, N, 3): the code broadcasts
        f2 = self.fold2.forward_concat([code, f1])
        return {"fold1": f1, "points": f2}

    def loss(self, outputs, batch, progress: float = 1.0):
        loss = chamfer_distance(outputs["points"], batch["gt_points"], self.chamfer, self.chamfer_method)
        return loss, {"cd": float(loss.detach())}
