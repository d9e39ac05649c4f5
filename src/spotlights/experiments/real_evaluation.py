"""Completion of real observations and the consistency report (the paper's Table 2).

:func:`evaluate_consistency` takes an observation file (from ``real extract``)
and any number of *completers* - objects with ``model_name`` (str), optionally
``n_params`` (int), and ``complete(partials (B, P, 3) float32 unit frame) ->
list of B arrays (K_i, 3)`` in the unit frame (the interface of
``spotlights.learning.inference.load_completer``). It completes every
observation of every object seen in two or more frames, scores the
consistency (:mod:`spotlights.metrics.consistency`), and returns a report dict;
:func:`write_report` writes it as Markdown and JSON (:mod:`.real_report`, importable from here).

Beside consistency (as the paper computes it, on the completions as the models give
them) the report holds, per model:

- **the resampling noise floor**: each tracked observation's kept points (stored by
  ``real extract``) resampled with a second seed and completed again; the two-sided
  Chamfer ``cd`` between the two completions of the *same* observation, in the
  consistency's frame (object frame / the track's mean box radius), averaged like
  consistency (observation -> track -> class). Part of any measured inconsistency is
  this noise: it is what consistency would be if nothing but the 256-point
  resampling changed between frames.
- **consistency at equal point counts** (``equal_points``): every completion first
  brought to one common count (default 512) by farthest-point sampling (fewer points:
  all kept plus seeded repeats), then scored the same way (with its own noise floor and
  diversity). A Chamfer distance between two sparse samplings of one surface is larger
  than between two dense ones, so at native counts a model that outputs ~560 points is
  penalised against one that outputs 2,048.
- **consistency at equal density** (``equal_density``, the headline for comparing models):
  every completion replaced by the centroids of its occupied cells of one voxel grid
  (default side 0.1 in the unit frame, :func:`spotlights.geometry.sampling.voxel_downsample`),
  then scored the same way. Two samplings of one surface at different densities give nearly
  the same cells, so this compares shapes at one spatial resolution. A fixed-count subset
  (``equal_points``) does not: it draws *different* points from two nearly identical dense
  clouds (measured: the dense default model's consistency on AV2 goes from 0.024 at its own
  15,600 points to 0.099 at 512 random or farthest points, the paper model's from 0.031 to
  0.034-0.037), so a fixed count mostly measures subsampling noise for dense models.
- **heading flips**: each observation also completed with its box turned by 180 degrees
  (the partial input rotated about the box's up axis); a flip is counted when that
  completion is clearly closer to the observed points (fidelity lower by more than the
  margin of :func:`spotlights.completion.frame.heading_turns`) - what
  ``spotlights complete --heading-check`` would do - and, separately, when it is closer at
  all. On annotated boxes every flip is a false alarm of the check.
- **out-of-domain boxes**: observations whose class or box size is outside what the
  model learned (:class:`spotlights.learning.domain.LearnedDomain`), counted per reason.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._version import __version__
from ..completion.frame import HEADING_MARGIN, heading_turns, snap_options
from ..data.real.base import CLASSES
from ..data.real.extract import Observations, read_observations
from ..data.store import open_dataset
from ..errors import InputFileError, ParameterError, SpotlightsError
from ..geometry.box_clamp import GROWN_BOX_MARGIN, grown_half_extents
from ..geometry.boxes import FLIP_Z, unit_extents
from ..geometry.evidence import snap_radius
from ..geometry.neighbors import NearestNeighbors, serial_queries
from ..geometry.sampling import resample_set, voxel_downsample
from ..learning.checkpoint import resolve_checkpoint
from ..metrics.consistency import (
    DIVERSITY_DOC,
    METRIC_DOC,
    OBSERVATION_METRIC_DOC,
    aggregate,
    consecutive_pairs,
    diversity,
    fidelity,
    minimal_matching_distance,
    same_observation_cd,
    track_consistency,
)
from ..options import settings_from_dict
from .real_report import report_markdown, write_report, write_report_json

__all__ = [
    "EQUAL_DENSITY",
    "EQUAL_DENSITY_DOC",
    "EQUAL_DOC",
    "EQUAL_POINTS",
    "HEADING_DOC",
    "NOISE_DOC",
    "RealEvaluationSettings",
    "complete_all",
    "equal_count",
    "evaluate_consistency",
    "flip_heading",
    "reference_shapes",
    "report_markdown",
    "tracked_rows",
    "write_report",
    "write_report_json",
]

SCORE_VERSION = 1
"""Version of the scoring of a consistency report: raise it when a change of the code changes any number of
a model's entry; ``real evaluate --resume`` reuses entries only of the same version (and package version)."""
EQUAL_POINTS = 512
"""Common point count of the equal-count consistency (farthest-point sampling of every completion)."""

EQUAL_DENSITY = 0.1
"""Voxel side (unit frame: the box's half diagonal) of the equal-density consistency: about 300-600 cells on a car's
completion, the scale of the sparsest models' outputs."""

NOISE_DOC = (
    "resampling noise floor: cd between the completions of the same observation resampled with two seeds "
    "(stored partial vs its kept points resampled with seed + 1), consistency's frame; mean per track, then per class"
)
EQUAL_DOC = (
    "every completion brought to {n} points by farthest-point sampling (seeded start; fewer points: all kept "
    "plus seeded repeats) before scoring, so models with different output sizes compare at one density"
)
EQUAL_DENSITY_DOC = (
    "every completion replaced by the centroids of its occupied cells of a voxel grid of side {v} (each observation's "
    "unit frame) before scoring: shapes compared at one spatial resolution, whatever each model's output density "
    "(the headline for comparing models)"
)
HEADING_DOC = (
    "share of observations whose completion with the box turned by 180 degrees is closer to the observed "
    "points than with the box as given - fidelity lower by more than the margin (rate; the check of "
    "'complete --heading-check') or at all (rate_margin0): on annotated boxes, false alarms"
)


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
    ``snap_mirror`` to its mirror image too.
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


def tracked_rows(obs: Observations, classes: Sequence[str] | None = None) -> np.ndarray:
    """Sorted row indices of the observations that belong to a consecutive pair (of class in ``classes``, if given)."""
    keep = (
        np.arange(len(obs))
        if classes is None
        else np.array([i for i, c in enumerate(obs.cls) if c in set(classes)], dtype=np.int64)
    )
    if keep.size == 0:
        return keep
    keys = obs.object_keys()
    pairs = consecutive_pairs([keys[i] for i in keep], obs.timestamp[keep])
    return np.array(sorted({int(keep[i]) for p in pairs for i in p}), dtype=np.int64)


def reference_shapes(dataset: str | os.PathLike, split: str | None = None) -> tuple[list[np.ndarray], dict]:
    """Complete reference cars for the minimal matching distance, from a completion dataset.

    Returns the ground-truth surface points (``/models/gt_points``: R arrays (2048, 3) float32, each in
    its model's unit frame, the frame of a real observation's completion) of every model, or of the
    models of ``split`` ("train", "val", "test"), and a description dict (file, split, count).
    """
    with open_dataset(dataset) as ds:
        models = ds.split_models(split) if split else np.arange(ds.n_models)
        gt = ds.models_array("gt_points", np.sort(models)) if len(models) else np.zeros((0, 0, 3), np.float32)
        shapes = list(np.asarray(gt, dtype=np.float32))
    if not shapes:
        raise InputFileError(str(dataset), f"no reference model in split {split!r}")
    return shapes, {
        "file": str(dataset),
        "split": split or "all",
        "n_shapes": len(shapes),
        "points_per_shape": int(len(shapes[0])),
        "sha256": hashlib.sha256(np.ascontiguousarray(np.stack(shapes)).tobytes()).hexdigest(),
    }


def _track_radii(keys, radii) -> np.ndarray:
    """(n,) the mean box radius of each row's track (the consistency's normaliser)."""
    groups: dict = {}
    for i, k in enumerate(keys):
        groups.setdefault(k, []).append(i)
    out = np.empty(len(keys))
    for rows in groups.values():
        out[rows] = float(np.mean(radii[rows]))
    return out


@dataclass(frozen=True, kw_only=True)
class RealEvaluationSettings:
    """What :func:`evaluate_consistency` scores and how (the scoring options of ``real evaluate``).

    classes : score only observations of these classes (a tuple or list; None: every class in the file).
    clip : SA-Net's depth clip in [0, 1], passed to ``complete`` when given; None: each model's default.
    equal_points : also score every completion resampled to this many points (None/0: not).
    equal_density : also score every completion voxel-downsampled with this cell side (unit frame;
        None/0: not) - the headline for comparing models of different output densities.
    noise_floor : also complete each observation resampled with a second seed (needs the raw
        points of a format-2 file; older files report no floor).
    heading_check : also complete each observation with its box turned around and count flips.
    heading_margin : margin of the counted heading flips (:func:`~spotlights.completion.frame.heading_turns`),
        in [0, 1).
    batch_size : observations per ``complete`` call.
    snap : > 0: the SA-Nets' rays snapped to each observation's input points within this radius (unit frame;
        :meth:`~spotlights.learning.inference.BaseCompleter.complete`); 0: off. Not with ``heading_check`` (which
        compares fidelities that snapping puts near 0 for both headings). snap_mirror : also snap to the partial's
        mirror image (``y -> -y``).

    Read from a mapping with :meth:`from_dict` (unknown keys are errors naming the closest field).
    """

    classes: Sequence[str] | None = None
    clip: float | None = None
    equal_points: int | None = EQUAL_POINTS
    equal_density: float | None = EQUAL_DENSITY
    noise_floor: bool = True
    heading_check: bool = True
    heading_margin: float = HEADING_MARGIN
    batch_size: int = 64
    snap: float = 0.0
    snap_mirror: bool = False

    def __post_init__(self):
        object.__setattr__(self, "snap", snap_radius(self.snap, self.snap_mirror) or 0.0)  # None (off): 0.0
        if self.snap > 0 and self.heading_check:
            raise ParameterError(
                "`snap` does not go with the heading check (add `no_heading_check`): the flips are counted by "
                "fidelity, which snapping puts near 0 for both headings",
                "snap",
                "no_heading_check",
            )

    @classmethod
    def from_dict(cls, d: object, where: str = "evaluate_consistency") -> RealEvaluationSettings:
        """The settings of mapping ``d`` (:func:`spotlights.options.settings_from_dict`: unknown keys are errors
        naming ``where`` and the closest field)."""
        return settings_from_dict(cls, d, where)

    @property
    def n_equal_points(self) -> int:
        """:attr:`equal_points` as an int, 0 when not scored."""
        return int(self.equal_points) if self.equal_points else 0

    @property
    def voxel(self) -> float:
        """:attr:`equal_density` as a float, 0.0 when not scored."""
        return float(self.equal_density) if self.equal_density else 0.0


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
    )
    comps = complete_all(completer, t.partials, desc=f"complete {name}", **run)
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


def _tracked_rows_or_fail(obs: Observations, classes, path: str | None) -> np.ndarray:
    """:func:`tracked_rows`, or a one-line :class:`InputFileError` when no object is seen twice."""
    rows = tracked_rows(obs, classes)
    if rows.size == 0:
        which = f" of class {', '.join(classes)}" if classes else ""
        raise InputFileError(
            path or "<observations>",
            f"no object{which} is observed in two or more frames, so there is nothing to compare "
            f"({len(obs)} observations; KITTI object frames carry no track ids - use Argoverse 2, nuScenes, KITTI-360 "
            "or a generic sequence with track_id)",
        )
    return rows


def _reusable(previous: Sequence[dict] | None, scored: dict) -> dict:
    """{(name, checkpoint digest): model entry} of the earlier reports scored with the settings ``scored``."""
    same = json.loads(json.dumps(scored))  # as it reads back from a report's JSON
    reusable = {}
    for rep in previous or ():
        earlier = (rep.get("data") or {}).get("settings")
        if isinstance(earlier, dict):  # reports from before --snap existed did not snap
            earlier = {"snap": 0.0, "snap_mirror": False} | earlier
        if earlier == same:
            reusable.update({(m.get("name"), m.get("checkpoint_sha256")): m for m in rep.get("models", [])})
    return reusable


def evaluate_consistency(
    source: str | os.PathLike | Observations,
    completers: Sequence,
    settings: RealEvaluationSettings | None = None,
    *,
    names: Sequence[str] | None = None,
    checkpoints: Sequence[str] | None = None,
    progress: bool = True,
    references: Sequence[np.ndarray] | None = None,
    reference_info: dict | None = None,
    previous: Sequence[dict] | None = None,
    on_model: Callable[[dict, bool], None] | None = None,
    **options,
) -> dict:
    """Consistency of each completer on the tracked objects of an observation file.

    Parameters
    ----------
    source : an observation HDF5 path or loaded :class:`Observations`.
    completers : objects with ``complete(partials) -> list of (K, 3)`` (see the module doc).
    settings : what is scored (:class:`RealEvaluationSettings`: classes, clip, equal points / density, noise
        floor, heading check and margin, batch size); or give its fields as keyword ``options``
        (``equal_points=64``, ``classes=["car"]``; unknown names are errors), not both.
    names : row names in the report (default: each completer's ``model_name``).
    checkpoints : checkpoint paths to record in the report (optional).
    progress : show progress bars.
    references : optional complete shapes (R arrays (L, 3), unit frame; see :func:`reference_shapes`)
        for the minimal matching distance ``mmd``; fidelity and diversity are always reported.
    reference_info : description of ``references`` recorded in the report.
    previous : earlier reports (JSON of :func:`write_report`, loaded) to resume from: a model whose
        entry in a report scored with the same settings (``data["settings"]``: the scoring code's
        version, a digest of the observations scored, classes, clip, resamplings, heading check, the
        MMD reference's content) has the same name and checkpoint content (``checkpoint_sha256``)
        is copied (with the current checkpoint path), not computed again. Needs ``checkpoints``; an
        entry without a digest is recomputed. The device is not part of the settings (CPU and CUDA
        scores differ by float rounding only).
    on_model : called as ``on_model(report_so_far, reused)`` after each model (``reused``: copied
        from ``previous``); ``real evaluate`` writes the report so far, so an interrupted run
        resumes where it stopped.

    Returns
    -------
    dict with ``data`` (file, counts, skip counts), ``metrics`` (definitions),
    and ``models``: one entry per completer with ``name``, ``n_params``,
    ``classes`` / ``average`` / ``all_objects`` (see
    :func:`spotlights.metrics.consistency.aggregate`; per-observation keys ``fidelity``,
    ``mmd``, ``noise_floor``), ``mean_points_per_completion``, ``diversity``,
    ``equal_points`` and ``equal_density`` (consistency, noise floor, diversity and
    ``mean_points_per_completion`` after bringing every completion to one count / one voxel
    grid; ``n_points`` / ``voxel`` say which), ``heading`` (flip counts and the ``margin``),
    ``out_of_domain`` and ``objects`` (per track).

    Raises
    ------
    InputFileError if no object of the file is observed in two or more frames.
    """
    if settings is None:
        settings = RealEvaluationSettings.from_dict(options)
    elif options:
        raise ParameterError(f"give either settings or their fields ({', '.join(sorted(options))}), not both")
    path = None if isinstance(source, Observations) else str(source)
    obs = source if isinstance(source, Observations) else read_observations(source)
    rows = _tracked_rows_or_fail(obs, settings.classes, path)
    if not completers:
        raise SpotlightsError("no completer (checkpoint) given")
    names = (
        list(names)
        if names is not None
        else [str(getattr(c, "model_name", f"model{i}")) for i, c in enumerate(completers)]
    )
    t = _tracked(obs, rows, references, settings.noise_floor)
    scored = dict(
        code=f"{__version__}/{SCORE_VERSION}",
        observations=observations_digest(obs, rows),
        classes=list(settings.classes) if settings.classes else None,
        clip=settings.clip,
        equal_points=settings.n_equal_points or None,
        equal_density=settings.voxel or None,
        noise_floor=t.partials2 is not None,
        heading_margin=float(settings.heading_margin) if settings.heading_check else None,
        mmd_reference=reference_info if references is not None else None,
        snap=float(settings.snap),
        snap_mirror=bool(settings.snap_mirror),
    )
    data, metrics = _report_head(obs, path, rows, t, scored, bool(settings.noise_floor))
    digests = [None] * len(completers) if checkpoints is None else [checkpoint_digest(c) for c in checkpoints]
    reusable = _reusable(previous, scored)
    models = []
    for k, completer in enumerate(completers):
        old = reusable.get((names[k], digests[k])) if digests[k] else None
        ck = None if checkpoints is None else checkpoints[k]  # a digest means a checkpoint
        if old is not None:
            models.append(dict(old, checkpoint=str(ck)))
        else:
            models.append(_model_entry(t, completer, names[k], ck, digests[k], settings, progress))
        if on_model is not None:
            on_model(dict(data=data, metrics=metrics, models=list(models)), old is not None)
    return dict(data=data, metrics=metrics, models=models)


def inside_shares(completions, sizes, margin: float = GROWN_BOX_MARGIN) -> np.ndarray:
    """(n,) float64 each unit-frame completion's share of points inside its box (sizes (n, 3), metres) grown by
    ``margin`` metres (NaN for an empty completion): what the network put inside, before any clamp."""
    half = grown_half_extents(np.asarray(sizes, dtype=np.float64).reshape(-1, 3), margin)
    return np.array([np.mean(np.all(np.abs(c) <= h, axis=1)) if len(c) else np.nan for c, h in zip(completions, half)])


def observations_digest(obs: Observations, rows: np.ndarray) -> str:
    """SHA-256 (hex) of what a consistency evaluation scores: the partials, raw points, boxes, track keys,
    timestamps and classes of observation ``rows``; two files with the same content give the same digest."""
    h = hashlib.sha256()
    for a in (obs.partial[rows], obs.box_size[rows], obs.timestamp[rows]):
        h.update(np.ascontiguousarray(a).tobytes())
    keys = obs.object_keys()
    h.update(json.dumps([[str(x) for x in keys[i]] + [str(obs.cls[i])] for i in rows]).encode())
    if obs.has_raw:
        for i in rows:
            h.update(np.ascontiguousarray(obs.raw(i)).tobytes())
    return h.hexdigest()


def checkpoint_digest(checkpoint) -> str | None:
    """SHA-256 (hex) of a checkpoint's file (a path or a short name such as ``default``); None when it names no file."""
    try:
        path = resolve_checkpoint(checkpoint)
    except SpotlightsError:
        return None
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def _report_head(obs, path, rows, t: _Tracked, settings: dict, noise_requested: bool) -> tuple[dict, dict]:
    """The ``data`` and ``metrics`` parts of a consistency report (everything but the models)."""
    sub_keys, sub_ts, sub_cls, classes_present, seed = t.keys, t.ts, t.cls, t.classes_present, t.seed
    eq, vox = settings["equal_points"], settings["equal_density"]
    with_noise = settings["noise_floor"]
    n_tracks = len(set(sub_keys))
    per_track: dict = {}
    for key in sub_keys:
        per_track[key] = per_track.get(key, 0) + 1
    return (
        dict(
            file=path,
            source_format=obs.meta.get("source_format"),
            source=obs.meta.get("source"),
            n_observations=len(obs),
            n_observations_tracked=int(rows.size),
            n_objects_tracked=n_tracks,
            n_objects_5_or_more=sum(1 for v in per_track.values() if v >= 5),
            n_pairs=len(consecutive_pairs(sub_keys, sub_ts)),
            objects_per_class={c: len({k for k, cc in zip(sub_keys, sub_cls) if cc == c}) for c in classes_present},
            classes=settings["classes"],
            extraction=obs.meta.get("config"),
            clip=settings["clip"],
            skipped=obs.meta.get("skipped"),
            mmd_reference=settings["mmd_reference"],
            noise_floor=(
                f"kept points resampled with seed {seed + 1} (the file's partials: seed {seed})"
                if with_noise
                else (
                    "not computed: the file holds no raw points (format version 1); extract it again"
                    if noise_requested
                    else None
                )
            ),
            equal_points=eq,
            equal_density=vox,
            settings=settings,
        ),
        dict(
            headline="cd",
            frame="consistency (cd*, d_*) and noise_floor: object frame divided by the track's mean box radius (half diagonal); "
            "fidelity and mmd: each observation's own unit frame (its box's half diagonal); '_m' keys in metres",
            aggregation="pair -> mean per tracked object -> mean per class; average = mean over classes present; all_objects = mean over objects",
            definitions={
                **METRIC_DOC,
                **OBSERVATION_METRIC_DOC,
                "diversity": DIVERSITY_DOC,
                "noise_floor": NOISE_DOC,
                "equal_points": EQUAL_DOC.format(n=eq or EQUAL_POINTS),
                "equal_density": EQUAL_DENSITY_DOC.format(v=vox or EQUAL_DENSITY),
                "heading": HEADING_DOC,
            },
        ),
    )
