"""The rays a depth-regressing model (SA-Net) decodes with: fixed for cap rigs, per sample for box rigs.

SA-Net predicts N*M depths and decodes them as ``P = o + 2 depth d`` (unit frame).
With the paper's cap rig the rays ``(o, d)`` are the same for every object, so the
model keeps them as constants. With a box-targeted rig (docs/box-rig.md) the
origins are still the same for every object, but the directions depend on the
object's box: sample b decodes with ``spec.for_box(e_b).directions``, where
``e_b = size_b / (2 R_b)`` are the box half-extents in the sample's unit frame
(``|e| = 1``). For a detector box of size ``(l, w, h)`` that is ``size / |size|``.

This module is the only place of the learning layer that turns rig descriptions
into rays (it uses :mod:`spotlights.geometry.rig`); the models receive the rays as
tensors: a constant ``(N*M, 3)`` origin buffer, and either a constant direction
buffer (cap rigs) or a ``(B, N*M, 3)`` direction tensor per batch (box rigs).
"""

from __future__ import annotations

import collections

import numpy as np

from ..errors import ParameterError
from ..geometry.boxes import unit_extents
from ..geometry.rig import Rig, RigSpec


def rig_spec(rig):
    """The :class:`~spotlights.geometry.rig.RigSpec` of a rig description (the form rigs travel in learning).

    ``rig``: a ``RigSpec``, a ``Rig`` (its spec), a dict (``RigSpec.to_dict()`` / ``Rig.to_dict()``,
    a box entry is dropped: every sample decodes with its own box: the ``rig`` entry of a
    checkpoint or a dataset's ``rig_json``), or None (returned as None). A cap spec's ``to_dict()``
    is exactly its rig's, so checkpoints written with either read back alike.
    """
    if rig is None or isinstance(rig, RigSpec):
        return rig
    if isinstance(rig, Rig):
        return rig.spec
    if not isinstance(rig, dict):
        raise ParameterError(f"a rig description must be a RigSpec, a Rig or a dict, got {type(rig).__name__}")
    return RigSpec.from_dict(rig)


def rig_needs_box(rig) -> bool:
    """True when ``rig`` (a dict, Rig or RigSpec) is box-targeted, i.e. decoding needs each sample's box."""
    return rig_spec(rig).needs_box


def rig_rays(rig) -> tuple[np.ndarray, np.ndarray | None]:
    """Constant rays of a rig: ``(origins (N*M, 3) float32, directions (N*M, 3) float32)``, unit frame.

    Box-targeted rigs return ``directions = None`` (they depend on each sample's box:
    :func:`directions_for_extents`).
    """
    spec = rig_spec(rig)
    origins = spec.origins.astype("float32")
    if spec.needs_box:
        return origins, None
    return origins, spec.for_box(None).directions.astype("float32")


def directions_for_extents(rig, extents) -> np.ndarray:
    """Per-sample ray directions: (B, N*M, 3) float32 unit vectors, unit frame.

    rig : dict / Rig / RigSpec. extents : (B, 3) box half-extents ``size / 2R`` (``|e| = 1``).
    Row b equals ``spec.for_box(extents[b]).directions`` (cap rigs: the fixed rays, broadcast).
    """
    spec = rig_spec(rig)
    e = np.asarray(extents, dtype=np.float64).reshape(-1, 3)
    if not spec.needs_box:  # cap rig: the same rays for every sample
        return np.broadcast_to(spec.for_box(None).directions.astype("float32"), (len(e), spec.n_rays, 3))
    # a tracked object keeps its box size from frame to frame: its rays are computed once (exact extents as key)
    keys = [(repr(spec), row.tobytes()) for row in e]
    missing = [k for k, key in enumerate(keys) if key not in _RAYS]
    if missing:
        fresh = spec.directions_for_boxes(e[missing]).astype("float32")
        for k, d in zip(missing, fresh):
            _RAYS[keys[k]] = d
            _RAYS.move_to_end(keys[k])
        while len(_RAYS) > RAY_CACHE_SIZE:
            _RAYS.popitem(last=False)
    return np.stack([_RAYS[key] for key in keys])


#: Box rigs' rays kept by :func:`directions_for_extents` (least recently computed dropped first); 196 kB each
#: at 16,384 rays.
RAY_CACHE_SIZE = 128
_RAYS: collections.OrderedDict = collections.OrderedDict()


class DirectionTable:
    """Per-model ray directions of a box-targeted rig over a dataset's models, computed once per model.

    Parameters
    ----------
    rig : the model's rig (dict / Rig / RigSpec).
    extents : (n_models, 3) float64 half-extents of every model's box (``size / 2R``), or
        None (only allowed for cap rigs).

    ``table.directions(models)`` with a (B,) int64 tensor of model rows returns a
    (B, N*M, 3) float32 tensor on ``models``' device, or None for cap rigs (the model
    uses its constant rays). Rows are computed on first use and kept (float32,
    12 bytes per ray and model), so a training run computes each model's rays once.
    """

    def __init__(self, rig, extents: np.ndarray | None):
        self.rig = rig_spec(rig)
        self.needs_box = self.rig.needs_box
        self.extents = None if extents is None else np.asarray(extents, dtype=np.float64).reshape(-1, 3)
        if self.needs_box and self.extents is None:
            raise ParameterError(f"rig {self.rig.name} is aimed at each object's box, but the data gives no box sizes")
        self._rows: dict = {}
        self._device_cache: dict = {}

    def directions(self, models):
        """(B, N*M, 3) float32 tensor of the rays of model rows ``models`` (a (B,) tensor), or None for cap rigs."""
        import torch

        if not self.needs_box:
            return None
        rows = models.detach().cpu().numpy().astype(np.int64).reshape(-1)
        new = sorted(set(rows.tolist()) - set(self._rows))
        if new:
            if min(new) < 0 or max(new) >= len(self.extents):
                raise ParameterError(f"model row {max(new)} has no box (the table holds {len(self.extents)} models)")
            d = directions_for_extents(self.rig, self.extents[new])
            for m, dm in zip(new, d):
                self._rows[m] = torch.from_numpy(np.ascontiguousarray(dm))
            self._device_cache.clear()
        dev = models.device
        key = str(dev)
        if key not in self._device_cache:
            order = sorted(self._rows)
            self._device_cache[key] = (
                torch.stack([self._rows[m] for m in order]).to(dev),
                {m: i for i, m in enumerate(order)},
            )
        stacked, index = self._device_cache[key]
        idx = torch.as_tensor([index[m] for m in rows.tolist()], dtype=torch.int64, device=dev)
        return stacked.index_select(0, idx)


TIMING_BOX_SIZE = (4.6, 1.9, 1.6)
"""A typical car's box (length, width, height, metres): the box latency measurements decode with."""


def timing_directions(model, batch: int):
    """Rays for timing a model on random input: None for models with constant rays; for a
    box-rig SA-Net (``model.needs_box``) the (batch, N*M, 3) float32 torch tensor of
    :data:`TIMING_BOX_SIZE` (one box for every sample; the decoding cost does not depend on it)."""
    if not getattr(model, "needs_box", False):
        return None
    import torch

    e = np.tile(unit_extents(TIMING_BOX_SIZE), (int(batch), 1))
    return torch.from_numpy(np.ascontiguousarray(directions_for_extents(model.rig, e)))
