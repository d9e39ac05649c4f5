"""Completion of real observations and the consistency report (the paper's Table 2).

:func:`evaluate_consistency` takes an observation file (from ``real extract``)
and any number of *completers* - objects with ``model_name`` (str), optionally
``n_params`` (int), and ``complete(partials (B, P, 3) float32 unit frame) ->
list of B arrays (K_i, 3)`` in the unit frame (the interface of
``spotlights.learning.inference.load_completer``). It completes every
observation of every object seen in two or more frames, scores the
consistency (:mod:`spotlights.metrics.consistency`), and returns a report dict;
:func:`write_report` writes it as Markdown and JSON (:mod:`.real_report`, importable from here). The
completion and the scoring of each model are in :mod:`.real_scoring` (its public names importable from here).

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

import numpy as np

from .._version import __version__
from ..completion.frame import HEADING_MARGIN
from ..data.real.extract import Observations, read_observations
from ..data.store import open_dataset
from ..errors import InputFileError, ParameterError, SpotlightsError
from ..geometry.evidence import snap_radius
from ..learning.checkpoint import resolve_checkpoint
from ..learning.fit import FIT_STEPS, FitSettings, check_fit_options, check_fit_steps
from ..metrics.consistency import (
    DIVERSITY_DOC,
    METRIC_DOC,
    OBSERVATION_METRIC_DOC,
    consecutive_pairs,
)
from ..options import settings_from_dict
from .real_report import report_markdown, write_report, write_report_json
from .real_scoring import (
    EQUAL_DENSITY,
    EQUAL_POINTS,
    _model_entry,
    _Tracked,
    _tracked,
    complete_all,
    equal_count,
    flip_heading,
)
from .real_scoring import inside_shares as inside_shares

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
    fit : each completion fitted to its observation's evidence (:func:`~spotlights.learning.fit.fit_completions`,
        as ``real complete --fit``; SA-Nets run with torch; point-set models unfitted); not with ``snap``.
        fit_steps : the fit's Adam steps (1..:data:`~spotlights.learning.fit.MAX_FIT_STEPS`; None: the default).

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
    fit: bool = False
    fit_steps: int | None = None

    def __post_init__(self):
        object.__setattr__(self, "snap", snap_radius(self.snap, self.snap_mirror) or 0.0)  # None (off): 0.0
        check_fit_options(self.fit, self.snap)
        if self.fit_steps is not None:
            if not self.fit:
                raise ParameterError("`fit_steps` goes with `fit`", "fit_steps", "fit")
            object.__setattr__(self, "fit_steps", check_fit_steps(self.fit_steps))
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

    @property
    def fit_settings(self) -> FitSettings | None:
        """The :class:`~spotlights.learning.fit.FitSettings` of ``fit``/``fit_steps`` (None: the default steps), or
        None when ``fit`` is off."""
        return FitSettings(steps=self.fit_steps or FIT_STEPS) if self.fit else None


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
        if isinstance(earlier, dict):  # reports from before --snap / --fit existed did not snap or fit
            earlier = {"snap": 0.0, "snap_mirror": False, "fit_steps": None} | earlier
        if earlier == same:
            reusable.update({(m.get("name"), m.get("checkpoint_sha256")): m for m in rep.get("models", [])})
    return reusable


def _settings_of(settings: RealEvaluationSettings | None, options: dict) -> RealEvaluationSettings:
    """``settings``, or the settings of the keyword ``options`` (:class:`ParameterError` when both are given)."""
    if settings is None:
        return RealEvaluationSettings.from_dict(options)
    if options:
        raise ParameterError(f"give either settings or their fields ({', '.join(sorted(options))}), not both")
    return settings


def _model_names(completers: Sequence, names: Sequence[str] | None) -> list[str]:
    """The report's row names: ``names``, or each completer's ``model_name`` (``model<i>`` without one)."""
    if names is not None:
        return list(names)
    return [str(getattr(c, "model_name", f"model{i}")) for i, c in enumerate(completers)]


def _scored_settings(
    settings: RealEvaluationSettings, observations: str, t: _Tracked, references, reference_info: dict | None
) -> dict:
    """What a report's numbers depend on (``data["settings"]``; a resumed run reuses entries scored with the same):
    the scoring code's version, the digest of the ``observations`` scored, the options and the MMD reference."""
    return dict(
        code=f"{__version__}/{SCORE_VERSION}",
        observations=observations,
        classes=list(settings.classes) if settings.classes else None,
        clip=settings.clip,
        equal_points=settings.n_equal_points or None,
        equal_density=settings.voxel or None,
        noise_floor=t.partials2 is not None,
        heading_margin=float(settings.heading_margin) if settings.heading_check else None,
        mmd_reference=reference_info if references is not None else None,
        snap=float(settings.snap),
        snap_mirror=bool(settings.snap_mirror),
        fit_steps=settings.fit_settings.steps if settings.fit_settings else None,
    )


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
    settings = _settings_of(settings, options)
    path = None if isinstance(source, Observations) else str(source)
    obs = source if isinstance(source, Observations) else read_observations(source)
    rows = _tracked_rows_or_fail(obs, settings.classes, path)
    if not completers:
        raise SpotlightsError("no completer (checkpoint) given")
    names = _model_names(completers, names)
    t = _tracked(obs, rows, references, settings.noise_floor)
    scored = _scored_settings(settings, observations_digest(obs, rows), t, references, reference_info)
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
