"""Evidence fitting at inference: an SA-Net's completion fitted to what its scan observed, a few steps per scan.

The network draws the shape it learned; the scan says where the surface is (observed points) and where it is
not (the beam from the LiDAR to each observed point is empty). :func:`fit_completions` moves each scan's
predicted depths toward that evidence with a fixed small budget of Adam steps, and keeps the result only where
it comes closer to the observed points (the gate). Everything is in the unit frame of each scan's box; a ray is
``P = o + 2 t u`` (:mod:`spotlights.geometry.evidence`).

What is optimised, per scan
---------------------------
* ``dc`` (C,): an offset of the encoder's global code (the decoder's input), initially 0 (Adam step size
  ``code_learning_rate``);
* ``r`` (R,): a per-ray depth residual (step size ``learning_rate``), starting from :func:`initial_residual`:
  each data ray's offset to its target, filled into the changed rays around it (``rings`` passes of neighbour
  means, from the data rays that were prior hits and move by at most ``radius``).

The fitted depth of a ray is ``decoder(code + dc) + r``; its hit decision is not optimised (the prior's hits,
plus the data rays below). Neighbours: the :attr:`FitSettings.neighbours` nearest rays of the same viewpoint
(:func:`ray_neighbours`).

Evidence (computed once from the unfitted prediction, reused by every step)
----------------------------------------------------------------------------
* **data rays**: the rays that :func:`spotlights.geometry.evidence.snap_to_observed` would snap at radius
  :attr:`FitSettings.radius` (occlusion rule included when the sensor is known), with its depth as target;
* **free space** (:class:`FreeSpace`): the LiDAR's angular grid of
  :func:`spotlights.geometry.evidence.carved_depths` (``carve_cells`` cells; a place is *carved*, observed
  empty, when its direction from the sensor falls in a cell that holds an observed point and it is nearer to
  the sensor than that cell's nearest point minus ``margin``). A kept ray *carries free-space evidence* when a
  carved place lies on it in front of (or at) its predicted point (``carve_samples`` samples per ray).

The rays that the fit may change (``changed``) are the evidence rays (data or free space) and every ray within
:attr:`FitSettings.rings` hops of one in the neighbour graph; **every other ray keeps the prior's depth and hit
exactly** (the code offset moves them too, so their fitted values are discarded).

Loss (a sum over scans of per-scan terms, so every scan's fit is independent of the others in its batch)
------------------------------------------------------------------------------------------------------------
Over the changed hits ``H`` (prior hits and data rays among the changed rays)::

    data_weight * mean_data huber(t - t*)                         (Huber, beta 0.01)
    + free_weight * sum_H relu(rho_cell - margin - |P - S|) / |H|   (the hinge: how deep in observed free space)
    + anchor_weight * mean_(H, not data) (t - t_prior)^2
    + smooth_weight * mean over neighbour pairs of H (r_i - r_j)^2
    + code_weight * mean dc^2

After the steps: the prior's hits plus the data rays, decoded as the completion is (the model's clip, each ray
clipped to its grown box); then every changed kept point still in observed free space moves along its ray to the
nearest place that is not (:func:`out_of_free_space`: steps of ``free_step``, at most ``free_tries`` each way,
inside the grown box) or is dropped: **no fitted point is in observed free space**. The gate (:func:`gate`)
keeps the fitted completion of a scan only when its fidelity to the observed points
(:func:`spotlights.metrics.consistency.fidelity`) is lower than the unfitted one's; else the scan's completion
is the unfitted one, bit for bit.

Budget: :data:`FIT_STEPS` steps by default (at most :data:`MAX_FIT_STEPS`); the candidates (data targets,
free-space grid, changed rays) are computed once per scan and reused by every step. Deterministic: no random
numbers; the same inputs and settings give the same bytes (on one device and thread count).
"""

from __future__ import annotations

import logging
import numbers
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError, parameter_names, shown
from ..metrics.consistency import fidelity
from .fit_evidence import FreeSpace, dilate, out_of_free_space, ray_neighbours
from .fit_targets import evidence_rays, leave_free_space
from .rays import directions_for_extents

LOG = logging.getLogger(__name__)

FIT_STEPS = 8
"""Adam steps per scan by default (``--fit-steps``)."""
MAX_FIT_STEPS = 50
"""Most steps a fit may take (``--fit-steps`` is refused above it)."""

FIT_DOC = (
    "SA-Nets run with torch: fit each object's completion to its scan for a few steps (the depths of the rays that "
    "pass near observed points pulled onto them, a smooth per-ray correction around them, no point left in the "
    "free space the LiDAR saw in front of its points), kept only where it comes closer to the observed points "
    "(lower fidelity); rays without evidence keep the model's shape; not with --snap; about 0.05-0.08 s of CPU per "
    "object; off by default: fidelity 2.4-3.8x lower on real scans, but less accurate on cars like the training "
    "ones and less consistent from frame to frame (docs/studies/fit.md)"
)
"""What ``--fit`` does (its help)."""

FIT_STEPS_DOC = f"with --fit: Adam steps per object, 1..{MAX_FIT_STEPS} (default {FIT_STEPS})"
"""``--fit-steps``'s help."""


@dataclass(frozen=True)
class FitSettings:
    """Settings of :func:`fit_completions` (lengths in the unit frame of each box: its half diagonal is 1).

    steps : Adam steps (1..:data:`MAX_FIT_STEPS`, default :data:`FIT_STEPS`). learning_rate, code_learning_rate :
    Adam's step sizes of the residual (normalised depth per step, roughly) and of the code offset.
    radius : data rays: rays passing within this of an observed point (the snap radius, 0.05 ~ 13 cm on a car).
    margin : free space ends this far in front of each observed point (LiDAR noise).
    neighbours : rays of the same viewpoint that smooth each ray's residual; rings : hops of that graph around
    the evidence rays that the fit may change. carve_cells : the sensor grid's G; carve_samples : samples per
    ray that find the rays crossing free space. free_step, free_tries : how a point left in free space is moved
    out (:func:`out_of_free_space`). The weights: see the module docstring. The defaults were chosen on the
    validation cars (docs/studies/fit.md).
    """

    steps: int = FIT_STEPS
    learning_rate: float = 0.002
    code_learning_rate: float = 0.001
    radius: float = 0.05
    margin: float = 0.02
    neighbours: int = 6
    rings: int = 1
    carve_cells: int = 32
    carve_samples: int = 16
    data_weight: float = 1.0
    free_weight: float = 1.0
    anchor_weight: float = 0.1
    smooth_weight: float = 1.0
    code_weight: float = 0.001
    free_step: float = 0.005
    free_tries: int = 16

    def __post_init__(self):
        for name in ("steps", "neighbours", "rings", "carve_cells", "carve_samples"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Integral):
                raise ParameterError(f"`{name}` must be a whole number, got {v!r}", name)
        check_fit_steps(self.steps, "steps")
        if not 1 <= self.neighbours <= 32 or not 0 <= self.rings <= 8:
            raise ParameterError(
                f"`neighbours` must be in 1..32 and `rings` in 0..8, got {self.neighbours}, {self.rings}",
                "neighbours",
                "rings",
            )
        if not 1 <= self.carve_cells <= 256 or not 1 <= self.carve_samples <= 64:
            raise ParameterError(
                "`carve_cells` must be in 1..256 and `carve_samples` in 1..64", "carve_cells", "carve_samples"
            )
        if (
            isinstance(self.free_tries, bool)
            or not isinstance(self.free_tries, numbers.Integral)
            or not (0 <= self.free_tries <= 256)
        ):
            raise ParameterError(
                f"`free_tries` must be a whole number in 0..256, got {self.free_tries!r}", "free_tries"
            )
        for name in ("learning_rate", "code_learning_rate", "radius", "free_step"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise ParameterError(f"`{name}` must be a finite number > 0, got {v!r}", name)
        for name in ("margin", "data_weight", "free_weight", "anchor_weight", "smooth_weight", "code_weight"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v >= 0):
                raise ParameterError(f"`{name}` must be a finite number >= 0, got {v!r}", name)


def check_fit_steps(steps, name: str = "fit_steps") -> int:
    """``steps`` as an int in 1..:data:`MAX_FIT_STEPS`, else :class:`ParameterError` naming ``name``."""
    if isinstance(steps, bool) or not isinstance(steps, numbers.Integral) or not 1 <= steps <= MAX_FIT_STEPS:
        raise ParameterError(
            f"{shown(name)} must be a whole number in 1..{MAX_FIT_STEPS}, got {steps!r}", *parameter_names(name)
        )
    return int(steps)


def check_fit_options(fit, snap: float | None) -> None:
    """Raise :class:`ParameterError` unless ``fit`` is True or False, and when it is True beside a ``snap`` radius
    (> 0): the fit puts the rays near observed points on them itself."""
    if not isinstance(fit, (bool, np.bool_)):
        raise ParameterError(f"`fit` must be True or False, got {fit!r}", "fit")
    if fit and snap:
        raise ParameterError(
            "`fit` does not go with `snap`: the fit puts the rays near observed points on them", "fit", "snap"
        )


def parse_fit_steps(text: str) -> int:
    """``--fit-steps`` text -> a step count in 1..:data:`MAX_FIT_STEPS` (:class:`ParameterError` otherwise)."""
    try:
        steps = int(text)
    except ValueError:
        raise ParameterError(f"expected a whole number in 1..{MAX_FIT_STEPS}, got {text!r}") from None
    if not 1 <= steps <= MAX_FIT_STEPS:
        raise ParameterError(f"expected a whole number in 1..{MAX_FIT_STEPS}, got {text!r}")
    return steps


def can_fit(completer) -> bool:
    """True when ``completer`` can be fitted: a torch :class:`~spotlights.learning.inference.Completer` of an
    SA-Net (a rig, a decoder of depths); an ONNX runtime or a point-set model cannot."""
    model = getattr(completer, "model", None)
    return (
        getattr(completer, "rig", None) is not None
        and model is not None
        and hasattr(model, "decoder")
        and hasattr(model, "kept_points")
        and hasattr(model, "encode")
    )


def require_fittable(completer, what: str = "fit") -> None:
    """Raise :class:`ParameterError` (naming ``what``) unless :func:`can_fit` ``completer``."""
    if not can_fit(completer):
        raise ParameterError(
            f"{shown(what)}: {getattr(completer, 'model_name', 'this model')} cannot be fitted: evidence fitting needs an "
            "SA-Net run with torch (not an ONNX file, not a point-set model)",
            *parameter_names(what),
        )


def _torch_depth_inside(torch, points, frames, extents, cells: int, limits, sensors, margin: float):
    """:meth:`FreeSpace.depth_inside` of B scans on tensors: points (B, R, 3), frames (B, 3, 3), extents (B,),
    limits (B, G*G) (-inf: empty), sensors (B, 3) (rows of unknown sensors: limits all -inf). Differentiable in
    ``points`` (the cell lookup is piecewise constant)."""
    rel = points - sensors[:, None]
    dist = torch.sqrt((rel * rel).sum(-1).clamp(min=1e-18))
    comp = torch.einsum("brj,bij->bri", rel, frames)
    den = dist + comp[..., 2]
    ok = den > 1e-9
    s = comp[..., :2] / torch.where(ok, den, torch.ones_like(den)).unsqueeze(-1)
    q = (s + extents[:, None, None]) / (2.0 * extents[:, None, None]) * cells
    inside = ok & (q >= 0).all(-1) & (q < cells).all(-1)
    idx = torch.floor(q.detach()).long().clamp(0, cells - 1)
    key = idx[..., 0] * cells + idx[..., 1]
    lim = torch.gather(limits, 1, key)
    depth = lim - margin - dist
    valid = inside & torch.isfinite(lim)
    return torch.where(valid, torch.relu(torch.where(valid, depth, torch.zeros_like(depth))), torch.zeros_like(depth))


@dataclass
class FitResult:
    """What :func:`fit_completions` returns (B scans, R rays, unit frames).

    clouds : B arrays (K_b, 3) float32: each scan's completion (the fitted one where ``fitted``, else the prior's).
    fitted : (B,) bool: the gate kept the fit. fidelity_prior, fidelity_fit : (B,) float64 fidelities of the two
    completions to the observed points (inf for an empty completion). evidence, changed : (B, R) bool: the
    evidence rays and the rays the fit may change (evidence grown by ``rings``). data : (B, R) bool data rays;
    target : (B, R) float32 their target depths (0 elsewhere).
    depth_prior, depth_fit : (B, R) float32 normalised depths as decoded (after the box clip); keep_prior,
    keep_fit : (B, R) bool the kept rays. inside : (B,) float32 each returned completion's share of kept rays
    inside its box before the clip.
    """

    clouds: list
    fitted: np.ndarray
    fidelity_prior: np.ndarray
    fidelity_fit: np.ndarray
    evidence: np.ndarray
    changed: np.ndarray
    data: np.ndarray
    target: np.ndarray
    depth_prior: np.ndarray
    depth_fit: np.ndarray
    keep_prior: np.ndarray
    keep_fit: np.ndarray
    inside: np.ndarray


def gate(fidelity_prior, fidelity_fit) -> np.ndarray:
    """(B,) bool: keep the fitted completion where its fidelity is finite and strictly lower than the prior's."""
    fp = np.asarray(fidelity_prior, dtype=np.float64)
    ff = np.asarray(fidelity_fit, dtype=np.float64)
    return np.isfinite(ff) & (ff < fp)


def _fidelity(observed: np.ndarray, cloud: np.ndarray) -> float:
    return float(fidelity(observed, cloud)) if len(cloud) else float("inf")


def fit_completions(
    completer,
    partials: np.ndarray,
    extents: np.ndarray,
    sensor_origins: np.ndarray | None = None,
    box_half: np.ndarray | None = None,
    classes=None,
    clip="default",
    observed=None,
    settings: FitSettings | None = None,
) -> FitResult:
    """Complete B scans with ``completer``'s SA-Net and fit each completion to its evidence (module docstring).

    Parameters
    ----------
    completer : a torch :class:`~spotlights.learning.inference.Completer` of an SA-Net (:func:`can_fit`).
    partials : (B, K, 3) float32 the network inputs, unit frame of each box.
    extents : (B, 3) box half-extents ``size / |size|`` (the rays of a box rig; ignored by a cap rig).
    sensor_origins : (B, 3) the LiDAR in each unit frame (None or NaN rows: unknown: no free space, and the data
        rays' occlusion rule is not applied).
    box_half : (B, 3) half-extents of each box grown by the clamp's margin (unit frame): kept rays clipped to it
        as :meth:`~spotlights.learning.models.sanet.SANet.clip_to_boxes` does; None: no clip.
    classes : B class names for a class-conditioned model (others ignore them).
    clip : the depth clip: a number in [0, 1]; None: none; anything else (``"default"``,
        :data:`~spotlights.learning.inference.DEFAULT`): the model's own.
    observed : B arrays (K_b, 3), the observed points the evidence and the gate use (default: the partials).
    settings : :class:`FitSettings` (default: its defaults).

    Runs in float32 whatever the completer's ``precision`` (the unfitted completion is the float32 one). Returns a
    :class:`FitResult`. Raises :class:`ParameterError` for a completer that cannot be fitted.
    """
    import torch

    require_fittable(completer)
    cfg = FitSettings() if settings is None else settings
    model = completer.model
    dev = completer.device
    x = np.ascontiguousarray(np.asarray(partials, dtype=np.float32).reshape(-1, np.shape(partials)[-2], 3))
    b_n = len(x)
    spec = model.rig
    r_n, m = spec.n_rays, spec.n_secondary
    dirs_np = directions_for_extents(spec, np.asarray(extents, dtype=np.float64).reshape(b_n, 3))
    obs = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in (x if observed is None else observed)]
    if len(obs) != b_n:
        raise ParameterError(f"{len(obs)} observed point sets for {b_n} scans", "observed")
    so = np.full((b_n, 3), np.nan) if sensor_origins is None else np.asarray(sensor_origins, np.float64).reshape(b_n, 3)
    own = clip is not None and (isinstance(clip, bool) or not isinstance(clip, numbers.Real))  # a marker
    c = model.clip if own else clip
    nbr = ray_neighbours(spec, cfg.neighbours)
    dirs = torch.from_numpy(np.array(dirs_np, dtype=np.float32)).to(dev)  # a copy: a cap rig's rays are a view
    bh = None if box_half is None else torch.from_numpy(np.asarray(box_half, np.float32).reshape(b_n, 3)).to(dev)
    cls = None
    if classes is not None and getattr(model, "class_embedding", None) is not None:
        cls = model.class_indices(classes).to(dev)
    hit_model = getattr(model, "outputs_per_ray", 1) == 2

    def depths_of(out):
        return out[..., r_n:] if hit_model else out

    code0, d0, keep0, prior = _prior(torch, model, x, cls, (c, dirs, bh), depths_of, hit_model, dev)

    origins = model.origins.detach().cpu().double().numpy()
    free = [FreeSpace.of(obs[b], so[b], cfg.carve_cells) for b in range(b_n)]
    dep_p = prior["depth"].cpu().double().numpy()
    keep_p = prior["keep"].cpu().numpy()
    data, target, evid_free = evidence_rays(obs, so, origins, dirs_np, dep_p, keep_p, free, m, cfg)
    evidence = data | evid_free
    changed = dilate(evidence, nbr, cfg.rings)

    fit_depth = _optimise(
        torch, model, code0, cls, d0, data, target, changed, keep_p, free, so, dirs, nbr, cfg, depths_of, dev
    )
    bh_np = None if box_half is None else np.asarray(box_half, np.float64).reshape(b_n, 3)
    rays = (origins, dirs_np, dirs)
    fit = _fitted_completion(torch, model, (d0, keep0), fit_depth, data, changed, free, rays, (c, bh, bh_np), cfg, dev)
    return _gated_result(obs, prior, fit, evidence, changed, data, target, keep_p)


def _fitted_completion(torch, model, start, fit_depth, data, changed, free, rays, clips, cfg: FitSettings, dev) -> dict:
    """The fitted completion after the steps: the ``changed`` rays take the fitted depths ``fit_depth`` (B, R)
    (the others keep the prior's, ``start`` = (depths, kept rays)), the prior's hits plus the ``data`` rays are
    decoded (:func:`_decode`; ``clips`` = (the depth clip, the box half-extents as a tensor and as an array)),
    then moved out of observed free space (:func:`~spotlights.learning.fit_targets.leave_free_space`; ``rays`` = (origins (R, 3), directions
    (B, R, 3) array and tensor)). Returns ``clouds`` (B arrays (K_b, 3) float32), ``decoded``, ``depth`` (B, R)
    and ``keep`` (B, R) bool."""
    d0, keep0 = start
    origins, dirs_np, dirs = rays
    clip, bh, bh_np = clips
    keep_f = keep0 | torch.from_numpy(data).to(dev)
    ch = torch.from_numpy(changed).to(dev)
    d_f = torch.where(ch, fit_depth, d0)
    with torch.no_grad():
        fitted_dec = _decode(model, d_f, keep_f, clip, dirs, bh)
    dep_np = fitted_dec["depth"].cpu().double().numpy()
    keep_fit = fitted_dec["keep"].cpu().numpy()
    leave_free_space(free, changed, keep_fit, dep_np, origins, dirs_np, bh_np, cfg)
    dep_f = torch.where(ch, torch.from_numpy(dep_np).to(dev, fitted_dec["depth"].dtype), fitted_dec["depth"])
    with torch.no_grad():
        pts_fit, mask_fit = model.decode(dep_f, None, dirs, keep=torch.from_numpy(keep_fit).to(dev))
    clouds_fit = [p[k].cpu().numpy().astype(np.float32) for p, k in zip(pts_fit, mask_fit)]
    return {"clouds": clouds_fit, "decoded": fitted_dec, "depth": dep_f, "keep": keep_fit}


def _prior(torch, model, x: np.ndarray, cls, decoding: tuple, depths_of, hit_model: bool, dev):
    """The unfitted prediction of the partials ``x`` (B, K, 3): the global codes, the activated depths (B, R), the
    kept rays (B, R) and :func:`_decode` 's completion with ``decoding`` = (clip, directions, box half-extents)."""
    clip, dirs, bh = decoding
    with torch.no_grad():
        xt = torch.from_numpy(x).to(dev)
        code0 = model.encode(xt, cls)
        out0 = model.add_template(model.decoder(code0), cls)
        d0 = _activated(model, depths_of(out0).float())
        if hit_model:
            keep0 = torch.sigmoid(out0[..., : model.rig.n_rays].float()) >= model.threshold
        else:
            keep0 = d0 > 0  # as SANet.outputs_to_points keeps them
        prior = _decode(model, d0, keep0, clip, dirs, bh)
    return code0, d0, keep0, prior


def _gated_result(obs, prior: dict, fit: dict, evidence, changed, data, target, keep_p) -> FitResult:
    """The :class:`FitResult`: each scan's fitted completion (``fit``: its ``clouds``, ``decoded`` (:func:`_decode`),
    ``depth``, ``keep``) where :func:`gate` keeps it over the ``prior``'s, by their fidelities to ``obs``."""
    b_n = len(obs)
    clouds_prior, clouds_fit = prior["clouds"], fit["clouds"]
    f_prior = np.array([_fidelity(obs[b], clouds_prior[b]) for b in range(b_n)])
    f_fit = np.array([_fidelity(obs[b], clouds_fit[b]) for b in range(b_n)])
    keep_it = gate(f_prior, f_fit)
    LOG.debug("fit: %d of %d scans kept the fit", int(keep_it.sum()), b_n)
    return FitResult(
        clouds=[clouds_fit[b] if keep_it[b] else clouds_prior[b] for b in range(b_n)],
        fitted=keep_it,
        fidelity_prior=f_prior,
        fidelity_fit=f_fit,
        evidence=evidence,
        changed=changed,
        data=data,
        target=target.astype(np.float32),
        depth_prior=prior["depth"].cpu().numpy().astype(np.float32),
        depth_fit=fit["depth"].cpu().numpy().astype(np.float32),
        keep_prior=keep_p,
        keep_fit=fit["keep"],
        inside=np.where(keep_it, fit["decoded"]["share"], prior["share"]).astype(np.float32),
    )


def _decode(model, depths, keep, clip, dirs, box_half) -> dict:
    """The completion as :meth:`SANet.kept_points` decodes it (the clip, then each kept ray clipped to its box):
    ``depth`` (B, R) and ``keep`` (B, R) as decoded, ``clouds`` (B arrays (K_b, 3) float32) and ``share`` (B,)
    each scan's share of kept rays inside its box before the box clip (1 without a box)."""
    mask = keep.clone()
    if clip is not None:
        mask &= depths >= float(clip)
    share = np.ones(len(depths))
    if box_half is not None:
        depths, mask, inside = model.clip_to_boxes(depths, mask, dirs, box_half)
        share = inside.cpu().numpy().astype(np.float64)
    pts, mask = model.decode(depths, None, dirs, keep=mask)
    clouds = [p[k].cpu().numpy().astype(np.float32) for p, k in zip(pts, mask)]
    return {"depth": depths, "keep": mask, "clouds": clouds, "share": share}


def initial_residual(
    prior: np.ndarray,
    target: np.ndarray,
    data: np.ndarray,
    hits: np.ndarray,
    changed,
    neighbours,
    rings: int,
    cap: float = np.inf,
) -> np.ndarray:
    """(B, R) float64 the residual the steps start from: on the data rays ``target - prior``; then ``rings`` passes
    in which every changed ray without a value takes the mean of its neighbours' values (the offsets of the data
    rays that were prior hits and moved by at most ``cap``: a prior miss's depth is not a surface, a large move is
    a jump to another surface); 0 elsewhere."""
    r = np.where(data, target - prior, 0.0)
    known = data & hits & (np.abs(r) <= cap)
    val = np.where(known, r, 0.0)
    for _ in range(int(rings)):
        cnt = known[..., neighbours].sum(-1)
        fill = changed & ~known & (cnt > 0)
        mean = val[..., neighbours].sum(-1) / np.maximum(cnt, 1)
        val = np.where(fill, mean, val)
        known = known | fill
    return np.where(data, r, np.where(changed, val, 0.0))


def _optimise(torch, model, code0, cls, d0, data, target, changed, hits, free, so, dirs, nbr, cfg, depths_of, dev):
    """The Adam steps (module docstring): (B, R) float32 fitted depths (before masking to the changed rays)."""
    b_n, r_n = d0.shape
    ch = torch.from_numpy(changed).to(dev)
    dt = torch.from_numpy(data).to(dev)
    hit = torch.from_numpy(hits | data).to(dev) & ch
    tgt = torch.from_numpy(target.astype(np.float32)).to(dev)
    nb = torch.from_numpy(np.array(nbr)).to(dev)
    pair = hit.unsqueeze(-1) & hit[:, nb]  # (B, R, k) neighbour pairs of changed hits
    n_pair = pair.sum((-1, -2)).clamp(min=1).float()
    g = free[0].cells
    frames = torch.from_numpy(np.stack([f.frame for f in free]).astype(np.float32)).to(dev)
    exts = torch.from_numpy(np.array([f.extent for f in free], dtype=np.float32)).to(dev)
    lims = torch.from_numpy(np.stack([f.limit for f in free]).astype(np.float32)).to(dev)
    sensors = torch.from_numpy(np.where(np.isfinite(so), so, 0.0).astype(np.float32)).to(dev)
    o = model.origins.to(dev).float()
    half = (-(o * dirs).sum(-1)).clamp(min=0.0)
    n_data = dt.sum(-1).clamp(min=1).float()
    anchor_rows = hit & ~dt
    n_anchor = anchor_rows.sum(-1).clamp(min=1).float()
    n_hit = hit.sum(-1).clamp(min=1).float()
    r0 = initial_residual(d0.cpu().double().numpy(), target, data, hits, changed, nbr, cfg.rings, cfg.radius)
    dc = torch.zeros_like(code0, requires_grad=True)
    res = torch.from_numpy(r0.astype(np.float32)).to(dev).requires_grad_(True)
    opt = torch.optim.Adam([{"params": [dc], "lr": cfg.code_learning_rate}, {"params": [res], "lr": cfg.learning_rate}])
    flags = [p.requires_grad for p in model.parameters()]
    for p in model.parameters():
        p.requires_grad_(False)
    try:
        with torch.enable_grad():
            for _ in range(cfg.steps):
                opt.zero_grad(set_to_none=False)
                d = _fitted_depth(model, code0, dc, res, cls, depths_of)
                huber = torch.nn.functional.smooth_l1_loss(d, tgt, reduction="none", beta=0.01)
                data_term = (huber * dt).sum(-1) / n_data
                pts = o + (2.0 * torch.minimum(d.clamp(min=0.0), half)).unsqueeze(-1) * dirs
                inside = _torch_depth_inside(torch, pts, frames, exts, g, lims, sensors, cfg.margin)
                free_term = (inside * hit).sum(-1) / n_hit
                anchor_term = (((d - d0) ** 2) * anchor_rows).sum(-1) / n_anchor
                smooth_term = (((res.unsqueeze(-1) - res[:, nb]) ** 2) * pair).sum((-1, -2)) / n_pair
                loss = (
                    cfg.data_weight * data_term
                    + cfg.free_weight * free_term
                    + cfg.anchor_weight * anchor_term
                    + cfg.smooth_weight * smooth_term
                    + cfg.code_weight * (dc * dc).mean(-1)
                ).sum()
                loss.backward()
                opt.step()
            with torch.no_grad():
                d = _fitted_depth(model, code0, dc, res, cls, depths_of)
    finally:
        for p, was in zip(model.parameters(), flags):
            p.requires_grad_(was)
    return d.detach().float()


def _fitted_depth(model, code0, dc, res, cls, depths_of):
    """(B, R) the decoder's depths of the code ``code0 + dc`` (its output activation applied) plus ``res``."""
    return _activated(model, depths_of(model.add_template(model.decoder(code0 + dc), cls)).float()) + res


def _activated(model, d):
    """The depths ``d`` after the model's output activation (:class:`~spotlights.learning.models.sanet.SANet`'s
    ``output_activation``: none, ReLU or sigmoid; the hit-aware SA-Net has none)."""
    import torch

    act = getattr(model, "output_activation", "none")
    if act == "relu":
        return torch.relu(d)
    if act == "sigmoid":
        return torch.sigmoid(d)
    return d


__all__ = [
    "FIT_DOC",
    "FIT_STEPS",
    "FIT_STEPS_DOC",
    "MAX_FIT_STEPS",
    "FitResult",
    "FitSettings",
    "FreeSpace",
    "can_fit",
    "check_fit_steps",
    "dilate",
    "fit_completions",
    "gate",
    "initial_residual",
    "parse_fit_steps",
    "out_of_free_space",
    "ray_neighbours",
    "require_fittable",
]
