"""Building blocks shared by every completion model: the PCN encoder, MLPs, the model base class.

Layout convention: point features are (B, K, C) tensors and every "shared
point-wise" layer (a 1x1 convolution in the original papers) is an
``nn.Linear`` applied to the last axis, which is the same function with the
same parameter count as ``Conv1d(C_in, C_out, 1)``.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import ClassVar

import torch
from torch import nn

CLIP_DEFAULT = object()
"""Sentinel: "use the model's configured clip threshold"."""


class MLP(nn.Module):
    """Shared point-wise (or plain) MLP on the last axis: Linear -> [BatchNorm] -> ReLU, last layer linear.

    Parameters
    ----------
    sizes : [C_in, C_1, ..., C_out] channel sizes.
    batch_norm : BatchNorm1d after every hidden Linear (TopNet, AtlasNet), over all
        leading axes flattened.
    float32_last : run the last Linear in float32 even under a bf16/fp16 autocast (its input
        cast to float32); no effect without autocast.
    """

    materialise_concat: ClassVar[bool] = False
    """Benchmarks only: when True, :meth:`forward_concat` builds the expanded concatenation
    (the original papers' form) instead of broadcasting; same outputs, slower."""

    def __init__(self, sizes: Sequence[int], batch_norm: bool = False, float32_last: bool = False):
        super().__init__()
        self.float32_last = bool(float32_last)
        sizes = [int(s) for s in sizes]
        if len(sizes) < 2:
            raise ValueError(f"an MLP needs at least an input and an output size, got {sizes}")
        self.linears = nn.ModuleList(nn.Linear(a, b) for a, b in zip(sizes[:-1], sizes[1:]))
        self.norms = nn.ModuleList(nn.BatchNorm1d(b) for b in sizes[1:-1]) if batch_norm else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(..., C_in) -> (..., C_out)."""
        shape = x.shape[:-1]
        return self._from_layer(x.reshape(-1, x.shape[-1]), 0).reshape(*shape, -1)

    def forward_concat(self, parts: Sequence[torch.Tensor]) -> torch.Tensor:
        """The MLP on ``torch.cat(parts, dim=-1)`` (parts broadcast), without building the concatenation.

        ``parts``: tensors (B or 1, K or 1, C_i) whose channel counts sum to C_in, in the
        order of the concatenation. The first Linear is applied part by part to the
        unexpanded tensors, ``W @ [a; b] = W_a @ a + W_b @ b``, and the results are
        broadcast-added: a per-shape code (B, 1, 1024) replicated on K points costs one
        matrix product per shape instead of K. Same function and parameters as
        ``forward(torch.cat(expanded parts))`` (up to float rounding; tested);
        returns (B, K, C_out).
        """
        lin = self.linears[0]
        sizes = [int(p.shape[-1]) for p in parts]
        if sum(sizes) != lin.in_features:
            raise ValueError(f"parts have {sum(sizes)} channels in all, the first layer takes {lin.in_features}")
        if MLP.materialise_concat:
            shape = torch.broadcast_shapes(*(p.shape[:-1] for p in parts))
            return self.forward(torch.cat([p.expand(*shape, -1) for p in parts], dim=-1))
        x = None
        start = 0
        for p, c in zip(parts, sizes):
            y = torch.nn.functional.linear(p, lin.weight[:, start : start + c])
            x = y if x is None else x + y
            start += c
        x = x + lin.bias
        shape = x.shape[:-1]
        return self._from_layer(x.reshape(-1, x.shape[-1]), 1, first_done=True).reshape(*shape, -1)

    def _from_layer(self, x: torch.Tensor, start: int, first_done: bool = False) -> torch.Tensor:
        """Run layers ``start..`` on (R, C) rows; ``first_done``: ``x`` is layer ``start - 1``'s
        pre-activation (normalise and activate it first)."""
        if first_done:
            x = self._activate(start - 1, x)
        last = len(self.linears) - 1
        for j in range(start, len(self.linears)):
            if j == last and self.float32_last:
                with torch.autocast(device_type=x.device.type, enabled=False):
                    x = self.linears[j](x.float())
            else:
                x = self._activate(j, self.linears[j](x))
        return x

    def _activate(self, j: int, x: torch.Tensor) -> torch.Tensor:
        """After layer ``j``: [BatchNorm +] ReLU for a hidden layer, nothing after the last one."""
        if j == len(self.linears) - 1:
            return x
        if self.norms is not None:
            x = self.norms[j](x)
        return torch.relu(x)


class PCNEncoder(nn.Module):
    """The PCN encoder (Yuan et al. 2018), shared by every model as in the paper.

    Two stacked PointNet layers, no batch norm: point-wise 3 -> 128 -> 256, max-pool
    to a 256-d global feature, concatenated to every point (512), point-wise
    512 -> 512 -> ``code_size``, max-pool. ReLU between layers, none after the last
    layer of each stage (as in PCN's ``mlp_conv``). 821,504 parameters for code 1024.

    ``widths`` = (128, 256, 512) are PCN's; they are parameters only so that tests can
    use a narrower encoder.

    ``mirror`` (attribute, default False; the config's ``model.mirror``, set by ``build_model``):
    encode the points together with their mirror image across the x-z plane of the box frame
    (``y -> -y``; vehicles are left-right symmetric), 2K points; no parameter changes.

    forward: (B, K, 3) float32 unit-frame points (any K >= 1) -> (B, code_size) code.
    """

    mirror: bool = False

    def __init__(self, code_size: int = 1024, widths: Sequence[int] = (128, 256, 512)):
        super().__init__()
        self.code_size = int(code_size)
        w1, w2, w3 = (int(w) for w in widths)
        self.first = MLP([3, w1, w2])
        self.second = MLP([2 * w2, w3, self.code_size])

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        if self.mirror:
            points = torch.cat([points, mirror_y(points)], dim=1)
        if not torch.is_grad_enabled() and not _exporting():
            return self._forward_distinct(points)
        f = self.first(points)  # (B, K, 256)
        g = f.amax(dim=1, keepdim=True)  # (B, 1, 256)
        f = torch.cat([f, g.expand_as(f)], dim=-1)  # (B, K, 512)
        return self.second(f).amax(dim=1)  # (B, code)

    def _forward_distinct(self, points: torch.Tensor) -> torch.Tensor:
        """:meth:`forward` on each shape's distinct points only (inference): (B, K, 3) -> (B, code_size).

        A sparse scan is resampled up to K points by repeating some (``learning.inference.prepare_partial``:
        on nuScenes about half of the 256 input rows are repeats), and both stages end in a max-pool, so a
        repeated row changes nothing but costs its two MLPs. The rows that are bit-for-bit distinct within a
        shape are packed into one (R, 3) batch, run through the same layers, and max-pooled per shape
        (``scatter_reduce``); every Linear works row by row, so the code is the dense forward's (tested
        equal bit for bit on the CPU, fp32 and bf16), at ~R / (B K) of its cost. Used when no gradient is
        recorded (a gradient would be the same but is not needed), never while tracing, compiling or exporting
        (R depends on the data). Any floating dtype: rows are compared by their bits (16-bit ones widened to
        float32 first, which is exact), so -0.0 and 0.0 count as two rows.
        """
        b, k, _ = points.shape
        flat = points.reshape(b * k, 3)
        key = flat.float() if flat.element_size() == 2 else flat.contiguous()
        bits = key.view(torch.int64 if key.element_size() == 8 else torch.int32)  # (B K, 3) exact equality
        order = torch.arange(b * k, device=points.device)
        for column in (2, 1, 0):  # stable sorts, least significant key first: rows by (shape, x, y, z)
            order = order[torch.sort(bits[order, column], stable=True).indices]
        order = order[torch.sort(order // k, stable=True).indices]
        shape_index = order // k
        sorted_bits = bits[order]
        new_row = torch.ones_like(shape_index, dtype=torch.bool)
        new_row[1:] = (sorted_bits[1:] != sorted_bits[:-1]).any(dim=1) | (shape_index[1:] != shape_index[:-1])
        order, shape_index = order[new_row], shape_index[new_row]
        x = flat[order]  # (R, 3) distinct rows, grouped by shape

        def pool(f: torch.Tensor) -> torch.Tensor:
            out = f.new_full((b, f.shape[1]), -torch.inf)
            return out.scatter_reduce(0, shape_index[:, None].expand_as(f), f, "amax")

        f = self.first(x)  # (R, 256)
        f = torch.cat([f, pool(f)[shape_index]], dim=-1)  # (R, 512)
        return pool(self.second(f))  # (B, code)


def _exporting() -> bool:
    """True while torch traces, compiles or exports a model (``torch.jit.trace``, ``torch.compile``, ONNX's
    dynamo exporter): the encoder keeps its dense form there (the distinct rows' count depends on the data).
    ``torch.onnx`` is consulted only when something imported it (importing it costs ~20 ms)."""
    if torch.jit.is_tracing() or torch.compiler.is_compiling():
        return True
    onnx = sys.modules.get("torch.onnx")
    return bool(onnx is not None and onnx.is_in_onnx_export())


def mirror_y(points: torch.Tensor) -> torch.Tensor:
    """(..., 3) points mirrored across the x-z plane of the box frame: ``(x, y, z) -> (x, -y, z)``."""
    return points * points.new_tensor([1.0, -1.0, 1.0])


def count_parameters(module: nn.Module) -> int:
    """Number of trainable parameters (buffers such as BatchNorm statistics excluded)."""
    return sum(p.numel() for p in module.parameters() if p.requires_grad)


class CompletionModel(nn.Module):
    """Base class: a PCN encoder (``self.encoder``) and a decoder.

    Subclasses set ``name`` (registry key) and ``target`` (``"depths"`` for SA-Net,
    ``"points"`` for the baselines) and implement :meth:`forward`, :meth:`loss`
    and :meth:`complete`.
    """

    name: ClassVar[str] = ""
    target: ClassVar[str] = "points"
    encoder: PCNEncoder

    def forward(self, partial: torch.Tensor) -> dict[str, torch.Tensor]:  # pragma: no cover - abstract
        """partial (B, K, 3) unit frame -> dict of raw outputs (``"points"`` or ``"depths"``, ...)."""
        raise NotImplementedError

    def loss(self, outputs: dict[str, torch.Tensor], batch: dict[str, torch.Tensor], progress: float = 1.0):
        """Training loss (scalar tensor) and a dict of float terms to log.

        ``progress`` in [0, 1] is the share of training done (for schedules such as PCN's alpha).
        """
        raise NotImplementedError  # pragma: no cover - abstract

    needs_box: bool = False
    """True when decoding needs each sample's box (SA-Net on a box-targeted rig): pass ``directions``."""

    uses_evidence: bool = False
    """True when :meth:`forward` also takes each scan's ray directions and sensor origin (``sanet-local``)."""

    def forward_inputs(self, batch: dict, rays=None) -> tuple:
        """The positional arguments of :meth:`forward` for a training or validation batch: ``(partial,)``
        (models with evidence add each scan's ray directions, from ``rays`` (a
        :class:`~spotlights.learning.rays.DirectionTable` or None), and its sensor origin)."""
        return (batch["partial"],)

    def outputs_to_points(
        self, outputs: dict[str, torch.Tensor], clip=CLIP_DEFAULT, directions: torch.Tensor | None = None
    ) -> list[torch.Tensor]:
        """Completed clouds from :meth:`forward` outputs: list of B tensors (K_b, 3) float32, unit frame.

        ``clip`` and ``directions`` only matter for SA-Net (depth threshold, ``None`` keeps
        every ray with depth > 0; per-sample ray directions (B, N*M, 3), required with a
        box-targeted rig); point models return all their points and ignore both.
        """
        return list(outputs["points"].detach().float().unbind(0))

    @torch.no_grad()
    def complete(
        self, partial: torch.Tensor, clip=CLIP_DEFAULT, directions: torch.Tensor | None = None
    ) -> list[torch.Tensor]:
        """partial (B, K, 3) unit frame -> list of B completed clouds (K_b, 3) float32, unit frame.

        ``directions``: see :meth:`outputs_to_points` (box-targeted SA-Net only)."""
        return self.outputs_to_points(self.forward(partial), clip, directions)

    def param_counts(self) -> dict[str, int]:
        """{"encoder": ..., "decoder": ..., "total": ...} trainable parameters (decoder = total - encoder)."""
        total = count_parameters(self)
        enc = count_parameters(self.encoder)
        return {"encoder": enc, "decoder": total - enc, "total": total}


def regular_grid(rows: int, cols: int, half_extent_rows: float, half_extent_cols: float) -> torch.Tensor:
    """(rows * cols, 2) float32 regular 2-D grid, row-major, on [-h_r, h_r] x [-h_c, h_c]."""
    r = torch.linspace(-half_extent_rows, half_extent_rows, rows) if rows > 1 else torch.zeros(1)
    c = torch.linspace(-half_extent_cols, half_extent_cols, cols) if cols > 1 else torch.zeros(1)
    rr, cc = torch.meshgrid(r, c, indexing="ij")
    return torch.stack([rr.reshape(-1), cc.reshape(-1)], dim=1)
