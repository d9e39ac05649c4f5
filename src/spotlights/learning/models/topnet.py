"""TopNet baseline (Tchapmi et al., CVPR 2019): a rooted tree decoder whose leaves are the points.

Decoder as in the Completion3D reference implementation: the root level maps the
code through an MLP [256, 64, nfeat * d_0] (batch norm + ReLU hidden) and tanh to
``d_0`` child features of ``nfeat`` dims; every further level ``l`` takes each
node's feature concatenated with the code (Nin = nfeat + code) through a shared
MLP [Nin, Nin/2, Nin/4, Nin/8, nout * d_l] (batch norm + ReLU hidden, none on the
last level) and tanh, producing ``d_l`` children per node; the last level outputs
3-D points (nout = 3). Degrees [2, 4, 4, 4, 4, 4] give 2048 leaves (Completion3D's
6-level tree for 2048 points), node features of 8 dims.

Deviations: the PCN encoder (as in the paper's comparison); Chamfer loss kind
set by the config (the Completion3D default is the squared CD; we train with the
same CD as the other baselines, see docs/learning.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from ..losses import chamfer_distance
from .base import MLP, CompletionModel, PCNEncoder


class TopNet(CompletionModel):
    """TopNet with the PCN encoder; forward: (B, K, 3) -> {"points": (B, prod(degrees), 3)}."""

    name = "topnet"
    target = "points"

    def __init__(
        self,
        code_size: int = 1024,
        encoder_widths: Sequence[int] = (128, 256, 512),
        degrees: Sequence[int] = (2, 4, 4, 4, 4, 4),
        node_features: int = 8,
        root_hidden: Sequence[int] = (256, 64),
        batch_norm: bool = True,
        chamfer: str = "l1",
        chamfer_method: str = "auto",
    ):
        super().__init__()
        self.degrees = [int(d) for d in degrees]
        if len(self.degrees) < 2:
            raise ValueError("TopNet needs at least two tree levels")
        self.nfeat = int(node_features)
        self.n_points = math.prod(self.degrees)
        self.chamfer, self.chamfer_method = chamfer, chamfer_method
        self.encoder = PCNEncoder(code_size, encoder_widths)
        self.root = MLP([code_size, *root_hidden, self.nfeat * self.degrees[0]], batch_norm=batch_norm)
        nin = self.nfeat + code_size
        levels = []
        for i, d in enumerate(self.degrees[1:], start=1):
            last = i == len(self.degrees) - 1
            nout = 3 if last else self.nfeat
            levels.append(MLP([nin, nin, nin // 2, nin // 4, nin // 8, nout * d], batch_norm=batch_norm and not last))
        self.levels = nn.ModuleList(levels)

    def forward(self, partial: torch.Tensor) -> dict[str, torch.Tensor]:
        code = self.encoder(partial)
        b = code.shape[0]
        nodes = torch.tanh(self.root(code)).reshape(b, self.degrees[0], self.nfeat)
        for i, level in enumerate(self.levels, start=1):
            nout = 3 if i == len(self.degrees) - 1 else self.nfeat
            x = level.forward_concat([nodes, code.unsqueeze(1)])
            nodes = torch.tanh(x).reshape(b, nodes.shape[1] * self.degrees[i], nout)
        return {"points": nodes}

    def loss(self, outputs, batch, progress: float = 1.0):
        loss = chamfer_distance(outputs["points"], batch["gt_points"], self.chamfer, self.chamfer_method)
        return loss, {"cd": float(loss.detach())}
