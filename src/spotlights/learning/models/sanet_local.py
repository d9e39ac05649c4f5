"""Ray-local SA-Net (``sanet-local``): the hit-aware SA-Net whose every ray also looks at the scan along its line.

Every model before it decodes one global 1024-d code and never looks at the input again, so it
draws the car it remembers. Spotlights' outputs are rays with a known origin and direction, so each
ray can read the evidence on its own line (:mod:`spotlights.geometry.evidence`, batched in
:mod:`spotlights.learning.evidence`): the observed points near the line (their depth along the ray
and distance to it) and the depth bins the LiDAR saw empty (free space: the segment from the sensor
to each observed point is empty).

Network: the hit-aware SA-Net (same PCN encoder, same fully connected decoder, a hit logit and a
depth per ray: the *global* prediction), then a small MLP shared by all rays that corrects it from
that ray's evidence:

* per near-ray candidate (up to 4), ``(depth, distance / radius, valid)`` -> ``candidate_width``
  (shared point-wise layer, ReLU), max-pooled over the valid candidates (zeros without one);
* the ray's input ``[code (1024, broadcast: one product per scan), global logit, global depth,
  pooled candidates, the raw evidence features (4 x 3 candidates, count, T carved bins)]`` ->
  ``local_hidden`` (ReLU) -> 2: added to the global logit and depth. Only the rays with evidence
  (a counted candidate or a carved bin) go through it; the others keep the global prediction.

Loss: the hit-aware SA-Net's (:func:`~spotlights.learning.models.sanet_hit.hit_depth_loss`) on the
corrected outputs. Decoding: as ``sanet-hit`` (p(hit) >= the validation-chosen threshold), then the
**free-space constraint** (``free_space_decoding``, on by default): a surface predicted inside a
depth bin the scan saw empty moves to the start of the next bin that is not carved, or the ray is
dropped when every bin after it is carved (:func:`spotlights.learning.evidence.free_space_decode`).
A hard constraint at decoding rather than a penalty in training: what the sensor saw empty is
empty whatever the network learned, and the network still sees the carved bins as input.

Inputs: ``forward(partial, directions, sensor_origin)``; ``directions`` (B, N*M, 3) are required on
a box-targeted rig (cap rigs: the rig's own), ``sensor_origin`` (B, 3) unit frame (None or NaN
rows: no free-space evidence for that scan). Training needs a dataset with the sensor origin
(``/samples/sensor_to_unit``).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from ...geometry.evidence import NEAR_CANDIDATES, EvidenceParams
from ..evidence import FEATURES_PER_CANDIDATE, evidence_features, feature_count, free_space_decode, ray_evidence
from .base import CLIP_DEFAULT, MLP
from .sanet_hit import THRESHOLD_GRID, HitSANet


class LocalSANet(HitSANet):
    """The ray-local SA-Net (registry name ``sanet-local``; see the module docstring).

    Parameters
    ----------
    rig, code_size, encoder_widths, hidden, threshold, threshold_grid, hit_weight, depth_weight, clip,
    float32_head : as :class:`~spotlights.learning.models.sanet_hit.HitSANet` (the global prediction).
    near_cells, radius, carve_cells, carve_samples, margin : the evidence
        (:class:`~spotlights.geometry.evidence.EvidenceParams`).
    candidate_width : width of the shared layer over each near-ray candidate (16).
    local_hidden : hidden widths of the per-ray correction MLP (default [32, 32]).
    free_space_decoding : apply the free-space constraint when decoding (default True).
    classes : class vocabulary of a class-conditioned model (:class:`~spotlights.learning.models.sanet.SANet`).

    forward: (partial (B, K, 3), directions (B, N*M, 3) or None, sensor_origin (B, 3) or None) ->
    ``hit_logits``, ``depths`` (B, N*M) and, for decoding, ``carved`` (B, N*M, T) bool and
    ``half_chord`` (B, N*M).
    """

    name = "sanet-local"
    uses_evidence = True
    """Its forward takes each scan's ray directions and sensor origin (:meth:`forward_inputs`)."""

    def __init__(
        self,
        rig,
        code_size: int = 1024,
        encoder_widths: Sequence[int] = (128, 256, 512),
        hidden: Sequence[int] = (256, 256),
        threshold: float = 0.5,
        threshold_grid: Sequence[float] | None = THRESHOLD_GRID,
        hit_weight: float = 1.0,
        depth_weight: float = 1.0,
        clip: float | None = None,
        float32_head: bool = False,
        near_cells: int = 32,
        radius: float = 0.05,
        carve_cells: int = 32,
        carve_samples: int = 8,
        margin: float = 0.02,
        candidate_width: int = 16,
        local_hidden: Sequence[int] = (32, 32),
        free_space_decoding: bool = True,
        classes: Sequence[str] | None = None,
    ):
        super().__init__(
            rig,
            code_size=code_size,
            encoder_widths=encoder_widths,
            hidden=hidden,
            threshold=threshold,
            threshold_grid=threshold_grid,
            hit_weight=hit_weight,
            depth_weight=depth_weight,
            clip=clip,
            float32_head=float32_head,
            classes=classes,
        )
        self.evidence = EvidenceParams(
            int(near_cells), float(radius), int(carve_cells), int(carve_samples), float(margin)
        )
        self.free_space_decoding = bool(free_space_decoding)
        self.n_secondary = int(self.rig.n_secondary)
        c = int(candidate_width)
        self.candidate = MLP([FEATURES_PER_CANDIDATE, c])
        width_in = code_size + 2 + c + feature_count(self.evidence)
        self.local = MLP([width_in, *[int(w) for w in local_hidden], 2], float32_last=bool(float32_head))
        last = self.local.linears[-1]
        torch.nn.init.zeros_(last.weight)  # starts as the global prediction
        torch.nn.init.zeros_(last.bias)

    def forward_inputs(self, batch: dict, rays=None) -> tuple:
        """Forward arguments for a batch: ``(partial, directions, sensor_origin)`` (directions from ``rays``, a
        :class:`~spotlights.learning.rays.DirectionTable`, for box-targeted rigs)."""
        dirs = rays.directions(batch["model"]) if rays is not None else None
        if self.class_embedding is not None:
            return batch["partial"], dirs, batch.get("sensor_origin"), batch.get("cls")
        return batch["partial"], dirs, batch.get("sensor_origin")

    def _directions(self, directions: torch.Tensor | None, b: int) -> torch.Tensor:
        if directions is None:
            if self.directions is None:
                raise ValueError(
                    f"the ray-local SA-Net on the box-targeted rig {self.rig.name} needs each scan's ray "
                    "directions (B, N*M, 3), e.g. spotlights.learning.rays.directions_for_extents"
                )
            return self.directions.expand(b, -1, -1)
        return directions

    def forward(
        self, partial: torch.Tensor, directions=None, sensor_origin=None, classes=None
    ) -> dict[str, torch.Tensor]:
        b = partial.shape[0]
        code = self.encode(partial, classes)
        out = self.decoder(code)
        n = self.rig.n_rays
        logit, depth = out[..., :n], out[..., n:]
        dirs = self._directions(directions, b)
        with torch.autocast(device_type=partial.device.type, enabled=False):
            ev = ray_evidence(
                partial.float(), self.origins, dirs.float(), sensor_origin, self.n_secondary, self.evidence
            )
            feats = evidence_features(ev, self.evidence)  # (B, R, F) float32
        # only the rays with evidence (a counted candidate or a carved bin) are corrected: the others keep the
        # global prediction (their MLP input would hold no evidence), which saves most of the per-ray work
        active = (ev["valid"].any(-1) | ev["carved"].any(-1)).reshape(-1)
        rows = active.nonzero().squeeze(1)  # (A,) into (B*R)
        f = feats.reshape(b * n, -1)[rows]  # (A, F)
        cand = f[:, : NEAR_CANDIDATES * FEATURES_PER_CANDIDATE].reshape(-1, NEAR_CANDIDATES, FEATURES_PER_CANDIDATE)
        valid = ev["valid"].reshape(b * n, NEAR_CANDIDATES, 1)[rows]
        pooled = torch.where(valid, torch.relu(self.candidate(cand.to(code.dtype))), 0.0).amax(1)  # (A, c)
        glob = torch.stack([logit, depth], -1).reshape(b * n, 2)[rows]
        first = self.local.linears[0]
        k = code.shape[-1]
        per_scan = torch.nn.functional.linear(code, first.weight[:, :k])  # (B, H): the code's product, once per scan
        rest = torch.cat([glob.to(code.dtype), pooled.to(code.dtype), f.to(code.dtype)], -1)
        x = per_scan[rows // n] + torch.nn.functional.linear(rest, first.weight[:, k:], first.bias)
        out_a = self.local._from_layer(x, 1, first_done=True)  # (A, 2)
        delta = torch.zeros(b * n, 2, dtype=out_a.dtype, device=out_a.device).index_copy(0, rows, out_a)
        delta = delta.reshape(b, n, 2)
        return {
            "hit_logits": logit + delta[..., 0].to(logit.dtype),
            "depths": depth + delta[..., 1].to(depth.dtype),
            "carved": ev["carved"],
            "half_chord": ev["half_chord"],
        }

    @torch.no_grad()
    def complete(
        self,
        partial,
        clip=CLIP_DEFAULT,
        directions=None,
        sensor_origin=None,
        classes=None,
        box_half=None,
        inside=None,
        snap=None,
    ) -> list[torch.Tensor]:
        """partial (B, K, 3) -> list of B clouds (K_b, 3) float32, unit frame; ``sensor_origin`` (B, 3) unit frame
        or None (no free-space evidence); ``classes`` (B,) int64 class indices (class-conditioned models);
        ``box_half``, ``inside``: the box clip, ``snap``: snapping to the observed points
        (:meth:`~spotlights.learning.models.sanet.SANet.kept_points`)."""
        out = self.forward(partial, directions, sensor_origin, classes)
        return self.outputs_to_points(out, clip, directions, box_half=box_half, inside=inside, snap=snap)

    def outputs_to_points(
        self,
        outputs,
        clip=CLIP_DEFAULT,
        directions: torch.Tensor | None = None,
        threshold: float | None = None,
        box_half=None,
        inside=None,
        snap=None,
    ) -> list[torch.Tensor]:
        """As the hit-aware SA-Net's, with the free-space constraint (when ``free_space_decoding``)."""
        t = self.threshold if threshold is None else float(threshold)
        keep = self.hit_probabilities(outputs) >= t
        depths = outputs["depths"].detach().float()
        if self.free_space_decoding and "carved" in outputs:
            depths, keep = free_space_decode(depths, keep, outputs["carved"], outputs["half_chord"].float())
        return self.kept_points(depths, keep, clip, directions, box_half, inside, snap)
