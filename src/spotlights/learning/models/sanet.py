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

import hashlib
from collections import OrderedDict
from collections.abc import Sequence

import torch

from ...data.vehicle_classes import canonical_class, class_rows
from ...geometry.evidence import SnapTargets, snap_batch_to_observed
from ..losses import depth_l1
from ..rays import rig_rays, rig_spec
from .base import CLIP_DEFAULT, MLP, CompletionModel, PCNEncoder


def _digest(x: torch.Tensor) -> bytes:
    """16 bytes of BLAKE2b of a CPU tensor's dtype, shape and values."""
    h = hashlib.blake2b(f"{x.dtype} {tuple(x.shape)}".encode(), digest_size=16)
    h.update(x.detach().contiguous().numpy().tobytes())
    return h.digest()


def _plus_class_rows(x: torch.Tensor, table, classes) -> torch.Tensor:
    """``x`` (B, D) plus row ``classes[b]`` of ``table`` (an ``Embedding`` with D columns) for each scan ``b``; a class
    of -1 adds nothing; ``x`` itself when ``table`` or ``classes`` is None. The row is cast to ``x``'s dtype."""
    if table is None or classes is None:
        return x
    idx = torch.as_tensor(classes, device=x.device).long().reshape(-1)
    rows = table(idx.clamp(min=0)) * (idx >= 0).unsqueeze(-1)
    return x + rows.to(x.dtype)


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
    classes : the class vocabulary of a class-conditioned model (e.g. ``["car", "caravan", "truck", "bus",
        "trailer"]``, :data:`spotlights.data.vehicle_classes.VEHICLE_CLASSES`); ``None`` (default): no class
        input (every checkpoint before it: a car model). With a vocabulary, a learned embedding per class
        (``class_embedding``, (C, code_size), **zero-initialised**) is added to the encoder's global code, so
        a model fine-tuned from a checkpoint without it starts as exactly that checkpoint.
    class_templates : with ``classes``, also a learned **template per class** added to the decoder's outputs
        (``class_template``, (C, outputs_per_ray * N*M), zero-initialised): each class's own offset of every
        ray's outputs, so a class is not only a shift of the 1,024-d code that the decoder's last hidden
        layer (64 wide in the shipped default.pt) must turn into a shape, but can hold a mean shape of its
        own (a box trailer is not a sum of car shapes). Off by default; a model fine-tuned with it from one
        without starts as that one.

    forward: partial (B, K, 3), classes (B,) int64 or None -> {"depths": (B, N*M)}; a class index is a row of
    ``classes`` (-1 or ``None``: no class, the code as the encoder gives it).
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
        classes: Sequence[str] | None = None,
        class_templates: bool = False,
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
        self.classes = tuple(canonical_class(c) for c in (classes or ()))
        if len(set(self.classes)) != len(self.classes):
            raise ValueError(f"classes must be distinct, got {list(classes or ())}")
        self.class_embedding = None
        if self.classes:
            self.class_embedding = torch.nn.Embedding(len(self.classes), int(code_size))
            torch.nn.init.zeros_(self.class_embedding.weight)  # starts as the model without classes
        if class_templates and not self.classes:
            raise ValueError("class_templates needs a class vocabulary (classes)")
        self.class_template = None
        if class_templates:
            self.class_template = torch.nn.Embedding(len(self.classes), self.outputs_per_ray * self.rig.n_rays)
            torch.nn.init.zeros_(self.class_template.weight)  # starts as the model without templates
        origins, directions = rig_rays(self.rig)
        self.register_buffer("origins", torch.from_numpy(origins), persistent=False)
        self.register_buffer(
            "directions", None if directions is None else torch.from_numpy(directions), persistent=False
        )

    def encode(self, partial: torch.Tensor, classes: torch.Tensor | None = None) -> torch.Tensor:
        """The global code (B, code_size): the encoder's, plus the class embedding of each scan's class
        (``classes`` (B,) int64 rows of :attr:`classes`; -1 or ``None``: nothing added)."""
        return _plus_class_rows(self.encoder(partial), self.class_embedding, classes)

    def add_template(self, out: torch.Tensor, classes: torch.Tensor | None) -> torch.Tensor:
        """The decoder's outputs ``out`` (B, outputs_per_ray * N*M) plus each scan's class template (``classes``
        (B,) rows of :attr:`classes`; -1 or ``None``: nothing added); ``out`` itself without templates."""
        return _plus_class_rows(out, self.class_template, classes)

    def class_indices(self, names) -> torch.Tensor:
        """(B,) int64 rows of :attr:`classes` of class names (aliases resolved; ``None`` or an unknown class: -1)."""
        return torch.from_numpy(class_rows(names, self.classes))

    def forward_inputs(self, batch: dict, rays=None) -> tuple:
        """``(partial,)``, and each scan's class index (``batch["cls"]``) for a class-conditioned model."""
        if self.class_embedding is not None:
            return batch["partial"], batch.get("cls")
        return (batch["partial"],)

    @torch.no_grad()
    def complete(
        self, partial, clip=CLIP_DEFAULT, directions=None, classes=None, box_half=None, inside=None, snap=None
    ) -> list[torch.Tensor]:
        """As :meth:`CompletionModel.complete`, with each scan's class index ``classes`` (B,) (see :meth:`encode`)
        and, with ``box_half`` (B, 3), every kept ray's depth clipped to that box (:meth:`clip_to_boxes`;
        ``inside``, a list, gets each scan's share of kept rays inside before the clip); ``snap``: see
        :meth:`kept_points`."""
        return self.outputs_to_points(
            self.forward(partial, classes), clip, directions, box_half=box_half, inside=inside, snap=snap
        )

    def clip_to_boxes(
        self, depths: torch.Tensor, keep: torch.Tensor, directions: torch.Tensor | None, box_half: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Clip every ray's depth to an axis-aligned box of the unit frame, exactly along the ray.

        depths : (B, R) float32 regressed depths (a point is ``o + 2 d u``); keep : (B, R) bool kept rays;
        directions : (B, R, 3) per-scan unit ray directions (None: the rig's fixed ones); box_half : (B, 3)
        half-extents of each scan's box in its unit frame (e.g. the box grown by 0.15 m,
        :func:`spotlights.geometry.box_clamp.grown_half_extents`).

        Each ray meets the box on ``t in [t_in, t_out]`` (slab method, as
        :func:`spotlights.geometry.box_clamp.ray_box_interval`); a kept depth moves to the nearest end of
        that interval (``t`` clipped into ``[max(t_in, 0), t_out]``) and a kept ray that never meets the box
        is dropped. Returns ``(depths (B, R), keep (B, R), inside (B,) float32)``: ``inside`` is each scan's
        share of kept rays whose point was inside the box before the clip (1 for a scan with no kept ray).
        """
        dirs = self.directions if directions is None else directions
        if dirs is None:
            raise ValueError("clipping to a box needs each scan's ray directions (B, N*M, 3)")
        h = box_half.double().reshape(-1, 1, 3)
        if dirs.device.type == "cpu":  # each box's interval once per box size and rays (a track keeps both)
            rig = _digest(self.origins)
            per_box = dirs.dim() == 3 and len(dirs) > 1
            rows = [self._interval(rig, dirs[b] if per_box else dirs.reshape(-1, 3), h[b]) for b in range(len(h))]
            t_in, t_out = torch.stack([r[0] for r in rows]), torch.stack([r[1] for r in rows])
        else:
            t_in, t_out = self._ray_box_interval(dirs.double(), h)
        meets = (t_in <= t_out) & (t_out > 0)
        t = 2.0 * depths.double().clamp(min=0.0)
        was_in = keep & meets & (t >= t_in) & (t <= t_out)
        n_keep = keep.sum(-1)
        inside = torch.where(n_keep > 0, was_in.sum(-1) / n_keep.clamp(min=1), torch.ones_like(n_keep, dtype=t.dtype))
        t = torch.minimum(torch.maximum(t, t_in.clamp(min=0.0)), t_out)
        keep = keep & meets
        return torch.where(keep, t / 2.0, depths.double()).to(depths.dtype), keep, inside.float()

    def snap_rays(
        self, depths: torch.Tensor, keep: torch.Tensor, directions: torch.Tensor | None, targets: SnapTargets
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Snap every scan's rays to its observed points (:func:`spotlights.geometry.evidence.snap_batch_to_observed`).

        depths : (B, R) float32 regressed depths; keep : (B, R) bool kept rays; directions : (B, R, 3) per-scan
        unit ray directions (None: the rig's fixed ones); targets : :class:`~spotlights.geometry.evidence.SnapTargets`
        (observed points, radius, sensor origins; unit frame). Returns ``(depths (B, R) float32, keep (B, R)
        bool)`` on the inputs' device.
        """
        dirs = self.directions if directions is None else directions
        if dirs is None:
            raise ValueError("snapping needs each scan's ray directions (B, N*M, 3)")
        dep, kp = snap_batch_to_observed(
            targets,
            self.origins.detach().cpu().double().numpy(),
            dirs.detach().cpu().double().numpy(),
            self.rig.n_secondary,
            depths.detach().cpu().double().numpy(),
            keep.detach().cpu().numpy(),
        )
        return torch.from_numpy(dep).to(depths.device, depths.dtype), torch.from_numpy(kp).to(keep.device)

    #: Ray-box intervals kept by :meth:`_interval` (least recently used dropped first; 256 kB each at 16,384 rays).
    INTERVAL_CACHE_SIZE = 64

    def _ray_box_interval(self, u: torch.Tensor, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Slab method: each ray ``o + t u`` (origins (R, 3), directions ``u`` (R, 3) or (B, R, 3), float64) meets
        the box of half-extents ``h`` ((B, 1, 3) or (1, 3), float64) on ``t in [t_in, t_out]`` ((B, R) or (R,))."""
        o = self.origins.double()
        zero = u == 0
        axial = bool(zero.any())  # a ray parallel to a slab (rare): that slab holds it everywhere or nowhere
        safe = torch.where(zero, torch.ones_like(u), u) if axial else u
        t1, t2 = (-h - o) / safe, (h - o) / safe
        lo, hi = torch.minimum(t1, t2), torch.maximum(t1, t2)
        if axial:
            slab_in = o.abs() <= h
            inf = torch.full_like(lo, float("inf"))
            lo = torch.where(zero, torch.where(slab_in, -inf, inf), lo)
            hi = torch.where(zero, torch.where(slab_in, inf, -inf), hi)
        return lo.amax(-1), hi.amin(-1)

    def _interval(self, rig: bytes, u: torch.Tensor, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`_ray_box_interval` of one box (rays ``u`` (R, 3) float32, half-extents ``h`` (1, 3) float64, CPU),
        kept by the bytes of the box, the rays and the rays' origins (``rig``: their digest): a tracked vehicle
        keeps its size, so its rays and box, frame after frame. The same numbers as computing them again."""
        cache = self.__dict__.setdefault("_intervals", OrderedDict())
        key = (rig, h.numpy().tobytes(), _digest(u))
        hit = cache.pop(key, None)
        if hit is None:
            hit = self._ray_box_interval(u.double(), h)
        cache[key] = hit  # the most recently used last
        while len(cache) > self.INTERVAL_CACHE_SIZE:
            cache.popitem(last=False)
        return hit

    def forward(self, partial: torch.Tensor, classes: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        d = self.add_template(self.decoder(self.encode(partial, classes)), classes)
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
        self, outputs, clip=CLIP_DEFAULT, directions: torch.Tensor | None = None, box_half=None, inside=None, snap=None
    ) -> list[torch.Tensor]:
        depths = outputs["depths"].detach().float()
        return self.kept_points(depths, None, clip, directions, box_half, inside, snap)

    def kept_points(self, depths, keep, clip, directions, box_half=None, inside=None, snap=None) -> list[torch.Tensor]:
        """The decoded clouds (list of B (K_b, 3) float32, unit frame) of depths (B, R) and kept rays (B, R)
        (None: ``depth > 0``), with the clip, then with ``snap`` (a :class:`~spotlights.geometry.evidence.SnapTargets`)
        the rays snapped to each scan's observed points (:meth:`snap_rays`), and with ``box_half`` the box clip (:meth:`clip_to_boxes`;
        ``inside`` gets its shares)."""
        clip = self.clip if clip is CLIP_DEFAULT else clip
        mask = depths > 0 if keep is None else keep.clone()
        if clip is not None:
            mask &= depths >= float(clip)
        if snap is not None:
            depths, mask = self.snap_rays(depths, mask, directions, snap)
        if box_half is not None:
            depths, mask, share = self.clip_to_boxes(depths, mask, directions, box_half)
            if inside is not None:
                inside.extend(float(v) for v in share)
        pts, mask = self.decode(depths, None, directions, keep=mask)
        return [p[m] for p, m in zip(pts, mask)]
