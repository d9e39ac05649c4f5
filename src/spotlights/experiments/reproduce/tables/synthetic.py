"""Tables 1 and 5: completion accuracy on the synthetic cars (five models; SA-Net at three sampling resolutions)."""

from __future__ import annotations

import math

from ....errors import SpotlightsError
from ... import paper_tables as paper
from ..pipeline import Context
from ..settings import DISPLAY, TABLE1_RUNS, TABLE5_RUNS
from .common import diff, eval_rows, fmt, md_table, training_note, value


def build_table1(ctx: Context) -> dict:
    ours = {}
    for run in TABLE1_RUNS:
        ours.update(eval_rows(ctx, run))
    # the clipped SA-Net row is named after the checkpoint's clip (the paper's is 0.2)
    clipped = next((k for k in ours if k.startswith("sanet (clip")), "sanet (clip 0.2)")
    order = ["atlasnet", "pcn", "foldingnet", "topnet", "sanet (no clip)", clipped]
    cols = list(paper.CAR_CATEGORIES) + ["average"]
    head = ["Method", "", "Hatchback", "Sedan", "SUV", "Average", "#Params", "Runtime b1 (ms)"]
    body, rows = [], []
    for name in order:
        o, p = ours.get(name), paper.TABLE1["sanet (clip 0.2)" if name == clipped else name]
        if o is None:
            continue
        label = DISPLAY[name.split(" ")[0]] + (" " + name.split(" ", 1)[1] if " " in name else "")
        body.append(
            [f"**{label}**", "ours", *[fmt(o[c]) for c in cols], f"{o['params_m']:.2f}M", fmt(o["runtime_ms"], 2)]
        )
        body.append(["", "paper", *[fmt(p[c]) for c in cols], f"{p['params_m']:.1f}M", fmt(p["runtime_ms"], 2)])
        body.append(["", "ours vs paper", *[diff(o[c], p[c]) for c in cols], "", ""])
        for c in cols + ["params_m", "runtime_ms"]:
            rows.append({"row": name, "column": c, "ours": o.get(c), "paper": p.get(c)})
    avg = {n: value(ours[n]["average"]) for n in order if n in ours}
    best = min(avg, key=lambda n: avg[n]) if avg else None
    checks = [
        {
            "claim": "SA-Net with clip is the most accurate method (lowest Average)",
            "holds": best == clipped,
            "detail": f"lowest Average: {best} ({fmt(avg.get(best))})" if best else "-",
        },
        {
            "claim": "the clip improves SA-Net's accuracy",
            "holds": bool(avg.get(clipped, math.inf) < avg.get("sanet (no clip)", math.inf)),
            "detail": f"no clip {fmt(avg.get('sanet (no clip)'))}, {clipped[7:-1]} {fmt(avg.get(clipped))}",
        },
        {
            "claim": "SA-Net has the fewest parameters and the shortest runtime",
            "holds": bool(
                ours
                and min(ours, key=lambda n: ours[n]["params_m"]).startswith("sanet")
                and min(ours, key=lambda n: value(ours[n]["runtime_ms"])).startswith("sanet")
            ),
            "detail": ", ".join(
                f"{n}: {ours[n]['params_m']:.2f}M / {fmt(ours[n]['runtime_ms'], 2)} ms" for n in order if n in ours
            ),
        },
    ]
    any_row = next(iter(ours.values())) if ours else {}
    md = [
        f"Accuracy = one-sided CD prediction -> 16,384-point dense ground truth (unit frame, lower is better), on the "
        f"test split: {any_row.get('n_samples', '?')} scans of {any_row.get('n_models', '?')} cars. Average = mean over scans "
        "(the paper's Average). Runtime: median time of one scan (batch 1), forward pass (SA-Net no clip) or forward + "
        f"decoding (the others), on {any_row.get('latency_device') or '?'} with {any_row.get('threads') or '?'} threads "
        "(the paper: a GPU).",
        "",
    ]
    md += md_table(head, body)
    md += [
        "",
        f"Training (schedule `{ctx.s.schedule}` for new runs; each run's own config kept when reused): "
        + training_note(ctx, TABLE1_RUNS)
        + ".",
    ]
    return {"ours": ours, "paper": paper.TABLE1, "rows": rows, "checks": checks, "markdown": "\n".join(md)}


def build_table5(ctx: Context) -> dict:
    cols = list(paper.CAR_CATEGORIES) + ["average"]
    ours = {}
    for res_name, run in TABLE5_RUNS.items():
        ev = eval_rows(ctx, run)
        row = next((v for k, v in ev.items() if "clip" in k and "no clip" not in k), None)
        if row is None:
            raise SpotlightsError(
                f"{ctx.run_dir(run)}: run {run} has no clipped SA-Net row to put in Table 5 "
                "(its checkpoint sets no clip); retrain it with the default clip"
            )
        ours[res_name] = row
    head = ["Resolution", "", "Hatchback", "Sedan", "SUV", "Average", "hit ratio (clip)"]
    body, rows = [], []
    for name, o in ours.items():
        p = paper.TABLE5[name]
        body.append([f"**{name.replace('x', '*')}**", "ours", *[fmt(o[c]) for c in cols], fmt(o.get("hit_ratio"), 3)])
        body.append(["", "paper", *[fmt(p[c]) for c in cols], ""])
        body.append(["", "ours vs paper", *[diff(o[c], p[c]) for c in cols], ""])
        for c in cols:
            rows.append({"row": name, "column": c, "ours": o[c], "paper": p[c]})
    a = {k: value(v["average"]) for k, v in ours.items()}
    rel = abs(a["64x32"] / a["32x64"] - 1.0) if math.isfinite(a["64x32"] + a["32x64"]) else math.inf
    checks = [
        {
            "claim": "32*64 and 64*32 (same ray count) perform alike (within 5%)",
            "holds": bool(rel < 0.05),
            "detail": f"{fmt(a['32x64'])} vs {fmt(a['64x32'])} ({100 * rel:.1f}% apart; paper 2.2%)",
        },
        {
            "claim": "256*64 (8x the rays) is the most accurate",
            "holds": bool(a["256x64"] < min(a["32x64"], a["64x32"])),
            "detail": ", ".join(f"{k}: {fmt(v)}" for k, v in a.items()),
        },
    ]
    md = [
        "SA-Net (with clip 0.2) trained on the Spotlights ground truth of three rigs (N*M: N viewpoints, M rays each, "
        "60°; 2048, 2048 and 16,384 rays), accuracy as in Table 1 on the same test scans. The 32*64 row is the Table 1 "
        "run. hit ratio (clip) = share of the rig's rays kept after the clip.",
        "",
    ]
    md += md_table(head, body)
    md += ["", "Training: " + training_note(ctx, TABLE5_RUNS.values()) + "."]
    return {"ours": ours, "paper": paper.TABLE5, "rows": rows, "checks": checks, "markdown": "\n".join(md)}
