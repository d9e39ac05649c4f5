"""Completion of real observations and the consistency report (the paper's Table 2).

:func:`evaluate_consistency` takes an observation file (from ``real extract``)
and any number of *completers* - objects with ``model_name`` (str), optionally
``n_params`` (int), and ``complete(partials (B, P, 3) float32 unit frame) ->
list of B arrays (K_i, 3)`` in the unit frame (the interface of
``spotlights.learning.inference.load_completer``). It completes every
observation of every object seen in two or more frames, scores the
consistency (:mod:`spotlights.data.consistency`), and returns a report dict;
:func:`write_report` writes it as Markdown and JSON.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ...errors import InputFileError, SpotlightsError
from ...geometry.neighbors import NearestNeighbors, serial_queries
from ..consistency import (DIVERSITY_DOC, METRIC_DOC, OBSERVATION_METRIC_DOC, aggregate, consecutive_pairs, diversity,
                           fidelity, minimal_matching_distance, track_consistency)
from .base import CLASSES
from .extract import Observations, read_observations


def complete_all(completer, partials: np.ndarray, batch_size: int = 64, progress: bool = True, desc: str = "complete",
                 clip: float | None = None, box_sizes: np.ndarray | None = None) -> list[np.ndarray]:
    """Run ``completer.complete`` over (n, P, 3) float32 partials in batches; returns n (K_i, 3) float32 arrays.

    ``clip`` is passed on as ``complete(batch, clip=clip)`` only when given (else the model's default).
    ``box_sizes`` (n, 3): each observation's box (l, w, h); completers with ``needs_box``
    (SA-Net on a box-targeted rig) get ``extents = size / |size|`` per observation, the
    half-extents of the box in the observation's unit frame. Others never see it.
    """
    from tqdm import tqdm

    out: list[np.ndarray] = []
    n = len(partials)
    extents = None
    if getattr(completer, "needs_box", False):
        if box_sizes is None:
            raise SpotlightsError(f"completer {getattr(completer, 'model_name', '?')} decodes rays aimed at each object's "
                                  "box: give the boxes' sizes")
        sizes = np.asarray(box_sizes, dtype=np.float64).reshape(n, 3)
        extents = sizes / np.linalg.norm(sizes, axis=1, keepdims=True)
    for s in tqdm(range(0, n, batch_size), desc=desc, unit="batch", disable=not progress or n == 0):
        batch = np.ascontiguousarray(partials[s : s + batch_size], dtype=np.float32)
        kw = {} if clip is None else {"clip": clip}
        if extents is not None:
            kw["extents"] = extents[s : s + batch_size]
        res = completer.complete(batch, **kw)
        if len(res) != len(batch):
            raise SpotlightsError(f"completer {getattr(completer, 'model_name', '?')} returned {len(res)} completions for {len(batch)} inputs")
        for r in res:
            r = np.asarray(r, dtype=np.float32)
            if r.ndim != 2 or r.shape[1] != 3:
                if r.size == 0:
                    r = r.reshape(0, 3)
                else:
                    raise SpotlightsError(f"completer {getattr(completer, 'model_name', '?')} returned an array of shape {r.shape}, expected (K, 3)")
            out.append(r)
    return out


def tracked_rows(obs: Observations) -> np.ndarray:
    """Sorted row indices of the observations that belong to a consecutive pair."""
    pairs = consecutive_pairs(obs.object_keys(), obs.timestamp)
    return np.array(sorted({i for p in pairs for i in p}), dtype=np.int64)


def reference_shapes(dataset: str | os.PathLike, split: str | None = None) -> tuple[list[np.ndarray], dict]:
    """Complete reference cars for the minimal matching distance, from a completion dataset.

    Returns the ground-truth surface points (``/models/gt_points``: R arrays (2048, 3) float32, each in
    its model's unit frame, the frame of a real observation's completion) of every model, or of the
    models of ``split`` ("train", "val", "test"), and a description dict (file, split, count).
    """
    from ..store import open_dataset

    with open_dataset(dataset) as ds:
        models = ds.split_models(split) if split else np.arange(ds.n_models)
        gt = ds.models_array("gt_points", np.sort(models)) if len(models) else np.zeros((0, 0, 3), np.float32)
        shapes = list(np.asarray(gt, dtype=np.float32))
    if not shapes:
        raise InputFileError(str(dataset), f"no reference model in split {split!r}")
    return shapes, {"file": str(dataset), "split": split or "all", "n_shapes": len(shapes), "points_per_shape": int(len(shapes[0]))}


def evaluate_consistency(
    source: str | os.PathLike | Observations,
    completers: Sequence,
    names: Sequence[str] | None = None,
    checkpoints: Sequence[str] | None = None,
    batch_size: int = 64,
    progress: bool = True,
    clip: float | None = None,
    references: Sequence[np.ndarray] | None = None,
    reference_info: dict | None = None,
) -> dict:
    """Consistency of each completer on the tracked objects of an observation file.

    Parameters
    ----------
    source : an observation HDF5 path or loaded :class:`Observations`.
    completers : objects with ``complete(partials) -> list of (K, 3)`` (see the module doc).
    names : row names in the report (default: each completer's ``model_name``).
    checkpoints : checkpoint paths to record in the report (optional).
    clip : passed to ``complete`` when given (SA-Net's depth clip); None = each model's default.
    references : optional complete shapes (R arrays (L, 3), unit frame; see :func:`reference_shapes`)
        for the minimal matching distance ``mmd``; fidelity and diversity are always reported.
    reference_info : description of ``references`` recorded in the report.

    Returns
    -------
    dict with ``data`` (file, counts, skip counts), ``metrics`` (definitions),
    and ``models``: one entry per completer with ``name``, ``n_params``,
    ``classes`` / ``average`` / ``all_objects`` (see
    :func:`spotlights.data.consistency.aggregate`) and ``objects`` (per track).

    Raises
    ------
    InputFileError if no object of the file is observed in two or more frames.
    """
    path = None
    if isinstance(source, Observations):
        obs = source
    else:
        path = str(source)
        obs = read_observations(source)
    rows = tracked_rows(obs)
    if rows.size == 0:
        raise InputFileError(
            path or "<observations>",
            "no object is observed in two or more frames, so there is nothing to compare "
            f"({len(obs)} observations; KITTI object frames carry no track ids - use Argoverse 2, KITTI-360 or a generic scene with track_id)",
        )
    if not completers:
        raise SpotlightsError("no completer (checkpoint) given")
    names = list(names) if names is not None else [str(getattr(c, "model_name", f"model{i}")) for i, c in enumerate(completers)]
    keys = obs.object_keys()
    sub_keys = [keys[i] for i in rows]
    sub_ts = obs.timestamp[rows]
    sub_cls = [obs.cls[i] for i in rows]
    radii = 0.5 * np.linalg.norm(obs.box_size[rows], axis=1)
    classes_present = [c for c in CLASSES if c in set(sub_cls)]
    ref_trees = None if references is None else [NearestNeighbors(np.asarray(r, dtype=np.float64)) for r in references]
    partials = obs.partial[rows]
    models = []
    for k, completer in enumerate(completers):
        comps = complete_all(completer, partials, batch_size=batch_size, progress=progress, desc=f"complete {names[k]}",
                             clip=clip, box_sizes=obs.box_size[rows])
        with serial_queries():  # many small KD-tree queries
            per_obs = {"fidelity": np.array([fidelity(p, c) for p, c in zip(partials, comps)])}
            if ref_trees:
                per_obs["mmd"] = np.array([minimal_matching_distance(c, ref_trees)[0] for c in comps])
            per_obs["fidelity_m"] = per_obs["fidelity"] * radii
            tracks = track_consistency(comps, sub_keys, sub_ts, sub_cls, radii, per_observation=per_obs)
            div, _ = diversity(comps, sub_keys, sub_ts)
        agg = aggregate(tracks, classes=classes_present)
        cons_all = agg["all_objects"]["cd"]
        models.append(
            dict(
                name=names[k],
                model_name=str(getattr(completer, "model_name", names[k])),
                checkpoint=None if checkpoints is None else str(checkpoints[k]),
                n_params=getattr(completer, "n_params", None),
                mean_points_per_completion=float(np.mean([len(c) for c in comps])),
                diversity=div,
                consistency_over_diversity=(cons_all / div if cons_all is not None and np.isfinite(div) and div > 0 else None),
                **agg,
                objects=[
                    dict(sequence=t.key[0], track_id=t.key[1], cls=t.cls, n_observations=t.n_observations,
                         n_pairs=t.n_pairs, n_pairs_empty=t.n_pairs_empty, **t.values)
                    for t in tracks
                ],
            )
        )
    n_tracks = len(set(sub_keys))
    return dict(
        data=dict(
            file=path,
            source_format=obs.meta.get("source_format"),
            source=obs.meta.get("source"),
            n_observations=len(obs),
            n_observations_tracked=int(rows.size),
            n_objects_tracked=n_tracks,
            n_pairs=len(consecutive_pairs(sub_keys, sub_ts)),
            objects_per_class={c: len({k for k, cc in zip(sub_keys, sub_cls) if cc == c}) for c in classes_present},
            extraction=obs.meta.get("config"),
            clip=clip,
            skipped=obs.meta.get("skipped"),
            mmd_reference=reference_info if references is not None else None,
        ),
        metrics=dict(
            headline="cd",
            frame="consistency (cd*, d_*): object frame divided by the track's mean box radius (half diagonal); "
                  "fidelity and mmd: each observation's own unit frame (its box's half diagonal); '_m' keys in metres",
            aggregation="pair -> mean per tracked object -> mean per class; average = mean over classes present; all_objects = mean over objects",
            definitions={**METRIC_DOC, **OBSERVATION_METRIC_DOC, "diversity": DIVERSITY_DOC},
        ),
        models=models,
    )


def _fmt(v, digits=4) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{digits}f}"


def report_markdown(report: dict) -> str:
    """The report as Markdown: a Table-2-style headline table, then the other metric variants."""
    d = report["data"]
    classes = list(d["objects_per_class"])
    lines = ["# Consistency of completions on real scans (paper Table 2)", ""]
    lines.append(
        f"Source: `{d.get('source')}` ({d.get('source_format')}), file `{d.get('file')}`. "
        f"{d['n_objects_tracked']} objects observed in two or more frames "
        f"({d['n_observations_tracked']} of {d['n_observations']} observations, {d['n_pairs']} consecutive pairs); "
        "objects per class: " + ", ".join(f"{c} {n}" for c, n in d["objects_per_class"].items()) + "."
    )
    lines.append("")
    lines.append(
        "Headline: **CD = d(A->B) + d(B->A)**, the paper's Eq. (1) with unsquared Euclidean nearest-neighbour "
        "distances, between completions of the same object in consecutive frames, in the object frame divided by "
        "the track's mean box radius (half diagonal); mean per object, then per class; Average = mean of the class columns. "
        "Lower is better."
    )
    lines.append("")
    head = "| Model | " + " | ".join(c.capitalize() for c in classes) + " | Average | All objects |"
    lines += [head, "|" + "---|" * (len(classes) + 3)]
    for m in report["models"]:
        cells = [_fmt(m["classes"][c]["cd"]) for c in classes]
        lines.append(f"| {m['name']} | " + " | ".join(cells) + f" | {_fmt(m['average']['cd'])} | {_fmt(m['all_objects']['cd'])} |")
    lines += ["", "## Other variants (Average over classes; All objects in brackets)", ""]
    lines += ["| Model | CD (m) | CD/2 | d(A->B) | d(B->A) | CD-L2 (squared) | points per completion |", "|---|---|---|---|---|---|---|"]
    for m in report["models"]:
        a, o = m["average"], m["all_objects"]
        lines.append(
            f"| {m['name']} | {_fmt(a['cd_m'])} ({_fmt(o['cd_m'])}) | {_fmt(a['cd_half'])} ({_fmt(o['cd_half'])}) | "
            f"{_fmt(a['d_ab'])} ({_fmt(o['d_ab'])}) | {_fmt(a['d_ba'])} ({_fmt(o['d_ba'])}) | "
            f"{_fmt(a['cd_l2'], 5)} ({_fmt(o['cd_l2'], 5)}) | {m['mean_points_per_completion']:.0f} |"
        )
    has_mmd = any(m["average"].get("mmd") is not None for m in report["models"])
    lines += ["", "## Consistency beside fidelity" + (" and minimal matching distance" if has_mmd else ""), ""]
    lines.append("Consistency alone rewards a model that gives every scan the same shape; fidelity (does the completion "
                 "keep the observed points?)" + (", MMD (is it close to some complete car?)" if has_mmd else "")
                 + " and diversity tell such a model apart. Average over classes; All objects in brackets; lower is better "
                 "(but for diversity).")
    lines.append("")
    head = "| Model | CD (consistency) | Fidelity | Fidelity (m) |" + (" MMD |" if has_mmd else "") + " Diversity | CD / Diversity |"
    lines += [head, "|---|---|---|---|" + ("---|" if has_mmd else "") + "---|---|"]
    for m in report["models"]:
        a, o = m["average"], m["all_objects"]
        row = (f"| {m['name']} | {_fmt(a['cd'])} ({_fmt(o['cd'])}) | {_fmt(a.get('fidelity'))} ({_fmt(o.get('fidelity'))}) | "
               f"{_fmt(a.get('fidelity_m'))} ({_fmt(o.get('fidelity_m'))}) |")
        if has_mmd:
            row += f" {_fmt(a.get('mmd'))} ({_fmt(o.get('mmd'))}) |"
        row += f" {_fmt(m.get('diversity'))} | {_fmt(m.get('consistency_over_diversity'), 3)} |"
        lines.append(row)
    lines += ["", "Diversity: how much completions of *different* objects differ (mean CD over pairs of tracked objects); "
                  "a model that ignores its input has diversity ~0 and a perfect consistency. CD / Diversity = All objects "
                  "CD over diversity (ours, not the paper's)."]
    ref = d.get("mmd_reference")
    if ref:
        lines += ["", f"MMD reference: {ref['n_shapes']} complete shapes ({ref['points_per_shape']} points each) of "
                      f"`{ref['file']}` (split {ref['split']}), unit frame."]
    lines += ["", "Definitions (A = earlier frame's completion, B = later frame's):", ""]
    for k, v in report["metrics"]["definitions"].items():
        lines.append(f"- `{k}`: {v}")
    skipped = d.get("skipped") or {}
    if skipped:
        lines += ["", "Boxes skipped at extraction: " + ", ".join(f"{k} {v}" for k, v in skipped.items()) + "."]
    for m in report["models"]:
        unscored = sum(m["classes"][c]["n_objects_unscored"] for c in classes)
        if unscored:
            lines.append(f"\n{m['name']}: {unscored} object(s) had only empty completions and are not scored.")
    return "\n".join(lines) + "\n"


def write_report(report: dict, prefix: str | os.PathLike) -> tuple[Path, Path]:
    """Write ``PREFIX.md`` and ``PREFIX.json`` atomically; returns both paths."""
    from ...utils import atomic_output

    prefix = Path(prefix)
    md, js = prefix.with_name(prefix.name + ".md"), prefix.with_name(prefix.name + ".json")

    def clean(x):
        if isinstance(x, float) and not math.isfinite(x):
            return None
        if isinstance(x, dict):
            return {str(k): clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        if isinstance(x, np.generic):
            return clean(x.item())
        return x

    with atomic_output(js) as tmp:
        tmp.write_text(json.dumps(clean(report), indent=2, sort_keys=False) + "\n", encoding="utf-8")
    with atomic_output(md) as tmp:
        tmp.write_text(report_markdown(report), encoding="utf-8")
    return md, js
