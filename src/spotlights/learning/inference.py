"""Inference: the :class:`Completer` interface and completion of a user's partial scan.

``load_completer(checkpoint_path, device=None) -> Completer`` (the contract used
by the real-data and reproduce layers)::

    c = load_completer("runs/sanet/best.pt")
    c.model_name, c.n_params
    clouds = c.complete(partials)          # partials (B, 256, 3) float32, unit frame
    # -> list of B arrays (K_i, 3) float32, unit frame (SA-Net drops clipped/missed rays)
    c.needs_box                            # True for SA-Net on a box-targeted rig: then
    clouds = c.complete(partials, extents=E)   # E (B, 3) = box size / |size| per scan

:func:`complete_scan` takes a scan in any frame plus its detector box, normalises
it into the box's unit frame (``normalization_from_box``), resamples it to the
network's input size, completes it and maps the result back into the scan's frame.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import InputFileError, ParameterError, SpotlightsError

INPUT_POINTS = 256
"""Points per partial scan the models were trained with (the dataset's partial size)."""

PRETRAINED_NAME = "sanet.pt"


def pretrained_checkpoint() -> Path:
    """Path of the SA-Net checkpoint shipped in the package (``spotlights/learning/pretrained/sanet.pt``).

    Raises :class:`SpotlightsError` when this installation ships none.
    """
    p = Path(str(resources.files("spotlights.learning") / "pretrained" / PRETRAINED_NAME))
    if not p.is_file():
        raise SpotlightsError(f"no pretrained checkpoint is shipped in this installation ({p}); pass --checkpoint CKPT "
                              "(train one with 'spotlights train --model sanet --data DATASET.h5')")
    return p


class _Default:
    def __repr__(self):
        return "default"


DEFAULT = _Default()
"""Sentinel for "the model's configured clip" (SA-Net: 0.2)."""


class Completer:
    """A trained completion model ready for inference (eval mode, no gradients).

    Attributes
    ----------
    model_name : registry key ("sanet", "pcn", ...). n_params : trainable parameters.
    param_counts : {"encoder", "decoder", "total"}. device : torch device.
    clip : SA-Net's default clip threshold (None for the point models).
    rig : the SA-Net's :class:`~spotlights.geometry.rig.RigSpec` (cap or box-targeted; a cap spec's
        rays are ``rig.for_box(None)``) or None.
    threshold : the hit-aware SA-Net's p(hit) threshold (chosen on validation, stored in the
        checkpoint), else None.
    needs_box : True when :meth:`complete` needs each scan's box (SA-Net on a box-targeted rig).
    checkpoint : the loaded checkpoint dict (weights included).
    """

    def __init__(self, model, checkpoint: dict, device):
        self.model = model
        self.checkpoint = checkpoint
        self.device = device
        self.model_name = checkpoint["model_name"]
        self.param_counts = model.param_counts()
        self.n_params = int(self.param_counts["total"])
        self.rig = getattr(model, "rig", None)
        self.clip = getattr(model, "clip", None)
        self.threshold = getattr(model, "threshold", None)
        self.needs_box = bool(getattr(model, "needs_box", False))

    def __repr__(self):
        return f"Completer({self.model_name}, {self.n_params:,} parameters, {self.device})"

    def complete(self, partials: np.ndarray, clip=DEFAULT, batch_size: int = 256, extents=None) -> list[np.ndarray]:
        """Complete partial scans.

        Parameters
        ----------
        partials : (B, K, 3) float32 unit-frame points (K = 256 as in training; any K >= 1
            works, the encoder max-pools), or one (K, 3) scan.
        clip : SA-Net depth threshold: default = the checkpoint's (0.2), ``None`` = keep
            every ray with depth > 0. Ignored by the point models. The hit-aware SA-Net keeps
            the rays with p(hit) >= its stored threshold (:attr:`threshold`); its default clip is none.
        batch_size : forward passes are chunked to this many scans.
        extents : (B, 3) (or (3,) for all) box half-extents of each scan in its unit frame,
            ``size / |size|`` for a box of size (l, w, h) (:func:`~spotlights.learning.rays.extents_from_sizes`).
            Required when :attr:`needs_box` (SA-Net on a box-targeted rig: each scan decodes
            with the rays aimed at its own box); ignored otherwise.

        Returns
        -------
        list of B arrays (K_i, 3) float32, unit frame. SA-Net: the kept rays in ray
        order (variable K_i); baselines: their 2048 points.
        """
        import torch

        from .models.base import CLIP_DEFAULT

        x = np.asarray(partials, dtype=np.float32)
        if x.ndim == 2:
            x = x[None]
        if x.ndim != 3 or x.shape[-1] != 3:
            raise ParameterError(f"partials must have shape (B, K, 3), got {x.shape}")
        if x.shape[0] == 0:
            return []
        if x.shape[1] == 0:
            raise ParameterError("partial scans are empty (K = 0 points)")
        if not np.all(np.isfinite(x)):
            raise ParameterError("partial scans contain NaN or infinite coordinates")
        c = CLIP_DEFAULT if clip is DEFAULT else clip
        e = None
        if self.needs_box:
            if extents is None:
                raise ParameterError(f"this SA-Net regresses the box-targeted rig {self.rig.name}: give each scan's box "
                                     "half-extents (extents = size / |size|)")
            e = np.asarray(extents, dtype=np.float64)
            e = np.broadcast_to(e, (len(x), 3)) if e.shape == (3,) else e
            if e.shape != (len(x), 3):
                raise ParameterError(f"extents must have shape ({len(x)}, 3) or (3,), got {np.shape(extents)}")
        out: list[np.ndarray] = []
        with torch.inference_mode():
            for s in range(0, len(x), batch_size):
                t = torch.from_numpy(x[s:s + batch_size]).to(self.device)
                dirs = None
                if e is not None:
                    from .rays import directions_for_extents

                    d = directions_for_extents(self.rig, e[s:s + batch_size])
                    dirs = torch.from_numpy(np.ascontiguousarray(d)).to(self.device)
                out.extend(p.cpu().numpy().astype(np.float32) for p in self.model.complete(t, c, dirs))
        return out


def load_completer(checkpoint_path=None, device=None) -> Completer:
    """Load a checkpoint (default: the shipped SA-Net) as a :class:`Completer`.

    ``device``: torch device or name; default CUDA when available, else CPU.
    Raises :class:`InputFileError` for a missing/invalid checkpoint.
    """
    from .checkpoint import load_checkpoint, model_from_checkpoint
    from .device import resolve_device

    path = pretrained_checkpoint() if checkpoint_path is None else checkpoint_path
    dev = resolve_device(device)
    ckpt = load_checkpoint(path)
    model = model_from_checkpoint(ckpt, dev)
    return Completer(model, ckpt, dev)


# --- boxes and user scans -----------------------------------------------------------

@dataclass(frozen=True)
class Box:
    """An oriented detector box in the scan's frame.

    center : (3,) geometric centre; size : (3,) length, width, height along the box's
    x (forward), y (left), z (up); yaw : heading in radians about the scan's z axis.
    """

    center: tuple
    size: tuple
    yaw: float = 0.0

    def normalization(self):
        """The :class:`~spotlights.geometry.frames.Normalization` scan frame -> unit frame (R = half diagonal)."""
        from ..geometry.frames import normalization_from_box

        return normalization_from_box(np.asarray(self.center, float), np.asarray(self.size, float), float(self.yaw))

    def to_dict(self) -> dict:
        return {"center": list(map(float, self.center)), "size": list(map(float, self.size)), "yaw": float(self.yaw)}


def _vec3(value, what: str, src) -> tuple:
    try:
        v = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise InputFileError(src, f"box {what} must be three finite numbers, got {value!r}")
    return tuple(float(a) for a in v)


def box_from_dict(d: dict, src="box") -> Box:
    """A :class:`Box` from ``{"center": [x, y, z], "size": [l, w, h], "yaw": radians}``.

    ``yaw_deg`` (degrees) may replace ``yaw``; ``"dimensions"``/``"extent"`` may replace ``"size"``.
    """
    if not isinstance(d, dict):
        raise InputFileError(src, "a box must be a JSON object with center, size and yaw")
    if "center" not in d:
        raise InputFileError(src, "box has no 'center' [x, y, z]")
    size = d.get("size", d.get("dimensions", d.get("extent")))
    if size is None:
        raise InputFileError(src, "box has no 'size' [length, width, height]")
    if "yaw_deg" in d:
        yaw = np.deg2rad(float(d["yaw_deg"]))
    else:
        yaw = d.get("yaw", 0.0)
    try:
        yaw = float(yaw)
    except (TypeError, ValueError):
        raise InputFileError(src, f"box yaw must be a number of radians, got {yaw!r}") from None
    if not np.isfinite(yaw):
        raise InputFileError(src, "box yaw must be finite")
    center, size = _vec3(d["center"], "center", src), _vec3(size, "size", src)
    if min(size) < 0 or max(size) <= 0:
        raise InputFileError(src, f"box size must be non-negative and not all zero, got {list(size)}")
    return Box(center, size, yaw)


def load_box(path) -> Box:
    """Read a box JSON file (see :func:`box_from_dict`)."""
    p = Path(path)
    if not p.is_file():
        raise InputFileError(p, "no such box file")
    try:
        d = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputFileError(p, f"not valid JSON ({exc})") from None
    return box_from_dict(d, p)


def prepare_partial(points_unit: np.ndarray, n: int = INPUT_POINTS, seed: int = 0, method: str = "random") -> np.ndarray:
    """Resample a unit-frame scan (K, 3) to exactly ``n`` points (float32).

    More points: farthest-point sampling (``"fps"``) or a random subset (``"random"``);
    fewer: all points plus seeded random repeats (see ``geometry.sampling.resample``).
    """
    from ..geometry.sampling import resample

    return resample(np.asarray(points_unit, dtype=np.float64), n, seed=seed, method=method).astype(np.float32)


def complete_scan(points: np.ndarray, box: Box, completer: Completer, clip=DEFAULT, crop: float | None = None,
                  seed: int = 0, resample_method: str = "random", n_input: int = INPUT_POINTS) -> dict:
    """Complete one partial scan given in its own frame (sensor or world) with its box.

    Parameters
    ----------
    points : (K, 3) scan points in the box's frame (metres).
    box : the object's detector box in the same frame.
    crop : if given, keep only points inside the box enlarged by this margin (metres
        per side) before completing; ``None`` keeps all points.
    seed, resample_method, n_input : resampling of the scan to the network's input size.

    Returns
    -------
    dict with ``completed`` (M, 3) float64 in the scan's frame, ``completed_unit`` (M, 3)
    float32, ``partial_unit`` (n_input, 3) float32 (the network input), ``used_points``
    (number of scan points used), ``normalization`` (scan -> unit).

    Raises :class:`ParameterError` for an empty scan (or empty after cropping) or NaNs.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ParameterError(f"scan must be (K, 3) points, got shape {pts.shape}")
    if len(pts) == 0:
        raise ParameterError("the scan is empty (no points)")
    if not np.all(np.isfinite(pts)):
        raise ParameterError("the scan contains NaN or infinite coordinates")
    norm = box.normalization()
    unit = norm.to_unit(pts)
    if crop is not None:
        local = (pts - norm.center) @ norm.rotation
        half = np.asarray(box.size, float) / 2 + float(crop)
        unit = unit[np.all(np.abs(local) <= half, axis=1)]
        if len(unit) == 0:
            raise ParameterError("no scan point lies inside the box (after --crop); check the box and the scan's frame")
    partial = prepare_partial(unit, n_input, seed=seed, method=resample_method)
    if getattr(completer, "needs_box", False):  # box-targeted SA-Net: rays aimed at this box
        from .rays import extents_from_sizes

        done = completer.complete(partial[None], clip=clip, extents=extents_from_sizes(box.size)[None])[0]
    else:
        done = completer.complete(partial[None], clip=clip)[0]
    return {
        "completed": norm.from_unit(done.astype(np.float64)),
        "completed_unit": done,
        "partial_unit": partial,
        "used_points": int(len(unit)),
        "normalization": norm,
    }
