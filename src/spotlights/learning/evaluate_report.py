"""The report of ``spotlights evaluate``: Markdown (Table 1 under one protocol, accuracy per category, every
metric, parameters, definitions) and JSON, from the dict of :func:`spotlights.learning.evaluate.evaluate_checkpoints`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..metrics.completion import METRIC_DESCRIPTIONS
from ..outputs import atomic_output
from .models import DISPLAY_NAMES

TABLE_METRIC = "accuracy"
OTHER_METRICS = ("completeness", "chamfer_l1", "chamfer_l2", "fscore", "hit_ratio", "n_points")
"""The columns of the report's table of all metrics after accuracy."""


def latency_key(res: dict, row: dict) -> str:
    """Which latency a row reports: the network alone for SA-Net without clip (its raw depths are the
    completion), else forward + turning the output into clouds (``complete_ms``)."""
    return "forward_ms" if row.get("clip") is None and res["model"] == "sanet" else "complete_ms"


def _fmt(x: float, digits: int = 5) -> str:
    """``x`` with ``digits`` decimals; "n/a" for None or NaN."""
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def model_label(res: dict, row: dict) -> str:
    """A report row's model name: the display name of ``res["model"]``, its ``res["tag"]`` in brackets
    when :func:`tag_repeated_models` gave one, and the row's ``row["variant"]`` in parentheses when set."""
    name = DISPLAY_NAMES.get(res["model"], res["model"])
    if res.get("tag"):  # two checkpoints of one model in a report: say which is which
        name += f" [{res['tag']}]"
    return name + (f" ({row['variant']})" if row["variant"] else "")


def tag_repeated_models(results: list[dict]) -> None:
    """Give each result whose model appears more than once a ``tag``: its run folder's name
    (``runs/NAME/best.pt``) or the checkpoint file's stem."""
    models = [r["model"] for r in results]
    for r in results:
        if models.count(r["model"]) > 1:
            p = Path(r["checkpoint"])
            r["tag"] = p.parent.name if p.stem in ("best", "last") and p.parent.name else p.stem


def _lat(res: dict, row: dict, batch: int) -> str:
    """The row's median latency at ``batch`` in ms ("n/a" when not timed)."""
    lat = res.get("latency_ms") or {}
    v = lat.get(batch, lat.get(str(batch)))
    return f"{v[latency_key(res, row)]:.2f}" if v else "n/a"


def _table_head(head: list) -> list:
    """The header and separator lines of a Markdown table."""
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]


def _every_metric_cells(res: dict, row: dict) -> list:
    """One row of the first table: every metric, parameters, training and latency of one variant."""
    tr = res.get("training") or {}
    m = row["summary"]["mean_over_samples"]
    n = m.get("n_points")
    return [
        model_label(res, row),
        _fmt(m.get("accuracy")),
        _fmt(m.get("completeness")),
        _fmt(m.get("chamfer_l1")),
        _fmt(m.get("fscore"), 4),
        "n/a" if n is None else f"{n:.0f}",
        f"{res['params']['total'] / 1e6:.2f}M",
        "n/a" if tr.get("steps") is None else f"{tr['steps']:,}",
        "n/a" if tr.get("samples_seen") is None else f"{tr['samples_seen']:,}",
        "n/a" if tr.get("minutes") is None else f"{tr['minutes']:.0f}",
        tr.get("precision", "n/a"),
        _lat(res, row, 1),
        _lat(res, row, 32),
    ]


def _table1_section(report: dict) -> list:
    """The report's title and first table (Table 1 under one protocol) with its latency note."""
    lines = [
        f"# Completion on `{report['data']}` ({report['split']} split: "
        f"{report['n_samples']} samples of {report['n_models']} models)",
        "",
        "Means over samples, unit frame, lower is better except F-score; points = points per completion. "
        "Training: optimizer steps, samples seen and minutes (training + validation) up to the checkpoint, "
        "and its precision.",
        "",
    ]
    head = [
        "Method",
        "Accuracy",
        "Completeness",
        "CD-L1",
        "F@0.01",
        "Points",
        "#Params",
        "Steps",
        "Samples seen",
        "Minutes",
        "Precision",
        "Latency b1 (ms)",
        "Latency b32 (ms)",
    ]
    lines += _table_head(head)
    for res in report["results"]:
        for row in res["rows"]:
            lines.append("| " + " | ".join(_every_metric_cells(res, row)) + " |")
    timed = [r for r in report["results"] if "latency_ms" in r]
    if timed:
        lines += [
            "",
            "Latency: median forward time (SA-Net without clip) or forward + decoding (+ clip or p(hit) "
            f"threshold; baselines: forward + split into clouds), on {timed[0]['latency_device']} "
            f"with {timed[0]['threads']} threads.",
        ]
    else:
        lines += ["", "Latency not measured (opt-in: `spotlights evaluate --latency`)."]
    return lines


def _per_category_section(report: dict, metric: str) -> list:
    """The accuracy (``metric``) per category, the paper's layout."""
    cats = [c for c in report["categories"]]
    lines = [
        "",
        "## Accuracy per category",
        "",
        f"{metric}: {METRIC_DESCRIPTIONS[metric]}. Average (samples) = mean over all samples (the paper's "
        "Average); Average (categories) = unweighted mean of the per-category means.",
        "",
    ]
    head = [
        "Method",
        *[c.capitalize() if c != "suv" else "SUV" for c in cats],
        "Average (samples)",
        "Average (categories)",
        "#Params",
        "Latency b1 (ms)",
        "Latency b32 (ms)",
    ]
    lines += _table_head(head)
    for res in report["results"]:
        for row in res["rows"]:
            s = row["summary"]
            cells = [
                model_label(res, row),
                *[_fmt(s["per_category"].get(c, {}).get(metric)) for c in cats],
                _fmt(s["mean_over_samples"][metric]),
                _fmt(s["mean_over_categories"][metric]),
                f"{res['params']['total'] / 1e6:.2f}M",
                _lat(res, row, 1),
                _lat(res, row, 32),
            ]
            lines.append("| " + " | ".join(cells) + " |")
    return lines + [""]


def _metric_cell(k: str, v) -> str:
    """One cell of the all-metrics table: points with one decimal, F-score and hit ratio with 4, the rest 5."""
    if v is None:
        return "n/a"
    return f"{v:.1f}" if k == "n_points" else _fmt(v, 4 if k in ("fscore", "hit_ratio") else 5)


def _all_metrics_section(report: dict) -> list:
    """Every metric's mean over samples, one row per variant."""
    others = list(OTHER_METRICS)
    lines = ["## All metrics (mean over samples; per category in the JSON report)", ""]
    lines += _table_head(["Method", "accuracy", *others])
    for res in report["results"]:
        for row in res["rows"]:
            m = row["summary"]["mean_over_samples"]
            cells = [model_label(res, row), _fmt(m.get("accuracy"))]
            cells += [_metric_cell(k, m.get(k)) for k in others]
            lines.append("| " + " | ".join(cells) + " |")
    return lines


def report_markdown(report: dict, metric: str = TABLE_METRIC) -> str:
    """The Markdown report: Table 1 (every metric, parameters, training, latency), the accuracy per
    category (the paper's layout), all metrics, parameters and definitions."""
    lines = _table1_section(report)
    lines += _per_category_section(report, metric)
    lines += _all_metrics_section(report)
    lines += ["", "Parameters (encoder / decoder / total):", ""]
    for res in report["results"]:
        p = res["params"]
        lines.append(
            f"- {DISPLAY_NAMES.get(res['model'], res['model'])}: {p['encoder']:,} / {p['decoder']:,} / {p['total']:,} "
            f"({res['checkpoint']}, {res['trained_epochs']} epochs)"
        )
    lines += ["", "Metric definitions:", ""] + [f"- `{k}`: {v}" for k, v in METRIC_DESCRIPTIONS.items()]
    return "\n".join(lines) + "\n"


def _jsonable(x):
    """``x`` with numpy scalars as Python numbers, NaN as None and dict keys as strings (for JSON)."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return None if math.isnan(float(x)) else float(x)
    if isinstance(x, np.integer):
        return int(x)
    return x


def write_report(report: dict, out) -> tuple[Path, Path]:
    """Write ``OUT.md`` and ``OUT.json`` (atomically; NaN written as null). ``out`` may end in .md/.json or not."""
    out = Path(out)
    stem = out.with_suffix("") if out.suffix.lower() in (".md", ".json") else out
    md, js = Path(f"{stem}.md"), Path(f"{stem}.json")
    with atomic_output(md) as tmp:
        tmp.write_text(report_markdown(report))
    with atomic_output(js) as tmp:
        tmp.write_text(json.dumps(_jsonable(report), indent=2))
    return md, js
