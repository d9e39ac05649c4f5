"""Table 2: consistency of the completions of one object across consecutive real frames (Argoverse 2 and nuScenes).

One section per real set (:data:`~..settings.TABLE2_SETS`), each from the report of
:func:`spotlights.experiments.real_evaluation.evaluate_consistency` (``OUT/eval/<set>_consistency.json``)
of every Table 1 and product checkpoint: the paper-style table (per class, at the models' own point
counts and at one common count, the paper's KITTI-360 values beside), then the scores that tell a
consistent model from one that ignores its input (noise floor, fidelity, MMD, diversity...).
"""

from __future__ import annotations

import math

from ....data.real.extract import read_observations
from ... import paper_tables as paper
from ..pipeline import Context, read_json
from ..settings import BASELINE_RUNS, DEFAULT_RUN, DISPLAY, TABLE1_RUNS, TABLE2_CLASSES, TABLE2_RUNS, TABLE2_SETS
from .common import fmt, md_table, value

ELIGIBLE_DIVERSITY = 0.5
"""A baseline takes part in the default model's consistency target when its diversity (at the headline's
resampling) is at least this fraction of the other models' mean diversity (below it, its completions hardly
depend on the input)."""


def headline(rep_data: dict) -> tuple[str, str]:
    """(key suffix, label) of the headline consistency of a report's ``data``: equal density (``"_vox"``,
    voxel-downsampled completions) when the report has it, else the equal count (``"_eq"``)."""
    if rep_data.get("equal_density"):
        return "_vox", f"equal density (voxel {rep_data['equal_density']:g})"
    return "_eq", f"{rep_data.get('equal_points') or '?'} points"


def consistency_values(rep: dict) -> dict:
    """{report row name: Table 2 values} of one consistency report (``evaluate_consistency``'s dict).

    Per model: per class and ``average`` (mean over the classes present) / ``all_objects`` consistency
    ``cd`` at the model's own point count, the same at the report's equal count (keys ``<class>_eq``,
    ``average_eq``, ``all_objects_eq``), ``noise_floor`` / ``noise_floor_eq`` (Average), ``fidelity``,
    ``mmd`` (Average), ``diversity`` / ``diversity_eq``, ``cd_over_diversity_eq`` (all objects CD over
    diversity, at the equal count), ``points_per_completion``, ``out_of_domain`` (observations) and
    ``objects`` (tracked objects per class); the same at equal density with the suffix ``_vox`` (and
    ``points_vox``, points per voxel-downsampled completion). Distances in box half-diagonal units; None
    where not computed.
    """
    out = {}
    for m in rep["models"]:
        eq = m.get("equal_points") or {}
        eq_classes, eq_avg, eq_all = eq.get("classes") or {}, eq.get("average") or {}, eq.get("all_objects") or {}
        vx = m.get("equal_density") or {}
        vx_classes, vx_avg, vx_all = vx.get("classes") or {}, vx.get("average") or {}, vx.get("all_objects") or {}
        out[m["name"]] = {
            **{f"{c}_vox": (vx_classes.get(c) or {}).get("cd") for c in TABLE2_CLASSES},
            "average_vox": vx_avg.get("cd"),
            "all_objects_vox": vx_all.get("cd"),
            "noise_floor_vox": vx_avg.get("noise_floor"),
            "diversity_vox": vx.get("diversity"),
            "cd_over_diversity_vox": vx.get("consistency_over_diversity"),
            "points_vox": vx.get("mean_points_per_completion"),
            **{c: (m["classes"].get(c) or {}).get("cd") for c in TABLE2_CLASSES},
            "average": m["average"]["cd"],
            "all_objects": m["all_objects"]["cd"],
            **{f"{c}_eq": (eq_classes.get(c) or {}).get("cd") for c in TABLE2_CLASSES},
            "average_eq": eq_avg.get("cd"),
            "all_objects_eq": eq_all.get("cd"),
            "noise_floor": m["average"].get("noise_floor"),
            "noise_floor_eq": eq_avg.get("noise_floor"),
            "fidelity": m["average"].get("fidelity"),
            "mmd": m["average"].get("mmd"),
            "diversity": m.get("diversity"),
            "diversity_eq": eq.get("diversity"),
            "cd_over_diversity_eq": eq.get("consistency_over_diversity"),
            "points_per_completion": m["mean_points_per_completion"],
            "out_of_domain": (m.get("out_of_domain") or {}).get("n_observations"),
            "objects": {c: (m["classes"].get(c) or {}).get("n_objects") for c in TABLE2_CLASSES},
        }
    return out


def eligible_baselines(ours: dict, baselines=BASELINE_RUNS, suffix: str = "_eq") -> tuple[list, dict]:
    """The baselines whose completions depend on their input enough to take part in the default model's target.

    A baseline ``b`` of ``ours`` (row -> :func:`consistency_values`) is eligible when its ``diversity<suffix>``
    >= :data:`ELIGIBLE_DIVERSITY` x the mean ``diversity<suffix>`` of every *other* model of ``ours`` (finite
    values only; ``suffix`` "_eq" or "_vox", :func:`headline`). Returns (eligible baselines, {baseline: (its
    diversity, the threshold)}).
    """
    div = {n: value(v.get(f"diversity{suffix}")) for n, v in ours.items()}
    div = {n: d for n, d in div.items() if math.isfinite(d)}
    out, why = [], {}
    for b in baselines:
        if b not in div:
            continue
        others = [d for n, d in div.items() if n != b]
        thr = ELIGIBLE_DIVERSITY * (sum(others) / len(others)) if others else 0.0
        why[b] = (div[b], thr)
        if div[b] >= thr:
            out.append(b)
    return out, why


def consistency_checks(ours: dict, set_label: str, resampling: str, suffix: str = "_eq") -> list:
    """Table 2's checks on one set, at the headline's resampling (``average<suffix>``; ``resampling`` names it
    in the text, e.g. "512 points" or "equal density (voxel 0.1)"): (a) the paper's claim that SA-Net (run
    ``sanet``) is the most consistent of the paper's five models; (b) the issue's target that the default
    model is more consistent than every eligible baseline (:func:`eligible_baselines`)."""
    values = {n: value(v.get(f"average{suffix}")) for n, v in ours.items()}
    paper_models = {n: values[n] for n in TABLE1_RUNS if n in values}
    best = min(paper_models, key=lambda n: paper_models[n]) if paper_models else None
    checks = [
        {
            "claim": f"{set_label}: SA-Net's completions are the most consistent of the paper's five models "
            f"(lowest Average at {resampling})",
            "holds": best == "sanet",
            "detail": ", ".join(f"{n} {fmt(v, 4)}" for n, v in paper_models.items()) if best else "no model scored",
        }
    ]
    eligible, why = eligible_baselines(ours, suffix=suffix)
    d = values.get(DEFAULT_RUN, math.inf)
    beaten = [b for b in eligible if d < values[b]]
    rule = (
        f"eligible baseline = diversity at {resampling} >= {ELIGIBLE_DIVERSITY:g} x the mean diversity of the other "
        "models; "
        + ", ".join(
            f"{b} {fmt(dv, 4)} vs {fmt(thr, 4)} ({'eligible' if b in eligible else 'excluded'})"
            for b, (dv, thr) in why.items()
        )
    )
    if DEFAULT_RUN not in ours or not math.isfinite(d):
        detail, holds = f"{DEFAULT_RUN} not scored; {rule}", False
    else:
        holds = len(beaten) == len(eligible)
        detail = (
            f"{DEFAULT_RUN} CD at {resampling}: Average {fmt(d, 4)}; eligible: "
            + (", ".join(f"{b} {fmt(values[b], 4)}" for b in eligible) or "none (the target holds vacuously)")
            + f"; {rule}"
        )
    checks.append(
        {
            "claim": f"{set_label}: the default model ({DEFAULT_RUN}) is more consistent at {resampling} than every "
            "baseline whose diversity is at least half the others' mean",
            "holds": bool(holds),
            "detail": detail,
        }
    )
    return checks


def _name(run: str) -> str:
    return DISPLAY.get(run, run)


def _missing_section(p, key: str, label: str) -> tuple[list, list, list, dict, dict]:
    """The section of a set whose consistency report is missing: a note and a failed check."""
    claim = f"{label}: Table 2 computed"
    note = f"### {label}\n\nNot computed in this output folder (step `consistency-{key}`)."
    return [note], [], [{"claim": claim, "holds": False, "detail": f"{p} missing"}], {}, {}


def _extra_columns(cols: list, vox) -> list:
    """The CSV columns of a model beyond the per-class consistency at its own count (``vox``: equal density)."""
    return [
        "all_objects",
        *[f"{c}_eq" for c in cols],
        "all_objects_eq",
        *([f"{c}_vox" for c in cols] + ["all_objects_vox", "noise_floor_vox", "diversity_vox"] if vox else []),
        *(["cd_over_diversity_vox", "points_vox"] if vox else []),
        "noise_floor",
        "noise_floor_eq",
        "fidelity",
        "mmd",
        "diversity",
        "diversity_eq",
        "cd_over_diversity_eq",
        "points_per_completion",
        "out_of_domain",
    ]


def _paper_style_table(ours: dict, runs: list, key: str, d: dict) -> tuple[list, list]:
    """Body of the paper-style table of one set (per class, at each resampling, the paper's values) and CSV rows."""
    n_eq = d.get("equal_points") or "?"
    vox = d.get("equal_density")
    cols = list(TABLE2_CLASSES) + ["average"]
    body, rows = [], []
    variants = ([("_vox", f"ours @voxel {vox:g}")] if vox else []) + [
        ("_eq", f"ours @{n_eq}"),
        ("", "ours (own count)"),
    ]
    for run in runs:
        o, pp = ours[run], paper.TABLE2.get(run)
        for k, (suf, lab) in enumerate(variants):
            body.append(
                [f"**{_name(run)}**" if k == 0 else "", lab]
                + [fmt(o[f"{c}{suf}"], 4) for c in cols]
                + [fmt(o[f"all_objects{suf}"], 4)]
            )
        if pp is not None:
            body.append(["", "paper (KITTI-360)", *[fmt(pp[c], 4) for c in cols], ""])
        row = f"{run} ({key})"
        for c in cols:
            rows.append({"row": row, "column": c, "ours": o[c], "paper": None if pp is None else pp[c]})
        for c in _extra_columns(cols, vox):
            rows.append({"row": row, "column": c, "ours": o[c], "paper": None})
    return body, rows


def _headline_text(vox, n_eq) -> str:
    """Why the headline consistency is at equal density (``vox``, voxel side) or at ``n_eq`` points."""
    if vox:
        return (
            f"**Headline: consistency at equal density** (every completion replaced by the centroids of its occupied "
            f"cells of one voxel grid of side {vox:g}, unit frame): two samplings of one surface at different "
            "densities give nearly the same cells, so models that output 560, 2,048 or 16,384 points compare at one "
            "spatial resolution. At the models' own counts (the paper's way) a sparse output is penalised against a "
            f"dense one (a Chamfer between two sparse samplings of one surface is larger); at a fixed count ({n_eq} "
            "points, farthest-point sampling) it is the other way round: the subset draws *different* points from two "
            "nearly identical dense clouds, so a dense model's value there is mostly subsampling noise. Both are shown."
        )
    return (
        f"**Headline: consistency at {n_eq} points** (every completion first brought to {n_eq} points by "
        "farthest-point sampling), because a Chamfer distance between two sparse samplings of one surface is larger "
        "than between two dense ones. The 'own count' rows are consistency as the paper computes it."
    )


def _scores_row(o: dict, name: str, vox, n_tracked) -> list:
    """One model's row of the scores table (CD, noise floors, fidelity, MMD, diversity, points, out of domain)."""
    vox_cells = [
        fmt(o["average_vox"], 4),
        fmt(o["noise_floor_vox"], 4),
        fmt(o["diversity_vox"], 4),
        fmt(o["cd_over_diversity_vox"], 3),
        fmt(o["points_vox"], 0),
    ]
    return (
        [f"**{name}**", fmt(o["average"], 4), fmt(o["noise_floor"], 4)]
        + (vox_cells if vox else [])
        + [
            fmt(o["average_eq"], 4),
            fmt(o["noise_floor_eq"], 4),
            fmt(o["fidelity"], 4),
            fmt(o["mmd"], 4),
            fmt(o["diversity"], 4),
            fmt(o["diversity_eq"], 4),
            fmt(o["cd_over_diversity_eq"], 3),
            f"{o['points_per_completion']:.0f}",
            "-" if o["out_of_domain"] is None else f"{o['out_of_domain']} / {n_tracked}",
        ]
    )


def _scores_table(ours: dict, runs: list, d: dict) -> list:
    """Markdown lines of the scores that tell a consistent model from one that ignores its input."""
    n_eq = d.get("equal_points") or "?"
    vox = d.get("equal_density")
    vhead = ["CD @voxel", "noise floor @voxel", "diversity @voxel", "CD / diversity @voxel", "points @voxel"]
    return md_table(
        ["Model", "CD", "noise floor"]
        + (vhead if vox else [])
        + [
            f"CD @{n_eq}",
            f"noise floor @{n_eq}",
            "fidelity",
            "MMD",
            "diversity",
            f"diversity @{n_eq}",
            f"CD / diversity @{n_eq}",
            "points per completion",
            "out of domain",
        ],
        [_scores_row(ours[n], _name(n), vox, d["n_observations_tracked"]) for n in runs],
    )


def _set_section(ctx: Context, key: str, label: str) -> tuple[list, list, list, dict, dict]:
    """Markdown lines, CSV rows, checks, values and data counts of one set's Table 2 section."""
    p = ctx.out / "eval" / f"{key}_consistency.json"
    if not p.is_file():
        return _missing_section(p, key, label)
    rep = read_json(p)
    ours = consistency_values(rep)
    d = rep["data"]
    suffix, hl = headline(d)
    runs = [r for r in TABLE2_RUNS if r in ours]
    head = ["Model", "", *[c.capitalize() for c in TABLE2_CLASSES], "Average", "All objects"]
    body, rows = _paper_style_table(ours, runs, key, d)
    per_class = ", ".join(f"{c} {n}" for c, n in (d.get("objects_per_class") or {}).items())
    md = [
        f"### {label}",
        "",
        f"{d['n_objects_tracked']} vehicles seen in two or more frames ({per_class}; "
        f"{d.get('n_objects_5_or_more', '?')} in 5 or more), {d['n_pairs']} consecutive pairs, "
        f"{d['n_observations_tracked']} observations. "
        + _headline_text(d.get("equal_density"), d.get("equal_points") or "?"),
        "",
    ]
    md += md_table(head, body)
    md += [
        "",
        "Average over classes (All objects for CD / diversity); lower is better except diversity and points.",
        "",
    ]
    md += _scores_table(ours, runs, d)
    checks = consistency_checks(ours, label, hl, suffix)
    eligible, _ = eligible_baselines(ours, suffix=suffix)
    md += [
        "",
        f"The default model's target on {label}: at {hl} its Average consistency is lower than that of every "
        f"baseline whose diversity there is at least {ELIGIBLE_DIVERSITY:g} x the mean diversity of the other "
        f"models (eligible here: {', '.join(eligible) or 'none'}): **{'met' if checks[1]['holds'] else 'not met'}**.",
        "",
    ]
    data = {
        k: d.get(k)
        for k in ("n_objects_tracked", "n_objects_5_or_more", "n_pairs", "objects_per_class", "n_observations")
    }
    return md, rows, checks, ours, data


def build_table2(ctx: Context) -> dict:
    """Table 2 on every real set of :data:`TABLE2_SETS`: one section each (see the module docstring)."""
    md = [
        "Consistency = CD between the completions of the same object in consecutive frames (Eq. 1, unsquared, both "
        "directions summed), object frame / the track's mean box half diagonal, mean per object then per class "
        "(lower is better); classes car, truck and trailer (the paper's KITTI-360 classes without caravan, which "
        "neither set has). Our Average is the mean over the classes present; the paper's over its four classes "
        "(KITTI-360, 4,382 observations). Beside it: the **noise floor** (the same CD between two completions of one "
        "observation whose points were resampled with two seeds: what resampling alone explains), **fidelity** "
        "(observed points -> completion: does it keep what the LiDAR saw?), **MMD** (Chamfer to the nearest complete "
        "car of the synthetic dataset: does it look like a car?), **diversity** (mean Chamfer between completions of "
        "*different* objects; near 0: the same shape whatever the input, which is trivially consistent) and the "
        "observations outside what a model learned (class or box size). Read this table with Table 1: an "
        "under-trained model can score well here.",
        "",
    ]
    rows, checks, ours, data = [], [], {}, {}
    for key, label in TABLE2_SETS.items():
        m, r, c, o, d = _set_section(ctx, key, label)
        md += m
        rows += r
        checks += c
        ours[key], data[key] = o, d
    kitti_obs = None
    kp = ctx.out / "data" / "kitti.h5"
    if kp.is_file():
        kitti_obs = len(read_observations(kp))
    md += [
        f"KITTI: the shipped KITTI object frames ({kitti_obs if kitti_obs is not None else '?'} vehicles) carry no track ids, "
        "so no object is seen twice and consistency cannot be computed there; they appear in the qualitative figure.",
    ]
    return {
        "ours": ours,
        "paper": paper.TABLE2,
        "rows": rows,
        "checks": checks,
        "markdown": "\n".join(md),
        "data": data,
    }
