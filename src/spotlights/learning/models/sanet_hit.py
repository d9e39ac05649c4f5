"""Hit-aware SA-Net: per ray a hit logit and a depth, so misses need no clip.

The paper's SA-Net encodes a miss as depth 0 and regresses every ray with L1; at
inference a clip (0.2) removes the rays predicted near 0, and with them every true hit
closer than 0.2 (the paper's stated limitation). This variant separates the two
questions. The decoder (same PCN encoder, same hidden layers) ends in ``2 N*M`` outputs:

* ``hit_logits`` (B, N*M): trained with binary cross-entropy against the ground-truth
  hit mask ``depth > 0``;
* ``depths`` (B, N*M): trained with L1 on the ground-truth hits only (a miss has no depth).

Loss = ``hit_weight * BCE + depth_weight * L1_hits`` where BCE is the mean over all rays
of the batch and ``L1_hits = sum over hit rays |d - d*| / number of hit rays`` (batch-wide).
With ``box_weight > 0`` (opt-in) it adds ``box_weight * BOX``: every ray's point
``o + 2 d u`` is scored by its Euclidean distance outside the sample's box grown by 0.15 m
(the decoding clamp's box), weighted by p(hit) and divided by the number of hit rays
(:func:`box_outside_term`): a hit drawn outside the box is pushed in or turned off.

At inference a ray is kept where ``sigmoid(logit) >= threshold``; its depth is clamped to
[0, half the ray's chord] and decoded with the rig exactly as SA-Net does (:meth:`SANet.decode`). The threshold
is chosen during training on the validation split (the value of ``threshold_grid`` that
minimises validation CD-L1, :func:`spotlights.learning.train.validate`) and stored in the
checkpoint (``hit_threshold``); ``model_from_checkpoint`` sets it. ``clip`` (a depth clip on
top) defaults to none.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from .base import CLIP_DEFAULT
from .sanet import SANet
from .viewpoint_head import ViewpointDecoder

THRESHOLD_GRID = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
"""Hit-probability thresholds tried on the validation split (the CD-L1 minimiser is kept)."""


class HitSANet(SANet):
    """SA-Net with a per-ray hit head (registry name ``sanet-hit``).

    Parameters
    ----------
    rig, code_size, encoder_widths, hidden : as :class:`SANet` (the last decoder layer has
        ``2 N*M`` outputs: hit logits, then depths).
    threshold : p(hit) threshold used at inference until training chooses one (default 0.5).
    threshold_grid : thresholds tried on the validation split; ``None`` or ``[]`` keeps ``threshold``.
    hit_weight, depth_weight : loss weights of the BCE and the hit-only L1 terms.
    clip : optional depth clip applied on top of the hit decision (default None: none).
    classes, class_templates : class vocabulary of a class-conditioned model and its optional per-class output
        templates (:class:`~spotlights.learning.models.sanet.SANet`).
    box_weight : weight of the opt-in box term (default 0: the loss as before, exactly): the p(hit)-weighted
        distance of each ray's point outside its sample's grown box (:func:`box_outside_term`); the batch must
        then carry ``directions`` (B, N*M, 3) and ``box_half`` (B, 3) (the training loop adds them,
        :func:`spotlights.learning.validation.with_boxes`).
    float32_head : compute the last decoder layer (the logits and depths) in float32 under a
        bf16 autocast (default False: the layout of checkpoints written before it existed; the
        packaged config sets true). Measured: 400 bf16 steps with it reach a validation CD-L1
        4.4% *below* fp32's (0.0363 vs 0.0380), without it 9.1% above (0.0414); docs/learning.md.

    viewpoint_code : width ``c`` of a code per viewpoint (default None: the plain decoder, every checkpoint
        before it). With ``c`` the decoder's last layer is replaced by per-viewpoint codes and one output
        matrix per viewpoint (:class:`~spotlights.learning.models.viewpoint_head.ViewpointDecoder`): a
        completion is a ReLU mix of N*c output patterns instead of ``hidden[-1]``; same outputs, layout and loss.

    forward: partial (B, K, 3) -> {"hit_logits": (B, N*M), "depths": (B, N*M)} (raw depths;
    decoding clamps them to [0, half the ray's chord]).
    """

    name = "sanet-hit"
    outputs_per_ray = 2

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
        classes: Sequence[str] | None = None,
        box_weight: float = 0.0,
        class_templates: bool = False,
        viewpoint_code: int | None = None,
    ):
        super().__init__(
            rig,
            code_size=code_size,
            encoder_widths=encoder_widths,
            hidden=hidden,
            output_activation="none",
            clip=clip,
            classes=classes,
            class_templates=class_templates,
        )
        self.viewpoint_code = None if viewpoint_code is None else int(viewpoint_code)
        if self.viewpoint_code is not None:
            if self.viewpoint_code < 1:
                raise ValueError(f"viewpoint_code must be >= 1 or None, got {viewpoint_code}")
            self.decoder = ViewpointDecoder(
                [code_size, *hidden],
                self.rig.n_primary,
                self.rig.n_secondary,
                self.outputs_per_ray,
                self.viewpoint_code,
            )
        self.decoder.float32_last = bool(float32_head)
        self.threshold = check_probability(threshold, "threshold")
        self.threshold_grid = tuple(check_probability(t, "threshold_grid value") for t in (threshold_grid or ()))
        self.hit_weight, self.depth_weight = float(hit_weight), float(depth_weight)
        if self.hit_weight < 0 or self.depth_weight < 0 or self.hit_weight + self.depth_weight == 0:
            raise ValueError(
                f"hit_weight and depth_weight must be >= 0 and not both 0, got {hit_weight}, {depth_weight}"
            )
        self.box_weight = float(box_weight)
        if not self.box_weight >= 0:
            raise ValueError(f"box_weight must be >= 0, got {box_weight}")

    def init_state(self, state: dict) -> dict:
        """A checkpoint's state dict made to fit this model for ``model.init``: a plain decoder's weights become
        this model's per-viewpoint decoder computing the same outputs
        (:meth:`~spotlights.learning.models.viewpoint_head.ViewpointDecoder.state_from_plain`); else ``state``."""
        if isinstance(self.decoder, ViewpointDecoder) and "decoder.view_weight" not in state:
            return self.decoder.state_from_plain(state)
        return state

    def forward(self, partial: torch.Tensor, classes: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        out = self.add_template(self.decoder(self.encode(partial, classes)), classes)
        n = self.rig.n_rays
        return {"hit_logits": out[..., :n], "depths": out[..., n:]}

    def loss(self, outputs, batch, progress: float = 1.0):
        loss, parts = hit_depth_loss(
            outputs["hit_logits"], outputs["depths"], batch["depths"], self.hit_weight, self.depth_weight
        )
        if self.box_weight > 0:
            if batch.get("directions") is None or batch.get("box_half") is None:
                raise ValueError("box_weight > 0 needs each sample's ray directions and grown box in the batch")
            box = box_outside_term(
                outputs["hit_logits"],
                outputs["depths"],
                batch["depths"],
                self.origins,
                batch["directions"],
                batch["box_half"],
            )
            loss = loss + self.box_weight * box
            parts["box"] = float(box.detach())
        return loss, parts

    def hit_probabilities(self, outputs) -> torch.Tensor:
        """(B, N*M) float32 p(hit) of every ray."""
        return torch.sigmoid(outputs["hit_logits"].detach().float())

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
        """Completed clouds (list of B (K_b, 3) float32, unit frame): the rays with p(hit) >= ``threshold``
        (default: the model's, i.e. the checkpoint's chosen threshold), in ray order; ``box_half``, ``inside``:
        see :meth:`~spotlights.learning.models.sanet.SANet.kept_points`."""
        t = self.threshold if threshold is None else float(threshold)
        keep = self.hit_probabilities(outputs) >= t
        return self.kept_points(outputs["depths"].detach().float(), keep, clip, directions, box_half, inside, snap)


def hit_depth_loss(
    hit_logits: torch.Tensor,
    depths: torch.Tensor,
    target: torch.Tensor,
    hit_weight: float = 1.0,
    depth_weight: float = 1.0,
):
    """The hit-aware SA-Net's loss: ``hit_weight * BCE(logits, target > 0) + depth_weight * L1 on hits``.

    hit_logits, depths, target : (B, N*M) float32; ``target`` are ground-truth normalised depths,
    0 = miss. BCE is the mean over all B*N*M rays; the L1 term is the mean of ``|depth - target|``
    over the rays whose target is a hit (batch-wide; 0 when the batch has no hit).
    Returns (scalar loss tensor, {"bce", "l1_hits", "hit_accuracy"} floats).
    """
    if not (hit_logits.shape == depths.shape == target.shape):
        raise ValueError(
            f"shapes differ: logits {tuple(hit_logits.shape)}, depths {tuple(depths.shape)}, "
            f"target {tuple(target.shape)}"
        )
    hit = target > 0
    bce = torch.nn.functional.binary_cross_entropy_with_logits(hit_logits, hit.to(hit_logits.dtype))
    n_hit = hit.sum()
    l1 = torch.where(hit, (depths - target).abs(), torch.zeros_like(depths)).sum() / n_hit.clamp(min=1)
    loss = hit_weight * bce + depth_weight * l1
    with torch.no_grad():
        acc = ((hit_logits >= 0) == hit).float().mean()
    return loss, {"bce": float(bce.detach()), "l1_hits": float(l1.detach()), "hit_accuracy": float(acc)}


def box_outside_term(
    hit_logits: torch.Tensor,
    depths: torch.Tensor,
    target: torch.Tensor,
    origins: torch.Tensor,
    directions: torch.Tensor,
    box_half: torch.Tensor,
) -> torch.Tensor:
    """The box term of the hit-aware loss: ``sum over rays of p(hit) * outside / number of hit rays``.

    hit_logits, depths, target : (B, R) float32 (``target`` as in :func:`hit_depth_loss`: 0 = miss; it
    only gives the normaliser, the batch's number of true hits, as the L1 term's, so a weight of 1 prices
    a point 1 unit outside the box like a depth 1 unit off); origins : (R, 3) ray origins, directions :
    (B, R, 3) or (R, 3) unit directions, unit frame; box_half : (B, 3) half-extents of each sample's box
    grown by the margin, in its unit frame (:func:`spotlights.geometry.box_clamp.grown_half_extents`).

    ``outside`` is the Euclidean distance of the ray's point ``o + 2 d u`` (the raw depth, unclamped, so
    a negative or over-long depth is pulled back too) to the box ``[-box_half, box_half]``: 0 inside, so
    the points the network keeps inside cost nothing; an L1 form (not squared): a pull of constant size
    along the box's outward normal, like the depth L1, neither vanishing near the box nor dominated by
    a few far points. ``p(hit) = sigmoid(logit)`` is not detached: a point outside is pushed toward the
    box through its depth and turned off through its logit (the BCE keeps true hits on). Returns a
    scalar tensor (0 for a batch without a true hit).
    """
    points = origins + (2.0 * depths).unsqueeze(-1) * directions
    outside = torch.linalg.vector_norm(torch.relu(points.abs() - box_half.unsqueeze(-2)), dim=-1)
    n_hit = (target > 0).sum().clamp(min=1)
    return (torch.sigmoid(hit_logits) * outside).sum() / n_hit


def check_probability(t, what: str) -> float:
    """``t`` as a float if it lies strictly between 0 and 1 (a p(hit) threshold), else ValueError naming ``what``
    (NaN fails too). The one owner of the threshold's range: the model's arguments and a checkpoint's stored
    threshold (:func:`~spotlights.learning.checkpoint.model_from_checkpoint`)."""
    t = float(t)
    if not 0.0 < t < 1.0:
        raise ValueError(f"{what} must lie strictly between 0 and 1, got {t}")
    return t
