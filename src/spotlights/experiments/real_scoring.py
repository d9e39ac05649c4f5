"""The scoring behind :func:`spotlights.experiments.real_evaluation.evaluate_consistency`: completing tracked real
observations and scoring one model's completions.

:func:`complete_all` runs a completer over observations in batches (boxes, sensor origins, classes and snapping
handed on to the completers that use them); :func:`equal_count` and :func:`flip_heading` are the resampling and the
turned-around input of the report's equal-count consistency and heading check. The private part builds the tracked
observations one evaluation shares and one model's report entry: consistency (as the paper computes it, at equal
counts and at equal density), the resampling noise floor, fidelity, MMD, diversity, heading flips and out-of-domain
counts (see the module docstring of :mod:`spotlights.experiments.real_evaluation`). Every public name here is also
importable from :mod:`spotlights.experiments.real_evaluation`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..completion.frame import heading_turns, snap_options
from ..data.real.base import CLASSES
from ..data.real.extract import Observations
from ..errors import SpotlightsError
from ..geometry.box_clamp import GROWN_BOX_MARGIN, grown_half_extents
from ..geometry.boxes import FLIP_Z, unit_extents
from ..geometry.neighbors import NearestNeighbors, serial_queries
from ..geometry.sampling import resample_set, voxel_downsample
from ..learning.completion_request import DEFAULT
from ..learning.fit import can_fit
from ..learning.inference import fit_in_boxes
from ..metrics.consistency import (
    aggregate,
    diversity,
    fidelity,
    minimal_matching_distance,
    same_observation_cd,
    track_consistency,
)

if TYPE_CHECKING:
    from .real_evaluation import RealEvaluationSettings

EQUAL_POINTS = 512
"""Common point count of the equal-count consistency (farthest-point sampling of every completion)."""

EQUAL_DENSITY = 0.1
"""Voxel side (unit frame: the box's half diagonal) of the equal-density consistency: about 300-600 cells on a car's
completion, the scale of the sparsest models' outputs."""


def complete_all(
    completer,
    partials: np.ndarray,
    batch_size: int = 64,
    progress: bool = True,
    desc: str = "complete",
    clip: float | None = None,
    box_sizes: np.ndarray | None = None,
    sensor_origins: np.ndarray | None = None,
    classes=None,
    snap: float | None = None,
    snap_mirror: bool = False,
    fit=None,
    fitted: list | None = None,
) -> list[np.ndarray]:
    """Run ``completer.complete`` over (n, P, 3) float32 partials in batches; returns n (K_i, 3) float32 arrays.

    ``clip`` is passed on as ``complete(batch, clip=clip)`` only when given (else the model's default).
    ``box_sizes`` (n, 3): each observation's box (l, w, h); completers with ``needs_box``
    (SA-Net on a box-targeted rig) get ``extents = size / |size|`` per observation, the
    half-extents of the box in the observation's unit frame. Others never see it.
    ``sensor_origins`` (n, 3): the LiDAR in each observation's unit frame, for models that read free
    space (``sanet-local``; NaN rows: unknown) and for ``snap``'s occlusion rule; others never see it.
    ``classes`` (n,): each observation's class, for class-conditioned models (others never see it).
    ``snap``: radius (unit frame) of snapping each completion's rays to its partial (SA-Nets; None: off), with
    ``snap_mirror`` to its mirror image too. ``fit``: a :class:`~spotlights.learning.fit.FitSettings`: each
    completion fitted to its partial's evidence (:func:`~spotlights.learning.fit.fit_completions`, needs
    ``box_sizes``; outputs as they are, unclamped); ``fitted`` receives per observation whether the fit was kept.
    """
    from tqdm import tqdm

    out: list[np.ndarray] = []
    n = len(partials)
    extents = None
    if getattr(completer, "needs_box", False):
        if box_sizes is None:
            raise SpotlightsError(
                f"completer {getattr(completer, 'model_name', '?')} decodes rays aimed at each object's "
                "box: give the boxes' sizes"
            )
        extents = unit_extents(np.asarray(box_sizes, dtype=np.float64).reshape(n, 3))
    for s in tqdm(range(0, n, batch_size), desc=desc, unit="batch", disable=not progress or n == 0):
        batch = np.ascontiguousarray(partials[s : s + batch_size], dtype=np.float32)
        kw = {} if clip is None else {"clip": clip}
        if extents is not None:
            kw["extents"] = extents[s : s + batch_size]
        if sensor_origins is not None and (snap or getattr(getattr(completer, "model", None), "uses_evidence", False)):
            kw["sensor_origins"] = sensor_origins[s : s + batch_size]
        if classes is not None and getattr(completer, "classes", ()):
            kw["classes"] = list(classes[s : s + batch_size])
        if snap:
            kw["snap"], kw["snap_mirror"] = snap, bool(snap_mirror)
        if fit is not None:  # the clouds as fitted (outputs as they are: unclamped)
            origins = None if sensor_origins is None else sensor_origins[s : s + batch_size]
            sizes = box_sizes[s : s + batch_size]
            clip_kw = kw.get("clip", DEFAULT)  # as complete() without a clip: the model's default
            res = fit_in_boxes(completer, batch, sizes, fit, clip_kw, origins, kw.get("classes"), None,
                               kw.get("snap"), fitted).clouds  # fmt: skip
        else:
            res = completer.complete(batch, **kw)
        if len(res) != len(batch):
            raise SpotlightsError(
                f"completer {getattr(completer, 'model_name', '?')} returned {len(res)} completions for {len(batch)} inputs"
            )
        for r in res:
            r = np.asarray(r, dtype=np.float32)
            if r.ndim != 2 or r.shape[1] != 3:
                if r.size == 0:
                    r = r.reshape(0, 3)
                else:
                    raise SpotlightsError(
                        f"completer {getattr(completer, 'model_name', '?')} returned an array of shape {r.shape}, expected (K, 3)"
                    )
            out.append(r)
    return out


def equal_count(points: np.ndarray, n: int = EQUAL_POINTS, seed: int = 0) -> np.ndarray:
    """(n, 3) float32: ``points`` (K, 3) brought to ``n`` points by farthest-point sampling
    (:func:`~spotlights.geometry.sampling.resample_set` with ``method="fps"``: canonical order, first
    point chosen with ``seed``); K < n: all points plus seeded repeats; K = 0: an empty (0, 3) array."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros((0, 3), np.float32)
    return resample_set(p, n, seed=seed, method="fps").astype(np.float32)


def flip_heading(partials: np.ndarray) -> np.ndarray:
    """Unit-frame partials (..., 3) as seen in the box turned by 180 degrees about its up axis (x, y negated)."""
    return (np.asarray(partials) @ FLIP_Z).astype(np.float32)


def _track_radii(keys, radii) -> np.ndarray:
    """(n,) the mean box radius of each row's track (the consistency's normaliser)."""
    groups: dict = {}
    for i, k in enumerate(keys):
        groups.setdefault(k, []).append(i)
    out = np.empty(len(keys))
    for rows in groups.values():
        out[rows] = float(np.mean(radii[rows]))
    return out


@dataclass
class _Tracked:
    """The tracked observations one evaluation scores (``n`` rows), and what every model's scoring shares."""

    keys: list  # (n,) (sequence, track id)
    ts: np.ndarray  # (n,) float64 timestamps, seconds
    cls: list  # (n,) class names
    sizes: np.ndarray  # (n, 3) box sizes, metres
    sensors: np.ndarray  # (n, 3) the LiDAR in each unit frame
    radii: np.ndarray  # (n,) box radii (half diagonals), metres
    r_track: np.ndarray  # (n,) the mean box radius of each row's track
    classes_present: list
    partials: np.ndarray  # (n, P, 3) float32 unit frame
    partials2: np.ndarray | None  # the same resampled with seed + 1 (noise floor), or None
    ref_trees: list | None
    seed: int


def _tracked(obs: Observations, rows: np.ndarray, references, noise_floor: bool) -> _Tracked:
    """The :class:`_Tracked` of observation ``rows`` (``references``: MMD shapes or None)."""
    keys = obs.object_keys()
    sub_keys = [keys[i] for i in rows]
    sub_cls = [obs.cls[i] for i in rows]
    sizes = obs.box_size[rows]
    radii = 0.5 * np.linalg.norm(sizes, axis=1)
    partials = obs.partial[rows]
    seed = int((obs.meta.get("config") or {}).get("seed", 0))
    n_in = partials.shape[1]
    partials2 = (
        np.stack([resample_set(obs.raw(i), n_in, seed=seed + 1) for i in rows]).astype(np.float32)
        if bool(noise_floor) and obs.has_raw
        else None
    )
    return _Tracked(
        keys=sub_keys,
        ts=obs.timestamp[rows],
        cls=sub_cls,
        sizes=sizes,
        sensors=obs.sensor_origin[rows],
        radii=radii,
        r_track=_track_radii(sub_keys, radii),
        classes_present=[c for c in CLASSES if c in set(sub_cls)],
        partials=partials,
        partials2=partials2,
        ref_trees=None
        if references is None
        else [NearestNeighbors(np.asarray(r, dtype=np.float64)) for r in references],
        seed=seed,
    )


def _score(t: _Tracked, comps, ref_trees=None, noise=None):
    """Consistency of one set of completions plus the per-observation scores; returns (tracks, aggregate, diversity)."""
    with serial_queries():  # many small KD-tree queries
        per_obs = {"fidelity": np.array([fidelity(p, c) for p, c in zip(t.partials, comps)])}
        if ref_trees:
            per_obs["mmd"] = np.array([minimal_matching_distance(c, ref_trees)[0] for c in comps])
        per_obs["fidelity_m"] = per_obs["fidelity"] * t.radii
        if noise is not None:
            per_obs["noise_floor"] = same_observation_cd(comps, noise, t.radii / t.r_track)
            per_obs["noise_floor_m"] = same_observation_cd(comps, noise, t.radii)
        tracks = track_consistency(comps, t.keys, t.ts, t.cls, t.radii, per_observation=per_obs)
        div, _ = diversity(comps, t.keys, t.ts)
    return tracks, aggregate(tracks, classes=t.classes_present), div


def _ratio(consistency, div) -> float | None:
    """Consistency over diversity, None when either is missing or diversity is not positive."""
    return consistency / div if consistency is not None and np.isfinite(div) and div > 0 else None


def _rescored(t: _Tracked, comps: list, comps2: list | None, fn, **info) -> dict:
    """Consistency, noise floor and diversity of the completions mapped by ``fn`` (same aggregation)."""
    ce = [fn(c) for c in comps]
    ce2 = [fn(c) for c in comps2] if comps2 is not None else None
    _, agg_e, div_e = _score(t, ce, None, ce2)
    return dict(
        **info,
        mean_points_per_completion=float(np.mean([len(c) for c in ce])) if ce else None,
        diversity=div_e,
        **agg_e,
        consistency_over_diversity=_ratio(agg_e["all_objects"]["cd"], div_e),
    )


def _heading_entry(t: _Tracked, completer, name: str, comps: list, run: dict, margin: float) -> dict:
    """Heading flips: each observation completed with its box turned around, counted when closer (``margin``)."""
    flipped = complete_all(
        completer,
        flip_heading(t.partials),
        desc=f"heading check {name}",
        **dict(run, sensor_origins=flip_heading(t.sensors)),
    )
    with serial_queries():
        f0 = np.array([fidelity(p, c) for p, c in zip(t.partials, comps)])
        f1 = np.array([fidelity(p, c) for p, c in zip(flip_heading(t.partials), flipped)])
    ok = np.isfinite(f0) & np.isfinite(f1)
    flips = ok & heading_turns(f0, f1, margin)
    bare = ok & heading_turns(f0, f1, 0.0)
    return dict(
        margin=float(margin),
        n_observations=int(ok.sum()),
        n_flipped=int(flips.sum()),
        rate=float(flips.sum() / ok.sum()) if ok.any() else None,
        n_flipped_margin0=int(bare.sum()),
        rate_margin0=float(bare.sum() / ok.sum()) if ok.any() else None,
        per_class={c: int(sum(1 for i in np.flatnonzero(flips) if t.cls[i] == c)) for c in t.classes_present},
    )


def _domain_entry(domain, t: _Tracked) -> dict:
    """How many observations lie outside what the model learned, counted per reason."""
    reasons: dict = {}
    n_out = 0
    for c, sz in zip(t.cls, t.sizes):
        w = domain.warnings(c, sz)
        n_out += bool(w)
        for r in w:
            key = r.split(" (")[0] if r.startswith("size") else r
            reasons[key] = reasons.get(key, 0) + 1
    return dict(n_observations=n_out, reasons=reasons)


def fit_settings(completer, s: RealEvaluationSettings):
    """``s.fit_settings`` for ``completer``: None when ``s`` does not fit or the model cannot be fitted (a point-set
    model: its entry's ``fitted`` is None)."""
    return s.fit_settings if can_fit(completer) else None


def _model_entry(
    t: _Tracked, completer, name: str, checkpoint, digest, s: RealEvaluationSettings, progress: bool
) -> dict:
    """The report entry of one model: its completions of the tracked observations, scored."""
    run: dict[str, Any] = dict(
        batch_size=s.batch_size,
        progress=progress,
        clip=s.clip,
        box_sizes=t.sizes,
        sensor_origins=t.sensors,
        classes=t.cls,
        **snap_options(completer, s.snap, s.snap_mirror),  # a point-set model unsnapped (its entry says so)
        fit=fit_settings(completer, s),
    )
    fitted: list[bool] = []
    comps = complete_all(completer, t.partials, desc=f"complete {name}", fitted=fitted, **run)
    p2 = t.partials2
    comps2 = complete_all(completer, p2, desc=f"noise floor {name}", **run) if p2 is not None else None
    tracks, agg, div = _score(t, comps, t.ref_trees, comps2)
    entry = dict(
        name=name,
        model_name=str(getattr(completer, "model_name", name)),
        checkpoint=None if checkpoint is None else str(checkpoint),
        checkpoint_sha256=digest,
        n_params=getattr(completer, "n_params", None),
        mean_points_per_completion=float(np.mean([len(c) for c in comps])),
        snapped=run["snap"] is not None,
        fitted=None if run["fit"] is None else float(np.mean(fitted)) if fitted else 0.0,
        diversity=div,
        consistency_over_diversity=_ratio(agg["all_objects"]["cd"], div),
        **agg,
    )
    inside = inside_shares(comps, t.sizes)  # per class: the share of the network's points inside the grown box
    entry["inside_box"] = {
        c: float(np.nanmean([v for v, cc in zip(inside, t.cls) if cc == c])) for c in t.classes_present
    }
    eq, vox = s.n_equal_points, s.voxel
    if eq:
        entry["equal_points"] = _rescored(t, comps, comps2, lambda c: equal_count(c, eq), n_points=eq)
    if vox:
        entry["equal_density"] = _rescored(t, comps, comps2, lambda c: voxel_downsample(c, vox), voxel=vox)
    if s.heading_check:
        entry["heading"] = _heading_entry(t, completer, name, comps, run, s.heading_margin)
    domain = getattr(completer, "domain", None)
    if domain is not None:
        entry["out_of_domain"] = _domain_entry(domain, t)
    entry["objects"] = [
        dict(
            sequence=tr.key[0],
            track_id=tr.key[1],
            cls=tr.cls,
            n_observations=tr.n_observations,
            n_pairs=tr.n_pairs,
            n_pairs_empty=tr.n_pairs_empty,
            **tr.values,
        )
        for tr in tracks
    ]
    return entry


def inside_shares(completions, sizes, margin: float = GROWN_BOX_MARGIN) -> np.ndarray:
    """(n,) float64 each unit-frame completion's share of points inside its box (sizes (n, 3), metres) grown by
    ``margin`` metres (NaN for an empty completion): what the network put inside, before any clamp."""
    half = grown_half_extents(np.asarray(sizes, dtype=np.float64).reshape(-1, 3), margin)
    return np.array([np.mean(np.all(np.abs(c) <= h, axis=1)) if len(c) else np.nan for c, h in zip(completions, half)])
