"""SA-Net (paper Section 4): PCN encoder + a fully connected decoder regressing N*M depths.

The decoder is ``code -> hidden... -> N*M`` with ReLU between layers and a
*linear* output (no sigmoid). Reason: about two thirds of the ground-truth depths
are exact zeros (missed rays); a linear output reaches 0 exactly with a constant L1
gradient, while a sigmoid would saturate there. Under an L1 loss the prediction of
an ambiguous ray tends to the conditional *median* (either "miss" or "hit at
depth d"), not to an average of the two, which would be an outlier between them.

Inference decodes the rig (``P = P1 + 2 * depth * d``, unit frame) and keeps the
rays with depth > 0 (no clip) or depth >= ``clip`` (the paper's clip, 0.2):
an ordered point cloud with a variable number of points.

Rigs: with the paper's cap rig the rays are constants of the model. With a
box-targeted rig (docs/box-rig.md) the origins are constants but the directions
depend on each sample's box, so decoding takes a ``(B, N*M, 3)`` direction tensor
(``spotlights.learning.rays``: from the dataset's per-model boxes, or a detector
box, ``e = size / |size|``). The network itself (encoder, decoder, loss) is the
same for both kinds: N*M depths in a fixed ray order.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from ..losses import depth_l1
from ..rays import rig_rays, rig_spec
from .base import CLIP_DEFAULT, MLP, CompletionModel, PCNEncoder


class SANet(CompletionModel):
    """Spotlights Array Network.

    Parameters
    ----------
    rig : the rig whose depths are regressed: a ``RigSpec`` (kept as ``self.rig``), a ``Rig`` or a
        ``to_dict()`` of either; required.
    code_size : encoder code size (paper: 1024).
    hidden : hidden layer widths of the decoder (default [256, 256]: 0.85M parameters
        for 2048 rays, keeping the decoder under 1M).
    output_activation : ``"none"`` (linear, default), ``"relu"`` (exact zeros for misses: a
        ray the decoder drives below 0 decodes as a miss even without a clip) or ``"sigmoid"``.
    clip : default inference threshold on predicted depths (paper: 0.2); ``None`` = no clip.

    forward: partial (B, K, 3) -> {"depths": (B, N*M)}.
    """

    name = "sanet"
    target = "depths"
    outputs_per_ray = 1
    """Decoder outputs per ray (the hit-aware variant has two: a hit logit and a depth)."""

    def __init__(
        self,
        rig,
        code_size: int = 1024,
        encoder_widths: Sequence[int] = (128, 256, 512),
        hidden: Sequence[int] = (256, 256),
        output_activation: str = "none",
        clip: float | None = 0.2,
    ):
        super().__init__()

        if rig is None:
            raise ValueError("SA-Net needs a rig (the rig of the depths it regresses)")
        self.rig = rig_spec(rig)  # the RigSpec (cap or box-targeted)
        self.needs_box = self.rig.needs_box
        if output_activation not in ("none", "relu", "sigmoid"):
            raise ValueError(f"output_activation must be 'none', 'relu' or 'sigmoid', got {output_activation!r}")
        self.output_activation = output_activation
        self.clip = None if clip is None else float(clip)
        self.encoder = PCNEncoder(code_size, encoder_widths)
        self.decoder = MLP([code_size, *hidden, self.outputs_per_ray * self.rig.n_rays])
        origins, directions = rig_rays(self.rig)
        self.register_buffer("origins", torch.from_numpy(origins), persistent=False)
        self.register_buffer(
            "directions", None if directions is None else torch.from_numpy(directions), persistent=False
        )

    def forward(self, partial: torch.Tensor) -> dict[str, torch.Tensor]:
        d = self.decoder(self.encoder(partial))
        if self.output_activation == "sigmoid":
            d = torch.sigmoid(d)
        elif self.output_activation == "relu":
            d = torch.relu(d)
        return {"depths": d}

    def loss(self, outputs, batch, progress: float = 1.0):
        loss = depth_l1(outputs["depths"], batch["depths"])
        return loss, {"l1": float(loss.detach())}

    def decode(
        self,
        depths: torch.Tensor,
        clip=CLIP_DEFAULT,
        directions: torch.Tensor | None = None,
        keep: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Depths (B, N*M) -> points (B, N*M, 3) float32 unit frame and kept mask (B, N*M) bool.

        Same convention as ``spotlights.geometry.encode.decode``: a ray is kept when
        depth > 0 and (with a clip) depth >= clip; dropped rays sit at their origin.
        ``keep``: (B, N*M) bool rays to keep instead of ``depth > 0`` (the hit-aware SA-Net's
        ``p(hit) >= threshold``); a clip still applies on top. Kept depths are clamped to half
        the ray's chord through the unit sphere (<= 1): every point stays in the sphere.
        ``directions``: (B, N*M, 3) float32 per-sample unit ray directions (unit frame);
        required for a box-targeted rig (each sample's box), optional for a cap rig
        (default: the rig's fixed rays).
        """
        clip = self.clip if clip is CLIP_DEFAULT else clip
        mask = depths > 0 if keep is None else keep.clone()
        if clip is not None:
            mask &= depths >= float(clip)
        pts = self.ray_points(depths, directions)
        return torch.where(mask.unsqueeze(-1), pts, self.origins.expand_as(pts)), mask

    def ray_points(self, depths: torch.Tensor, directions: torch.Tensor | None = None) -> torch.Tensor:
        """Every ray's point ``o + 2 d dir``, (B, N*M, 3) float32 unit frame, kept or not (see :meth:`decode`).

        Safe outputs: a depth is clamped to [0, half the ray's chord through the unit sphere]
        (<= 1), so no decoded point can leave the sphere of the object's box, whatever the
        network regresses (a linear output is unbounded); true depths never exceed it.
        """
        if directions is None:
            if self.directions is None:
                raise ValueError(
                    f"SA-Net regresses the box-targeted rig {self.rig.name}: decoding needs each sample's "
                    "ray directions (B, N*M, 3), e.g. spotlights.learning.rays.directions_for_extents"
                )
            directions = self.directions
        elif directions.shape[-2:] != (self.rig.n_rays, 3) or (
            directions.dim() == 3 and directions.shape[0] != depths.shape[0]
        ):
            raise ValueError(
                f"directions of shape {tuple(directions.shape)} do not fit depths of shape {tuple(depths.shape)}"
            )
        half_chord = (-(self.origins * directions).sum(-1)).clamp(min=0.0)
        d = torch.minimum(depths.clamp(min=0.0), half_chord)
        return self.origins + (2.0 * d).unsqueeze(-1) * directions

    def outputs_to_points(
        self, outputs, clip=CLIP_DEFAULT, directions: torch.Tensor | None = None
    ) -> list[torch.Tensor]:
        pts, mask = self.decode(outputs["depths"].detach().float(), clip, directions)
        return [p[m] for p, m in zip(pts, mask)]
