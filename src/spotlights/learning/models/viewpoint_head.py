"""A decoder with a code per viewpoint: the SA-Net decoder without the shared bottleneck.

The plain SA-Net decoder is ``code -> hidden... -> P*N*M`` (P outputs per ray). With the
shipped default's hidden ``[256, 64]`` every completion is a ReLU mix of 64 learned output
patterns plus one bias, shared by every viewpoint: the last hidden layer is a 64-unit
bottleneck of the whole shape. :class:`ViewpointDecoder` keeps the hidden layers but ends in

* ``codes = ReLU(W_c h + b_c)`` reshaped to (B, N, c): a ``c``-dim code per viewpoint, then
* per viewpoint ``i``: ``out_i = V_i codes_i + v_i`` (``V_i`` (P*M, c), one matrix per viewpoint),

so a completion is a ReLU mix of ``N * c`` patterns, each viewpoint its own ``c`` (with N = 128
viewpoints and c = 32: 4,096 patterns instead of 64), at about the parameters of the plain
decoder (``h * N * c + N * c * P * M`` against ``h * P * N * M``).

The outputs come in the plain decoder's layout: (B, P * N*M), output kind major, then the rig's
ray order (row ``i*M + k`` = sample k of viewpoint i, :class:`spotlights.geometry.rig.Rig`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from .base import MLP


class ViewpointDecoder(nn.Module):
    """Decoder ``code -> hidden... -> per-viewpoint code (N, c) -> per-viewpoint linear -> P*N*M``.

    Parameters
    ----------
    sizes : [code_size, hidden...] the input size and the hidden widths (at least one hidden layer).
    n_viewpoints : N, the rig's primary viewpoints (>= 1).
    rays_per_viewpoint : M, the rays of each viewpoint (>= 1).
    outputs_per_ray : P (the hit-aware SA-Net: 2, a hit logit and a depth).
    viewpoint_code : c, the width of each viewpoint's code (>= 1).
    float32_last : run the per-viewpoint output layer in float32 under a bf16/fp16 autocast
        (as :class:`~spotlights.learning.models.base.MLP`'s ``float32_last``).

    forward: (B, code_size) float32 -> (B, P * N * M): output kind ``p`` of ray ``i*M + k`` at column
    ``p * N*M + i*M + k``.
    """

    def __init__(
        self,
        sizes: Sequence[int],
        n_viewpoints: int,
        rays_per_viewpoint: int,
        outputs_per_ray: int,
        viewpoint_code: int,
        float32_last: bool = False,
    ):
        super().__init__()
        sizes = [int(s) for s in sizes]
        if len(sizes) < 2:
            raise ValueError(f"a per-viewpoint decoder needs a code size and at least one hidden width, got {sizes}")
        self.n, self.m, self.p, self.c = (
            int(n_viewpoints),
            int(rays_per_viewpoint),
            int(outputs_per_ray),
            int(viewpoint_code),
        )
        if min(self.n, self.m, self.p, self.c) < 1:
            raise ValueError(
                f"n_viewpoints, rays_per_viewpoint, outputs_per_ray and viewpoint_code must be >= 1, "
                f"got {self.n}, {self.m}, {self.p}, {self.c}"
            )
        self.float32_last = bool(float32_last)
        # the hidden layers and the per-viewpoint codes: an MLP whose last layer's ReLU is applied in forward
        self.trunk = MLP([*sizes, self.n * self.c])
        out = self.p * self.m
        self.view_weight = nn.Parameter(torch.empty(self.n, self.c, out))
        self.view_bias = nn.Parameter(torch.empty(self.n, out))
        bound = 1.0 / self.c**0.5  # nn.Linear's default initialisation, per viewpoint
        nn.init.uniform_(self.view_weight, -bound, bound)
        nn.init.uniform_(self.view_bias, -bound, bound)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, code_size) -> (B, P * N * M)."""
        b = x.shape[0]
        codes = torch.relu(self.trunk(x)).reshape(b, self.n, self.c).transpose(0, 1)  # (N, B, c)
        if self.float32_last:
            with torch.autocast(device_type=x.device.type, enabled=False):
                out = torch.baddbmm(self.view_bias.unsqueeze(1), codes.float(), self.view_weight)
        else:
            out = torch.baddbmm(self.view_bias.unsqueeze(1).to(codes.dtype), codes, self.view_weight.to(codes.dtype))
        # (N, B, P*M) -> (B, P, N, M) -> (B, P*N*M)
        return out.reshape(self.n, b, self.p, self.m).permute(1, 2, 0, 3).reshape(b, self.p * self.n * self.m)

    def state_from_plain(self, plain: dict, prefix: str = "decoder.") -> dict:
        """This decoder's weights (a state dict under ``prefix``) computing exactly what a plain decoder computes.

        ``plain`` : a state dict holding a plain decoder (:class:`~spotlights.learning.models.base.MLP`
        ``[code_size, hidden..., P*N*M]`` with this decoder's code size and hidden widths) under ``prefix``
        (``prefix + "linears.J.weight"``, ...). Its hidden layers are copied; its last layer ``W`` (P*N*M, h),
        ``b`` is split by viewpoint: each viewpoint's code starts as the plain decoder's last hidden
        activation (identity rows: ``ReLU(I h) = h`` since ``h >= 0``), and viewpoint ``i``'s output matrix is
        ``W``'s rows of its rays. With ``c > h`` the extra code units keep their random weights and get zero
        output columns. So a run initialised from it starts as the plain model (the fine-tune of ``model.init``,
        a Net2Net-style widening) and can then grow beyond ``h`` shared patterns. Raises ValueError when the
        shapes do not fit or ``c < h``.
        """
        n_hidden = len(self.trunk.linears) - 1
        last_w, last_b = plain.get(f"{prefix}linears.{n_hidden}.weight"), plain.get(f"{prefix}linears.{n_hidden}.bias")
        out = self.p * self.n * self.m
        if last_w is None or last_b is None or tuple(last_w.shape[:1]) != (out,):
            raise ValueError(f"the plain decoder's last layer must have {out} outputs (layer {n_hidden})")
        h = int(last_w.shape[1])
        if self.c < h:
            raise ValueError(f"viewpoint_code ({self.c}) must be >= the plain decoder's last hidden width ({h})")
        new = {k: v for k, v in plain.items() if not k.startswith(prefix)}
        for j in range(n_hidden):
            for kind in ("weight", "bias"):
                new[f"{prefix}trunk.linears.{j}.{kind}"] = plain[f"{prefix}linears.{j}.{kind}"]
        trunk_w = self.trunk.linears[n_hidden].weight.detach().clone().reshape(self.n, self.c, h)
        trunk_b = self.trunk.linears[n_hidden].bias.detach().clone().reshape(self.n, self.c)
        trunk_w[:, :h, :] = torch.eye(h, dtype=trunk_w.dtype)
        trunk_b[:, :h] = 0.0
        view_w = torch.zeros(self.n, self.c, self.p * self.m, dtype=last_w.dtype)
        view_w[:, :h, :] = last_w.reshape(self.p, self.n, self.m, h).permute(1, 3, 0, 2).reshape(self.n, h, -1)
        new[f"{prefix}trunk.linears.{n_hidden}.weight"] = trunk_w.reshape(self.n * self.c, h)
        new[f"{prefix}trunk.linears.{n_hidden}.bias"] = trunk_b.reshape(-1)
        new[f"{prefix}view_weight"] = view_w
        new[f"{prefix}view_bias"] = last_b.reshape(self.p, self.n, self.m).permute(1, 0, 2).reshape(self.n, -1)
        return new
