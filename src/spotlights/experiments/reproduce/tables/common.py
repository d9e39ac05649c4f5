"""Helpers of the table builders: number formatting, Markdown tables, the evaluate reports and the runs' facts."""

from __future__ import annotations

import math

from ...paper_tables import CAR_CATEGORIES
from ..pipeline import Context, read_json
from ..steps import run_info


def value(x) -> float:
    """A value for comparisons: None / NaN (e.g. every completion empty) -> +inf."""
    return float("inf") if x is None or not math.isfinite(float(x)) else float(x)


def fmt(x, digits=5) -> str:
    """``x`` with ``digits`` decimals; "-" for None or NaN."""
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}f}"


def diff(ours, ref) -> str:
    """Relative difference of ours against the reference in per cent ("+12%"); "-" when undefined."""
    if ours is None or ref is None or not math.isfinite(ours) or not ref:
        return "-"
    return f"{100.0 * (ours / ref - 1.0):+.0f}%"


def md_table(head: list, body: list) -> list:
    """Lines of a Markdown table."""
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + [
        "| " + " | ".join(map(str, r)) + " |" for r in body
    ]


def eval_rows(ctx: Context, run: str, label: str | None = None) -> dict:
    """{row name: {category..., average, completeness, chamfer_l1, fscore, n_points, params_m, latency...}}
    from one run's evaluate report (means over the test scans, unit frame; runtimes in ms).

    Rows are named ``model (variant)`` (``sanet (clip 0.2)``, ``sanet-hit (p(hit) >= 0.3)``), or
    ``label (variant)`` with ``label`` given (two runs of one model: name them after the runs).
    """
    rep = read_json(ctx.eval_json(run))
    res = rep["results"][0]
    out = {}
    for row in res["rows"]:
        name = (label or res["model"]) + (f" ({row['variant']})" if row["variant"] else "")
        s = row["summary"]
        lat = res.get("latency_ms") or {}
        key = "complete_ms" if (row["clip"] is not None or res["model"] != "sanet") else "forward_ms"
        out[name] = {
            **{c: s["per_category"].get(c, {}).get("accuracy") for c in CAR_CATEGORIES},
            "average": s["mean_over_samples"]["accuracy"],
            "average_categories": s["mean_over_categories"]["accuracy"],
            "completeness": s["mean_over_samples"].get("completeness"),
            "completeness_per_category": {c: s["per_category"].get(c, {}).get("completeness") for c in CAR_CATEGORIES},
            "n_points": s["mean_over_samples"].get("n_points"),
            "chamfer_l1": s["mean_over_samples"].get("chamfer_l1"),
            "fscore": s["mean_over_samples"].get("fscore"),
            "hit_ratio": s["mean_over_samples"].get("hit_ratio"),
            "params_m": res["params"]["total"] / 1e6,
            "runtime_ms": (lat.get("1") or {}).get(key),
            "runtime_b32_ms": (lat.get("32") or {}).get(key),
            "n_samples": rep["n_samples"],
            "n_models": rep["n_models"],
            "epochs": res["trained_epochs"],
            "latency_device": res.get("latency_device"),
            "threads": res.get("threads"),
        }
    return out


def run_facts(ctx: Context, runs) -> dict:
    """{run: facts of its training (steps, epochs, seconds...)} from the step records or the checkpoints."""
    out = {}
    for r in runs:
        rec = ctx.records.get(f"train-{r}", {})
        info = rec.get("info") or {}
        if not info and (ctx.run_dir(r) / "last.pt").is_file():
            info = run_info(ctx.run_dir(r))
        out[r] = info
    return out


def duration(seconds: float) -> str:
    """A training time for the tables' text: '95 s' below two minutes, else whole minutes ('75 min')."""
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"


def training_note(ctx: Context, runs) -> str:
    """One line per run: steps, batch, epochs and minutes of training (for the text under a table)."""
    facts = run_facts(ctx, runs)
    parts = [
        f"{r}: {f.get('steps', 0):,} steps of {f.get('batch_size', '?')} ({f.get('epochs', '?')} epochs, "
        f"{duration(float(f.get('train_seconds') or 0))} of training)"
        if f
        else f"{r}: ?"
        for r, f in facts.items()
    ]
    return "; ".join(parts)
