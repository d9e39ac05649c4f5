"""Tables 3 and 4: completeness and hit ratio of the cap rigs (ray count x opening angle), from the rig study."""

from __future__ import annotations

import numpy as np

from ... import paper_tables as paper
from ...rig_study import CARS
from ..pipeline import Context
from ..settings import ABLATION_RAYS, ANGLE_LABELS, HIT_RATIO_RAYS
from .common import fmt, md_table


def _study_summary(ctx: Context):
    import pandas as pd

    s = pd.read_csv(ctx.out / "rig_study" / "summary.csv")
    s["angle"] = s["label"].map(ANGLE_LABELS)
    return s[s["angle"].notna()]


def _ablation_values(ctx: Context, metric: str, rays_list) -> tuple[dict, list, list, dict]:
    """{(rays, angle): {category: mean, "average": mean over the paper's 6, "average_all": over ours, "cars": ...}}."""
    s = _study_summary(ctx)
    cats_set = s[(s.mesh_set != CARS) & (s.category != "all")]
    cats = sorted(set(cats_set.category))
    extra = [c for c in cats if c not in paper.ABLATION_CATEGORIES]
    counts = {
        str(k): int(v) for k, v in cats_set.drop_duplicates(["category"]).set_index("category")["n_meshes"].items()
    }
    out = {}
    scale = 100.0 if metric == "hit_ratio" else 1.0
    for rays in rays_list:
        for angle in (30, 60, 83):
            sub = cats_set[(cats_set.rays == rays) & (cats_set.angle == angle)]
            vals = {c: float(sub[sub.category == c][metric].iloc[0]) * scale for c in cats if (sub.category == c).any()}
            six = [vals[c] for c in paper.ABLATION_CATEGORIES if c in vals]
            car = s[(s.mesh_set == CARS) & (s.category == "all") & (s.rays == rays) & (s.angle == angle)]
            out[(rays, angle)] = {
                **vals,
                "average": float(np.mean(six)) if six else None,
                "average_all": float(np.mean(list(vals.values()))) if vals else None,
                "cars": float(car[metric].iloc[0]) * scale if len(car) else None,
            }
    return out, cats, extra, counts


def build_table3(ctx: Context) -> dict:
    vals, cats, extra, counts = _ablation_values(ctx, "completeness", ABLATION_RAYS)
    p6 = list(paper.ABLATION_CATEGORIES)
    head = [
        "#Rays",
        "Angle",
        "",
        *[c.capitalize() for c in p6],
        "Average (6)",
        *[c.capitalize() for c in extra],
        f"Average ({len(cats)})",
        "Cars",
    ]
    body, rows = [], []
    for (rays, angle), o in vals.items():
        p = paper.TABLE3[(rays, angle)]
        body.append(
            [
                f"**{rays}**",
                f"{angle}°",
                "ours",
                *[fmt(o.get(c), 4) for c in p6],
                fmt(o["average"], 4),
                *[fmt(o.get(c), 4) for c in extra],
                fmt(o["average_all"], 4),
                fmt(o["cars"], 4),
            ]
        )
        body.append(["", "", "paper", *[fmt(p[c], 4) for c in p6], fmt(p["average"], 4), *[""] * len(extra), "", ""])
        for c in p6 + ["average"]:
            rows.append({"row": f"{rays} rays {angle} deg", "column": c, "ours": o.get(c), "paper": p.get(c)})
        for c in extra + ["average_all", "cars"]:
            rows.append({"row": f"{rays} rays {angle} deg", "column": c, "ours": o.get(c), "paper": None})
    checks = []
    for key, lab in (
        ("average", "the paper's 6 categories"),
        ("average_all", f"all {len(cats)} categories"),
        ("cars", "the cars"),
    ):
        if any(vals[k][key] is None for k in vals):
            continue
        for angle in (30, 60, 83):
            seq = [vals[(r, angle)][key] for r in ABLATION_RAYS]
            checks.append(
                {
                    "claim": f"completeness improves with the ray count ({angle}°, {lab})",
                    "holds": all(a > b for a, b in zip(seq, seq[1:])),
                    "detail": " > ".join(fmt(v, 4) for v in seq),
                }
            )
        for rays in ABLATION_RAYS:
            c30, c60, c83 = (vals[(rays, a)][key] for a in (30, 60, 83))
            checks.append(
                {
                    "claim": f"at {rays} rays, 60° beats 30° and 83° ({lab})",
                    "holds": bool(c60 < c30 and c60 < c83),
                    "detail": f"30°: {fmt(c30, 4)}, 60°: {fmt(c60, 4)}, 83°: {fmt(c83, 4)}",
                }
            )
    md = [
        "Completeness = mean distance from 16,384 uniform surface points to the Spotlights points (one-sided, "
        "unsquared, unit frame; lower is better), N x 64 rays (N = rays / 64), each object normalised by its own box. "
        f"Ours on `{ctx.s.category_meshes}`: the categories with at least 5 meshes ({', '.join(f'{c} {counts.get(c, 0)}' for c in cats)} "
        f"meshes{' used by --quick' if ctx.s.quick else ''}); the paper's 6 ShapeNet categories first, 'Average (6)' over them as "
        "in the paper, then our other categories, the average over all of ours, and the cars of the car dataset "
        "(mean over the cars). 83° = r = R/4 (82.8°).",
        "",
    ]
    md += md_table(head, body)
    return {
        "ours": {f"{r}x{a}": v for (r, a), v in vals.items()},
        "paper": {f"{r}x{a}": v for (r, a), v in paper.TABLE3.items()},
        "categories": cats,
        "meshes": counts,
        "rows": rows,
        "checks": checks,
        "markdown": "\n".join(md),
    }


def build_table4(ctx: Context) -> dict:
    vals, cats, extra, counts = _ablation_values(ctx, "hit_ratio", ABLATION_RAYS)
    p6 = list(paper.ABLATION_CATEGORIES)
    head = [
        "Angle",
        "",
        *[c.capitalize() for c in p6],
        "Average (6)",
        *[c.capitalize() for c in extra],
        f"Average ({len(cats)})",
        "Cars",
    ]
    body, rows = [], []
    for angle in (30, 60, 83):
        o, p = vals[(HIT_RATIO_RAYS, angle)], paper.TABLE4[angle]
        body.append(
            [
                f"**{angle}°**",
                "ours",
                *[fmt(o.get(c), 1) for c in p6],
                fmt(o["average"], 1),
                *[fmt(o.get(c), 1) for c in extra],
                fmt(o["average_all"], 1),
                fmt(o["cars"], 1),
            ]
        )
        body.append(["", "paper", *[fmt(p[c], 1) for c in p6], fmt(p["average"], 1), *[""] * len(extra), "", ""])
        for c in p6 + ["average"]:
            rows.append({"row": f"{angle} deg", "column": c, "ours": o.get(c), "paper": p.get(c)})
        for c in extra + ["average_all", "cars"]:
            rows.append({"row": f"{angle} deg", "column": c, "ours": o.get(c), "paper": None})
    spread = max(
        abs(vals[(r, a)]["average_all"] - vals[(HIT_RATIO_RAYS, a)]["average_all"])
        for r in ABLATION_RAYS
        for a in (30, 60, 83)
    )
    checks = []
    for key in ["average", "average_all", "cars"] + cats:
        seq = [vals[(HIT_RATIO_RAYS, a)].get(key) for a in (30, 60, 83)]
        if None in seq:
            continue
        checks.append(
            {
                "claim": f"the hit ratio falls as the angle grows ({key})",
                "holds": bool(seq[0] > seq[1] > seq[2]),
                "detail": " > ".join(f"{v:.1f}%" for v in seq),
            }
        )
    ours_avg = [vals[(HIT_RATIO_RAYS, a)]["average"] for a in (30, 60, 83)]
    md = [
        f"Hit ratio = rays that hit the object / all rays (%), at {HIT_RATIO_RAYS} rays (the paper does not give the ray "
        f"count; at 4096 and 8192 rays our averages differ by at most {spread:.1f} points). Same meshes and columns as "
        f"Table 3. Paper averages 78.6 / 50.9 / 34.8 %; ours (6 categories) {' / '.join(fmt(v, 1) for v in ours_avg)} %.",
        "",
    ]
    md += md_table(head, body)
    lower = [a for a, o in zip((30, 60, 83), ours_avg) if o is not None and o < paper.TABLE4[a]["average"] - 2.0]
    if lower:
        md += [
            "",
            f"Our hit ratios are lower than the paper's at {', '.join(f'{a}°' for a in lower)}: each of our objects is "
            "normalised by its axis-aligned box (centre and half diagonal, the paper's step 1), so it fills less of the "
            "unit sphere the wider the cap looks around it; different meshes and the paper's unstated details of the "
            "normalisation can account for the gap. The ordering by angle is the paper's.",
        ]
    return {
        "ours": {str(a): vals[(HIT_RATIO_RAYS, a)] for a in (30, 60, 83)},
        "ours_by_rays": {f"{r}x{a}": v for (r, a), v in vals.items()},
        "paper": {str(a): v for a, v in paper.TABLE4.items()},
        "rows": rows,
        "checks": checks,
        "markdown": "\n".join(md),
    }
