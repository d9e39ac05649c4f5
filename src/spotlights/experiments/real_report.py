"""The consistency report of :func:`spotlights.experiments.real_evaluation.evaluate_consistency` as Markdown
and JSON (the paper's Table 2 and the columns beyond it)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from ..outputs import atomic_output


def _fmt(v, digits=4) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{digits}f}"


def _resampled_cells(entry: dict, last: str, bold: bool = False) -> str:
    """Table cells of one resampled score (``equal_points`` / ``equal_density`` entry of a model): CD and noise
    floor (Average, All objects in brackets), diversity, then ``last``."""
    a, o = entry.get("average", {}), entry.get("all_objects", {})
    cd = f"**{_fmt(a.get('cd'))}**" if bold else _fmt(a.get("cd"))
    return (
        f" {cd} ({_fmt(o.get('cd'))}) | {_fmt(a.get('noise_floor'))} ({_fmt(o.get('noise_floor'))}) |"
        f" {_fmt(entry.get('diversity'))} | {last} |"
    )


def report_markdown(report: dict) -> str:
    """The report as Markdown: a Table-2-style headline table, then the other metric variants."""
    lines = _headline_lines(report) + _variant_lines(report) + _fidelity_lines(report) + _extra_lines(report)
    return "\n".join(lines + _closing_lines(report)) + "\n"


def _headline_lines(report: dict) -> list[str]:
    """The title, the data's description and the Table-2-style headline table (CD per class)."""
    d = report["data"]
    classes = list(d["objects_per_class"])
    lines = ["# Consistency of completions on real scans (paper Table 2)", ""]
    lines.append(
        f"Source: `{d.get('source')}` ({d.get('source_format')}), file `{d.get('file')}`. "
        f"{d['n_objects_tracked']} objects observed in two or more frames "
        f"({d['n_observations_tracked']} of {d['n_observations']} observations, {d['n_pairs']} consecutive pairs; "
        f"{d.get('n_objects_5_or_more', '?')} objects with 5 or more observations); "
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
        lines.append(
            f"| {m['name']} | "
            + " | ".join(cells)
            + f" | {_fmt(m['average']['cd'])} | {_fmt(m['all_objects']['cd'])} |"
        )
    return lines


def _variant_lines(report: dict) -> list[str]:
    """The CD variants: in metres, halved, one-sided, squared; points per completion."""
    lines = ["", "## Other variants (Average over classes; All objects in brackets)", ""]
    lines += [
        "| Model | CD (m) | CD/2 | d(A->B) | d(B->A) | CD-L2 (squared) | points per completion |",
        "|---|---|---|---|---|---|---|",
    ]
    for m in report["models"]:
        a, o = m["average"], m["all_objects"]
        lines.append(
            f"| {m['name']} | {_fmt(a['cd_m'])} ({_fmt(o['cd_m'])}) | {_fmt(a['cd_half'])} ({_fmt(o['cd_half'])}) | "
            f"{_fmt(a['d_ab'])} ({_fmt(o['d_ab'])}) | {_fmt(a['d_ba'])} ({_fmt(o['d_ba'])}) | "
            f"{_fmt(a['cd_l2'], 5)} ({_fmt(o['cd_l2'], 5)}) | {m['mean_points_per_completion']:.0f} |"
        )
    return lines


def _fidelity_lines(report: dict) -> list[str]:
    """Consistency beside fidelity, MMD (when a reference was given) and diversity."""
    has_mmd = any(m["average"].get("mmd") is not None for m in report["models"])
    lines = ["", "## Consistency beside fidelity" + (" and minimal matching distance" if has_mmd else ""), ""]
    lines.append(
        "Consistency alone rewards a model that gives every scan the same shape; fidelity (does the completion "
        "keep the observed points?)"
        + (", MMD (is it close to some complete car?)" if has_mmd else "")
        + " and diversity tell such a model apart. Average over classes; All objects in brackets; lower is better "
        "(but for diversity)."
    )
    lines.append("")
    head = (
        "| Model | CD (consistency) | Fidelity | Fidelity (m) |"
        + (" MMD |" if has_mmd else "")
        + " Diversity | CD / Diversity |"
    )
    lines += [head, "|---|---|---|---|" + ("---|" if has_mmd else "") + "---|---|"]
    for m in report["models"]:
        a, o = m["average"], m["all_objects"]
        row = (
            f"| {m['name']} | {_fmt(a['cd'])} ({_fmt(o['cd'])}) | {_fmt(a.get('fidelity'))} ({_fmt(o.get('fidelity'))}) | "
            f"{_fmt(a.get('fidelity_m'))} ({_fmt(o.get('fidelity_m'))}) |"
        )
        if has_mmd:
            row += f" {_fmt(a.get('mmd'))} ({_fmt(o.get('mmd'))}) |"
        row += f" {_fmt(m.get('diversity'))} | {_fmt(m.get('consistency_over_diversity'), 3)} |"
        lines.append(row)
    lines += [
        "",
        "Diversity: how much completions of *different* objects differ (mean CD over pairs of tracked objects); "
        "a model that ignores its input has diversity ~0 and a perfect consistency. CD / Diversity = All objects "
        "CD over diversity (ours, not the paper's).",
    ]
    return lines


def _extra_lines(report: dict) -> list[str]:
    """Noise floor, equal density, equal point counts, heading flips and out-of-domain counts (when scored)."""
    d = report["data"]
    lines: list[str] = []
    extra = any(k in m for m in report["models"] for k in ("equal_points", "equal_density", "heading")) or any(
        m["average"].get("noise_floor") is not None for m in report["models"]
    )
    if not extra:
        return lines
    eq = d.get("equal_points")
    vox = d.get("equal_density")
    lines += ["", "## Noise floor, equal density, equal point counts, heading check", ""]
    lines.append(_extra_intro(eq, vox))
    lines.append("")
    head = _extra_head(report, eq, vox)
    lines += [head, "|" + "---|" * (head.count("|") - 1)]
    lines += [_extra_row(m, d, eq, vox) for m in report["models"]]
    for m in report["models"]:
        od = m.get("out_of_domain")
        if od and od["n_observations"]:
            lines.append(
                f"\nWarning - {m['name']}: {od['n_observations']} of {d['n_observations_tracked']} observations are "
                "outside what the model learned ("
                + "; ".join(f"{k}: {v}" for k, v in od["reasons"].items())
                + "): their completions extrapolate."
            )
    if d.get("noise_floor") and not str(d["noise_floor"]).startswith("kept"):
        lines.append(f"\nNoise floor {d['noise_floor']}.")
    return lines


def _extra_intro(eq, vox) -> str:
    """The paragraph that defines the noise floor, the equal-count and equal-density scores (when
    scored: ``eq`` points, voxel side ``vox``) and the heading flips."""
    return (
        "Noise floor: consistency's CD between two completions of the *same* observation, its points "
        "resampled to the network's input with two seeds - the part of CD that resampling alone explains. "
        + (
            f"At {eq} points: every completion brought to {eq} points by farthest-point sampling first (one "
            "count for every model). "
            if eq
            else ""
        )
        + (
            f"At equal density (voxel {vox:g}): every completion replaced by the centroids of its occupied cells "
            f"of one grid of side {vox:g} (unit frame), so shapes compare at one spatial resolution whatever each "
            "model's output density - **the headline for comparing models** (a fixed count draws different points "
            "from two nearly identical dense clouds, so for dense models it mostly measures subsampling noise). "
            if vox
            else ""
        )
        + "Heading flips: observations whose completion with the box turned around is closer to the observed "
        "points (on annotated boxes, false alarms of `--heading-check`). Average over classes; All objects in brackets."
    )


def _extra_head(report: dict, eq, vox) -> str:
    """The header row of the noise-floor table (its columns depend on what was scored)."""
    head = "| Model | CD | Noise floor |"
    if vox:
        head += f" **CD @voxel {vox:g}** | Noise floor @voxel | Diversity @voxel | points @voxel |"
    if eq:
        head += f" CD @{eq} | Noise floor @{eq} | Diversity @{eq} | CD / Diversity @{eq} |"
    margins = {m["heading"]["margin"] for m in report["models"] if m.get("heading")}
    head += (
        f" Heading flips (margin {margins.pop():g}) |" if len(margins) == 1 else " Heading flips |"
    ) + " Out of domain |"
    return head


def _extra_row(m: dict, d: dict, eq, vox) -> str:
    """One model's row of the noise-floor table."""
    a, o = m["average"], m["all_objects"]
    row = f"| {m['name']} | {_fmt(a['cd'])} ({_fmt(o['cd'])}) | {_fmt(a.get('noise_floor'))} ({_fmt(o.get('noise_floor'))}) |"
    if vox:
        v = m.get("equal_density") or {}
        row += _resampled_cells(v, _fmt(v.get("mean_points_per_completion"), 0), bold=True)
    if eq:
        e = m.get("equal_points") or {}
        row += _resampled_cells(e, _fmt(e.get("consistency_over_diversity"), 3))
    h = m.get("heading")
    row += (
        f" {h['n_flipped']} / {h['n_observations']} ({100 * h['rate']:.1f}%; {100 * h['rate_margin0']:.1f}% at margin 0) |"
        if h and h.get("rate") is not None
        else " - |"
    )
    od = m.get("out_of_domain")
    row += f" {od['n_observations']} / {d['n_observations_tracked']} |" if od else " - |"
    return row


def _closing_lines(report: dict) -> list[str]:
    """The MMD reference, the metric definitions, the boxes skipped at extraction and the unscored objects."""
    d = report["data"]
    classes = list(d["objects_per_class"])
    lines: list[str] = []
    ref = d.get("mmd_reference")
    if ref:
        lines += [
            "",
            f"MMD reference: {ref['n_shapes']} complete shapes ({ref['points_per_shape']} points each) of "
            f"`{ref['file']}` (split {ref['split']}), unit frame.",
        ]
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
    return lines


def _json_ready(x):
    """``x`` with non-finite floats as None, numpy scalars as Python numbers, tuples as lists."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {str(k): _json_ready(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_ready(v) for v in x]
    if isinstance(x, np.generic):
        return _json_ready(x.item())
    return x


def write_report_json(report: dict, path: str | os.PathLike) -> Path:
    """Write a consistency report as JSON at ``path`` atomically (NaN as null); returns the path."""
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(_json_ready(report), indent=2, sort_keys=False) + "\n", encoding="utf-8")
    return Path(path)


def write_report(report: dict, prefix: str | os.PathLike) -> tuple[Path, Path]:
    """Write ``PREFIX.md`` and ``PREFIX.json`` atomically; returns both paths."""
    prefix = Path(prefix)
    md, js = prefix.with_name(prefix.name + ".md"), prefix.with_name(prefix.name + ".json")
    write_report_json(report, js)
    with atomic_output(md) as tmp:
        tmp.write_text(report_markdown(report), encoding="utf-8")
    return md, js
