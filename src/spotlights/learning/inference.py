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

import contextlib
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ParameterError
from ..geometry.box_clamp import clamp_to_grown_boxes, grown_half_extents
from ..geometry.boxes import Box
from ..geometry.sampling import resample_set
from .checkpoint import PRETRAINED, load_checkpoint, model_from_checkpoint, resolve_checkpoint
from .completion_request import DEFAULT, CompletionRequest, accepts, mirrored
from .domain import LearnedDomain
from .fit import check_fit_options, fit_completions
from .rays import directions_for_extents, unit_extents


def _one_torch_thread_after_fork() -> None:
    """In a process forked from one whose torch ran on several threads (a ``multiprocessing`` pool of frames started
    with ``fork``, Linux's default): torch on one thread, as PyTorch's DataLoader workers do. GNU OpenMP's thread
    team does not survive a fork: the child's first multi-threaded torch operation waited forever (measured:
    ``complete_frame`` in such a child never returned, with or without the frame loop's threads; with one thread it does)."""
    import sys

    torch = sys.modules.get("torch")
    if torch is not None and torch.get_num_threads() > 1:
        torch.set_num_threads(1)


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_one_torch_thread_after_fork)

INPUT_POINTS = 256
"""Points per partial scan the models were trained with (the dataset's partial size)."""

RESAMPLE_METHODS = ("random", "fps")
DEFAULT_RESAMPLE = "random"
"""How a scan is brought to :data:`INPUT_POINTS` by default: a seeded random subset of its points
taken in a canonical (sorted) order, as the training data's partials are random subsets. The
same set of points gives the same input, whatever their order or file (see :func:`prepare_partial`)."""


def pretrained_checkpoint(name: str = "default") -> Path:
    """Path of a checkpoint shipped in the package by short name (``default``, ``paper``).

    See :func:`spotlights.learning.checkpoint.resolve_checkpoint`; raises
    :class:`~spotlights.errors.InputFileError` when this installation ships none.
    """
    if name not in PRETRAINED:
        raise ParameterError(f"unknown pretrained model {name!r}; choose one of {', '.join(PRETRAINED)}")
    return resolve_checkpoint(name)


def _rows(value: np.ndarray | None, n: int) -> np.ndarray | None:
    """``value`` as (n, 3) float32 rows (one (3,) row repeated), or None."""
    return None if value is None else np.broadcast_to(np.asarray(value, dtype=np.float32).reshape(-1, 3), (n, 3))


class BaseCompleter:
    """What every completer shares, whatever runs its network (torch: :class:`Completer`; onnxruntime:
    :class:`~spotlights.learning.export.OnnxCompleter`): the input checks, the box handling (each scan's
    rays aimed at its own box), batching, and :meth:`complete_boxes` (clamped to the unit sphere). A
    runtime implements only :meth:`_forward`.

    Attributes (set by subclasses)
    ------------------------------
    model_name : registry key ("sanet", "pcn", ...). n_params : trainable parameters.
    param_counts : {"encoder", "decoder", "total"}. device : where it runs.
    clip : SA-Net's default clip threshold (None for the point models).
    rig : the SA-Net's :class:`~spotlights.geometry.rig.RigSpec` or None.
    threshold : the hit-aware SA-Net's p(hit) threshold, else None.
    needs_box : True when :meth:`complete` needs each scan's box (SA-Net on a box-targeted rig).
    domain : :class:`LearnedDomain`, the classes and box sizes the model learned.
    runtime : what runs the network, ``"torch"`` or ``"onnx"``. precision : the precision it runs at
    (``"fp32"``, ``"bf16"``, ``"fp16"``).
    """

    runtime: str = "torch"
    precision: str = "fp32"
    model_name: str
    n_params: int
    param_counts: dict
    rig: Any
    clip: float | None
    threshold: float | None
    needs_box: bool
    domain: LearnedDomain
    device: Any

    def complete(self, partials: np.ndarray | CompletionRequest, **options: Any) -> list[np.ndarray]:
        """Complete partial scans: ``complete(partials, clip=..., extents=..., ...)`` or
        ``complete(CompletionRequest(partials, ...))`` (the options are :class:`CompletionRequest`'s fields).

        Returns
        -------
        list of B arrays (K_i, 3) float32, unit frame. SA-Net: the kept rays in ray
        order (variable K_i); baselines: their 2048 points.
        """
        if isinstance(partials, CompletionRequest):
            if options:
                raise ParameterError(f"give the options in the request, not beside it: {', '.join(sorted(options))}")
            request = partials
        else:
            request = CompletionRequest(partials, **options)
        x = request.checked_partials()
        if x.shape[0] == 0:
            return []
        e = request.checked_extents(self, len(x))
        so = _rows(request.sensor_origins, len(x))
        bh = _rows(request.box_half, len(x))
        names = request.checked_classes(len(x))
        snap = request.checked_snap(self, len(x))
        out: list[np.ndarray] = []
        with self._session():
            for s in range(0, len(x), request.batch_size):
                chunk = slice(s, s + request.batch_size)
                dirs = None if e is None else directions_for_extents(self.rig, e[chunk])
                sb = None if so is None else np.array(so[chunk])
                kw: dict = {}
                if names is not None and accepts(self._forward, "classes"):
                    kw["classes"] = names[chunk]
                if bh is not None and accepts(self._forward, "box_half"):
                    kw["box_half"], kw["inside"] = np.array(bh[chunk]), request.inside
                if snap is not None:
                    kw["snap"] = request.snap_targets(x, chunk, snap, sb)
                out.extend(self._forward(x[chunk], request.clip, dirs, sb, **kw))
        return out

    def complete_boxes(self, partials: np.ndarray, sizes: np.ndarray, clip: Any = DEFAULT) -> list[np.ndarray]:
        """:func:`complete_in_boxes` with this completer: each scan with its box size (B, 3), every point clamped
        into the unit sphere."""
        return complete_in_boxes(self, partials, sizes, clip=clip)

    def _session(self) -> contextlib.AbstractContextManager:
        """The context every forward pass of one :meth:`complete` call runs in (torch: inference mode)."""
        return contextlib.nullcontext()

    def _forward(
        self,
        partials: np.ndarray,
        clip: Any,
        directions: np.ndarray | None,
        sensor_origins: np.ndarray | None = None,
        classes=None,
        box_half: np.ndarray | None = None,
        inside: list | None = None,
    ) -> list[np.ndarray]:
        """The network: (b, K, 3) float32 checked partials (and (b, N*M, 3) float32 ray directions for box rigs,
        (b, 3) float32 sensor origins in the unit frame for models that read free space, b class names, (b, 3)
        box half-extents to clip the rays to) -> b arrays (K_i, 3) float32, unit frame, with ``clip`` as
        :meth:`complete` takes it. A runtime that cannot condition on classes or clip to boxes ignores them
        (and leaves ``inside`` as it is)."""
        raise NotImplementedError


class Completer(BaseCompleter):
    """A trained completion model run with torch, ready for inference (eval mode, no gradients).

    Attributes: those of :class:`BaseCompleter`, and ``device`` (a torch device), ``checkpoint`` (the loaded
    checkpoint dict, weights included), ``precision``: ``"fp32"`` (default) or ``"bf16"``: the forward pass under
    bfloat16 autocast (weights stay float32; decoding in float32). On an AMD EPYC with avx512_bf16 (no AMX) it took
    2.0-2.6x less CPU per scan than fp32 (one thread, batch 1-32); the depths move by up to 0.02
    (docs/studies/speed.md).
    """

    def __init__(self, model: Any, checkpoint: dict, device: Any, precision: str = "fp32") -> None:
        from .device import resolve_precision

        self.model = model
        self.checkpoint = checkpoint
        self.device = device
        self.precision = resolve_precision(precision or "fp32", device)
        self.model_name = checkpoint["model_name"]
        self.param_counts = model.param_counts()
        self.n_params = int(self.param_counts["total"])
        self.rig = getattr(model, "rig", None)
        self.clip = getattr(model, "clip", None)
        self.threshold = getattr(model, "threshold", None)
        self.needs_box = bool(getattr(model, "needs_box", False))
        self.domain = LearnedDomain.from_checkpoint(checkpoint)
        self.classes = tuple(getattr(model, "classes", ()) or ())

    def __repr__(self) -> str:
        return f"Completer({self.model_name}, {self.n_params:,} parameters, {self.device})"

    def _session(self) -> contextlib.AbstractContextManager:
        import torch

        from .device import autocast

        stack = contextlib.ExitStack()
        stack.enter_context(torch.inference_mode())
        stack.enter_context(autocast(self.precision, self.device))
        return stack

    def _forward(
        self,
        partials: np.ndarray,
        clip: Any,
        directions: np.ndarray | None,
        sensor_origins: np.ndarray | None = None,
        classes=None,
        box_half: np.ndarray | None = None,
        inside: list | None = None,
        snap=None,
    ) -> list[np.ndarray]:
        import torch

        from .models.base import CLIP_DEFAULT

        t = torch.from_numpy(partials).to(self.device)
        dirs = None if directions is None else torch.from_numpy(np.ascontiguousarray(directions)).to(self.device)
        c = CLIP_DEFAULT if clip is DEFAULT else clip
        args = (t, c, dirs)
        if getattr(self.model, "uses_evidence", False):
            so = None if sensor_origins is None else np.ascontiguousarray(sensor_origins, dtype=np.float32)
            args += (None if so is None else torch.from_numpy(so).to(self.device),)
        kw: dict = {}
        if classes is not None and getattr(self.model, "class_embedding", None) is not None:
            kw["classes"] = self.model.class_indices(classes).to(self.device)
        if box_half is not None and hasattr(self.model, "clip_to_boxes"):
            kw["box_half"] = torch.from_numpy(np.ascontiguousarray(box_half, dtype=np.float32)).to(self.device)
            kw["inside"] = inside
        if snap is not None:
            if not hasattr(self.model, "snap_rays"):
                raise ParameterError(f"{self.model_name} has no rays to snap: snapping needs an SA-Net")
            kw["snap"] = snap
        return [p.cpu().numpy().astype(np.float32) for p in self.model.complete(*args, **kw)]


def load_completer(checkpoint_path=None, device=None, precision: str = "fp32") -> Completer:
    """Load a checkpoint as a :class:`Completer`.

    ``checkpoint_path``: a file, a short name (``"default"``, ``"paper"``, ``"classes"``) or None (the
    package's default model); see :func:`spotlights.learning.checkpoint.resolve_checkpoint`.
    ``device``: torch device or name; default CUDA when available, else CPU.
    ``precision``: ``"fp32"`` (default), ``"bf16"`` (autocast forward, faster on CPUs with native
    bfloat16) or ``"auto"`` (bf16 where supported).
    Raises :class:`InputFileError` for a missing/invalid checkpoint.
    """
    from .device import resolve_device

    dev = resolve_device(device)
    ckpt = load_checkpoint(checkpoint_path)
    model = model_from_checkpoint(ckpt, dev)
    return Completer(model, ckpt, dev, precision=precision)


# --- user scans ------------------------------------------------------------------------


def prepare_partial(
    points_unit: np.ndarray, n: int = INPUT_POINTS, seed: int = 0, method: str = DEFAULT_RESAMPLE
) -> np.ndarray:
    """The network input of one observation: its unit-frame points (K, 3) resampled to exactly ``n`` (float32).

    The points are first put in a canonical order (sorted by x, then y, then z), so the input
    depends only on the *set* of points and ``seed``: the same observation gives the same
    input, and so the same completion, whatever the order of its points or the file they came
    from. Then (``geometry.sampling.resample``): more points than ``n``: a random subset
    without replacement drawn with ``seed`` (``"random"``, the default: the training data's
    partials are random subsets) or farthest-point sampling started from a seeded point
    (``"fps"``); fewer: all points plus seeded random repeats (the encoders max-pool, so repeats
    change nothing). Another ``seed`` gives another subset: ``real evaluate``'s noise floor
    measures how much that alone moves a completion.
    """
    if method not in RESAMPLE_METHODS:
        raise ParameterError(f"unknown resampling method {method!r}; choose one of {', '.join(RESAMPLE_METHODS)}")
    return resample_set(np.asarray(points_unit, dtype=np.float64).reshape(-1, 3), n, seed=seed, method=method).astype(
        np.float32
    )


def complete_in_boxes(
    completer,
    partials: np.ndarray,
    sizes: np.ndarray,
    clip=DEFAULT,
    sensor_origins=None,
    inside: list | None = None,
    classes=None,
    snap: float | None = None,
    snap_mirror: bool = False,
    seen=None,
    fit=None,
    fitted: list | None = None,
) -> list[np.ndarray]:
    """Complete unit-frame partial scans, each with its box, every point inside its box grown by
    0.15 m and inside the box's sphere (``inside``, when given, gets each completion's share of points the
    network put in the grown box, before any clamp).

    SA-Nets clip every kept ray's depth to the grown box exactly along the ray at decoding
    (:meth:`~spotlights.learning.models.sanet.SANet.clip_to_boxes`); then every completion (the point
    models' too) is projected onto its grown box and into the unit sphere
    (:func:`~spotlights.geometry.box_clamp.clamp_to_grown_boxes`; a no-op for the clipped rays, up to float
    rounding). ``classes``: B class names for a class-conditioned model (the others ignore them).

    The step that the user-facing completions share (``complete_scan``; ``complete_scene``, so
    ``complete --boxes`` and ``real complete``): a box-targeted SA-Net (``completer.needs_box``) gets
    each scan's half-extents ``size / |size|``; the result is clamped to the unit sphere
    (:func:`clamp_to_unit_sphere`: point-set models are unbounded; depth models are inside
    already). The evaluations (``evaluate``, ``real evaluate``) score the models' outputs as they
    are, unclamped.

    Parameters
    ----------
    completer : a :class:`Completer` (or any object with its ``complete`` and ``needs_box``).
    partials : (B, K, 3) float32 unit-frame points (the box's object frame / half its diagonal).
    sizes : (B, 3) box sizes (length, width, height), metres.
    clip : passed to :meth:`Completer.complete`.
    sensor_origins : (B, 3) the LiDAR in each scan's unit frame, passed on to models that read free space and,
        with ``snap``, to every model (the occlusion rule).
    snap : radius (unit frame) to snap the SA-Nets' rays to each scan's partial (:meth:`Completer.complete`);
        None or 0: off. snap_mirror : also to its mirror image (``y -> -y``). seen : B arrays, the points each
        scan's LiDAR saw itself (the occlusion rule's free space; default the partials).
    fit : a :class:`~spotlights.learning.fit.FitSettings`: each completion fitted to its scan's evidence
        (:func:`~spotlights.learning.fit.fit_completions`; the observed points are ``seen``, default the partials);
        None: off. Not with ``snap``. fitted : a list that receives, per scan, whether the gate kept the fit.

    Returns a list of B arrays (K_i, 3) float32, unit frame, norms <= 1, inside the grown boxes.
    """
    if fit is not None:
        return _fitted_in_boxes(
            completer, partials, sizes, clip, sensor_origins, inside, classes, snap, seen, fit, fitted
        )
    kw = {"clip": clip}
    if snap:
        kw["snap"] = snap
    if snap_mirror:
        kw["snap_mirror"] = True  # without a radius, complete() says so
    if seen is not None:
        kw["seen"] = seen  # without a radius, complete() says so
    if sensor_origins is not None and (snap or getattr(getattr(completer, "model", None), "uses_evidence", False)):
        kw["sensor_origins"] = sensor_origins  # free space: the evidence of sanet-local, the snap's occlusion rule
    sz = np.asarray(sizes, dtype=np.float64).reshape(-1, 3)
    if getattr(completer, "needs_box", False):
        kw["extents"] = unit_extents(sz)
    if classes is not None and accepts(completer.complete, "classes"):
        kw["classes"] = list(classes)
    decoded: list[float] = []
    if len(sz) and getattr(completer, "rig", None) is not None and accepts(completer.complete, "box_half"):
        kw["box_half"], kw["inside"] = grown_half_extents(sz), decoded  # depth models: clipped along the rays
    done, shares = clamp_to_grown_boxes(completer.complete(partials, **kw), sizes)
    if inside is not None:
        inside.extend(decoded if len(decoded) == len(shares) else shares)
    return done


def _fitted_in_boxes(completer, partials, sizes, clip, sensor_origins, inside, classes, snap, seen, fit, fitted):
    """:func:`complete_in_boxes` with ``fit``: :func:`fit_in_boxes`, then clamped to the grown boxes."""
    res = fit_in_boxes(completer, partials, sizes, fit, clip, sensor_origins, classes, seen, snap, fitted)
    if res is None:
        return []
    done, _ = clamp_to_grown_boxes(res.clouds, sizes)
    if inside is not None:
        inside.extend(float(v) for v in res.inside)
    return done


def fit_in_boxes(
    completer, partials, sizes, fit, clip=DEFAULT, sensor_origins=None, classes=None, seen=None, snap=None, fitted=None
):
    """The evidence fit (:func:`spotlights.learning.fit.fit_completions`) of unit-frame ``partials`` (B, K, 3) in
    boxes of ``sizes`` (B, 3), metres, with ``fit`` (:class:`~spotlights.learning.fit.FitSettings`): its
    :class:`~spotlights.learning.fit.FitResult` (clouds as fitted, unclamped), None for no scan. ``seen``: the
    observed points (default the partials); ``fitted``, a list, receives per scan whether the gate kept the fit.
    A ``snap`` radius is refused (:class:`ParameterError`): the fit puts the rays near observed points itself."""
    check_fit_options(True, snap)
    x = np.asarray(partials, dtype=np.float32)
    sz = np.asarray(sizes, dtype=np.float64).reshape(-1, 3)
    if len(x) == 0:
        return None
    res = fit_completions(
        completer,
        x,
        unit_extents(sz),
        sensor_origins=sensor_origins,
        box_half=grown_half_extents(sz),
        classes=None if classes is None else list(classes),
        clip=clip,
        observed=seen,
        settings=fit,
    )
    if fitted is not None:
        fitted.extend(bool(v) for v in res.fitted)
    return res


def with_observed(completion: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """The keep-observed output: (K + L, 3) float32, the predicted points (K, 3) then the observed points (the
    model's input, repeats removed: L <= its rows), both unit frame (or both in any one frame)."""
    obs = np.unique(np.asarray(observed, dtype=np.float32).reshape(-1, 3), axis=0)
    return np.concatenate([np.asarray(completion, dtype=np.float32).reshape(-1, 3), obs])


def complete_scan(
    points: np.ndarray,
    box: Box,
    completer: Completer,
    clip=DEFAULT,
    crop: float | None = None,
    seed: int = 0,
    resample_method: str = DEFAULT_RESAMPLE,
    n_input: int = INPUT_POINTS,
) -> dict:
    """Complete one partial scan given in its own frame (sensor or world) with its box.

    Parameters
    ----------
    points : (K, 3) scan points in the box's frame (metres).
    box : the object's detector box in the same frame (:class:`spotlights.geometry.boxes.Box`).
    crop : if given, keep only points inside the box enlarged by this margin (metres
        per side) before completing; ``None`` keeps all points.
    seed, resample_method, n_input : resampling of the scan to the network's input size.

    Returns
    -------
    dict with ``completed`` (M, 3) float64 in the scan's frame, ``completed_unit`` (M, 3)
    float32 (inside the unit sphere, i.e. the box's circumscribed sphere: points of point-set
    models beyond it are moved radially onto it), ``partial_unit`` (n_input, 3) float32 (the network input), ``used_points``
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
        unit = unit[box.contains(pts, margin=float(crop))]
        if len(unit) == 0:
            raise ParameterError(
                "no scan point lies inside the box (after `crop`); check the box and the scan's frame", "crop"
            )
    partial = prepare_partial(unit, n_input, seed=seed, method=resample_method)
    done = complete_in_boxes(completer, partial[None], box.size[None], clip=clip)[0]
    return {
        "completed": norm.from_unit(done.astype(np.float64)),
        "completed_unit": done,
        "partial_unit": partial,
        "used_points": int(len(unit)),
        "normalization": norm,
    }


# the request and its helpers, importable from here too (spotlights.learning.completion_request holds them)
__all__ = [
    "DEFAULT",
    "DEFAULT_RESAMPLE",
    "INPUT_POINTS",
    "RESAMPLE_METHODS",
    "BaseCompleter",
    "Completer",
    "CompletionRequest",
    "accepts",
    "complete_in_boxes",
    "complete_scan",
    "load_completer",
    "mirrored",
    "prepare_partial",
    "pretrained_checkpoint",
    "with_observed",
]
