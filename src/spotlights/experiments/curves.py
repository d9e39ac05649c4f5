"""Learning curves of training runs: read every run's ``log.csv``, judge whether each curve has
flattened, draw all runs in one figure per metric (``spotlights curves``).

A run folder is what ``spotlights train`` writes: ``log.csv`` holds one row per validation
(``epoch, ..., val_accuracy, val_completeness, val_chamfer_l1, ..., global_step, samples_seen,
wall_seconds``). Two time axes are offered: ``samples_seen`` (training samples drawn so far)
and minutes. Minutes are either the run's own wall clock (``wall_seconds``: training plus
validation, which a busy machine inflates) or, with a budget, *budget minutes*: the fraction of
the run's steps done times its budget (the fair protocol gives every model the same budget as
a number of steps measured on a quiet machine, so this is the time the run would have taken
there).

Flatness: over the last ``tail`` share of a curve (by steps), the relative improvement of the
metric, ``(best before the tail - best in the tail) / best before the tail``, and the slope of
a least-squares line through the tail expressed as the relative change per tail length. A
curve is *still improving* when its tail improved it by ``tolerance`` (default 2%) or more or
still falls that fast; otherwise it has *flattened* ("flat"), and it is *worsening* when the
tail is worse than the best before it by more than ``tolerance`` (validation rising while
training goes on: overfitting).
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError, ParameterError
from ..outputs import atomic_output
from ..viz.curves import render_learning_curves

METRICS = (
    ("val_chamfer_l1", "validation CD-L1 (unit frame)"),
    ("val_accuracy", "validation accuracy"),
    ("val_completeness", "validation completeness"),
)
"""Columns of ``log.csv`` drawn and judged, with their panel titles (lower is better for all)."""


@dataclass(frozen=True)
class Flatness:
    """How a curve ends: its last value, the relative improvement over its last ``tail`` share
    (best in the tail against the best before it, positive = still improving), the slope of its
    tail as a relative change per tail length (negative = still falling), and the verdict."""

    metric: str
    last: float
    best: float
    tail_improvement: float
    tail_slope: float
    flattened: bool
    verdict: str  # "still improving", "flat" or "worsening"


def read_log(run_dir: str | os.PathLike) -> dict[str, np.ndarray]:
    """The columns of ``RUN/log.csv`` as float arrays (one entry per validation).

    Raises :class:`InputFileError` when the file is missing, empty or lacks the metric columns.
    """
    p = Path(run_dir)
    f = p / "log.csv" if p.is_dir() else p
    if not f.is_file():
        raise InputFileError(f, "no such training log (a run folder of 'spotlights train' holds log.csv)")
    try:
        with open(f, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputFileError(f, f"not a readable CSV ({exc})") from None
    if not rows:
        raise InputFileError(f, "holds no validation rows yet")
    missing = [c for c, _ in METRICS if c not in rows[0]] + [c for c in ("epoch",) if c not in rows[0]]
    if missing:
        raise InputFileError(f, f"is not a spotlights training log (no column {', '.join(missing)})")

    def num(v):
        try:
            return float(v)
        except (TypeError, ValueError):
            return float("nan")

    return {k: np.array([num(r.get(k)) for r in rows], dtype=np.float64) for k in rows[0]}


def flatness(
    steps: Sequence[float], values: Sequence[float], metric: str = "", tail: float = 0.2, tolerance: float = 0.02
) -> Flatness:
    """Judge whether a curve (lower is better) has flattened over its last ``tail`` share of steps.

    Parameters
    ----------
    steps : (K,) increasing step counts (or samples seen) of the validations.
    values : (K,) metric values; NaN entries are ignored.
    tail : the share of the run (by steps) that is judged, 0 < tail < 1.
    tolerance : the relative change below which the curve counts as flat.
    """
    if not 0.0 < tail < 1.0:
        raise ParameterError(f"tail must be in (0, 1), got {tail}")
    s = np.asarray(steps, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(s) & np.isfinite(v)
    s, v = s[ok], v[ok]
    if len(v) < 3:
        nan = float("nan")
        return Flatness(
            metric,
            float(v[-1]) if len(v) else nan,
            float(v.min()) if len(v) else nan,
            nan,
            nan,
            False,
            "too short to judge",
        )
    cut = s[0] + (1.0 - tail) * (s[-1] - s[0])
    head, tl = v[s < cut], v[s >= cut]
    if len(head) == 0 or len(tl) < 2:
        head, tl = v[:-2], v[-2:]
    before = float(head.min())
    improvement = (before - float(tl.min())) / before if before > 0 else 0.0
    ts = s[s >= cut] if len(v[s >= cut]) >= 2 else s[-2:]
    slope = float(np.polyfit(ts, tl, 1)[0]) if np.ptp(ts) > 0 else 0.0
    rel_slope = slope * (s[-1] - s[0]) * tail / float(np.mean(tl)) if np.mean(tl) > 0 else 0.0
    flat = improvement < tolerance and rel_slope > -tolerance
    verdict = "still improving" if not flat else ("worsening" if improvement < -tolerance else "flat")
    return Flatness(metric, float(v[-1]), float(v.min()), float(improvement), float(rel_slope), bool(flat), verdict)


def learning_curves(
    runs: Sequence[str | os.PathLike],
    names: Sequence[str] | None = None,
    out: str | os.PathLike = ".",
    budget_minutes: float | None = None,
    tail: float = 0.2,
    tolerance: float = 0.02,
) -> dict:
    """Read runs, judge each curve, draw one figure per x axis, write CSVs and a JSON summary.

    Parameters
    ----------
    runs : run folders (or their log.csv files).
    names : display names (default: the folder names).
    out : output folder: ``curves_samples.png``, ``curves_minutes.png``, ``curves.json`` and one
        ``NAME.csv`` copy of each log.
    budget_minutes : with a budget (the fair protocol's 45), the minutes axis is budget minutes
        (``budget * global_step / final steps of the run's schedule``), else the wall clock.

    Returns the summary dict written to ``curves.json``.
    """
    names = (
        list(names) if names is not None else [Path(r).name if Path(r).is_dir() else Path(r).parent.name for r in runs]
    )
    if len(names) != len(runs):
        raise ParameterError(f"{len(names)} names for {len(runs)} runs")
    if len(set(names)) != len(names):
        raise ParameterError(f"run names must differ: {', '.join(names)} (give `names`)", "names")
    logs = {n: read_log(r) for n, r in zip(names, runs)}
    total_steps = {n: _total_steps(r, logs[n]) for n, r in zip(names, runs)}
    summary: dict = {"tail": tail, "tolerance": tolerance, "budget_minutes": budget_minutes, "runs": {}}
    for n, cols in logs.items():
        steps = cols.get("global_step")
        if steps is None or not np.isfinite(steps).all():
            steps = cols["epoch"]
        if budget_minutes is not None:
            cols["minutes"] = budget_minutes * steps / max(total_steps[n], 1.0)
        else:
            wall = cols.get("wall_seconds")
            cols["minutes"] = (wall if wall is not None else np.cumsum(cols.get("epoch_seconds", cols["epoch"]))) / 60.0
        if "samples_seen" not in cols:
            cols["samples_seen"] = np.full_like(cols["epoch"], np.nan)
        judged = {m: asdict(flatness(steps, cols[m], m, tail, tolerance)) for m, _ in METRICS}
        summary["runs"][n] = {
            "validations": int(len(cols["epoch"])),
            "steps": float(steps[-1]),
            "planned_steps": float(total_steps[n]),
            "samples_seen": float(cols["samples_seen"][-1]),
            "wall_minutes": float(cols["wall_seconds"][-1] / 60.0) if "wall_seconds" in cols else None,
            "flatness": judged,
        }
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    minutes_label = "budget minutes (quiet 2-core machine)" if budget_minutes is not None else "wall-clock minutes"
    render_learning_curves(
        out / "curves_samples.png",
        logs,
        METRICS,
        "samples_seen",
        "training samples seen",
        "Validation metrics against samples seen",
    )
    render_learning_curves(
        out / "curves_minutes.png",
        logs,
        METRICS,
        "minutes",
        minutes_label,
        f"Validation metrics against {minutes_label}",
    )
    for n, r in zip(names, runs):
        src = Path(r) / "log.csv" if Path(r).is_dir() else Path(r)
        with atomic_output(out / f"{n}.csv") as tmp:
            tmp.write_bytes(src.read_bytes())
    with atomic_output(out / "curves.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=1) + "\n")
    return summary


def _total_steps(run, cols) -> float:
    """The steps the run's schedule plans (from its config.yaml), else the steps done so far."""
    import yaml

    p = Path(run)
    cfg_path = (p if p.is_dir() else p.parent) / "config.yaml"
    done = float(np.nanmax(cols.get("global_step", cols["epoch"])))
    try:
        cfg = yaml.safe_load(cfg_path.read_text())
        t = cfg["train"]
        if t.get("steps_per_epoch"):
            return float(int(t["steps_per_epoch"]) * int(t["epochs"]))
        per_epoch = done / float(cols["epoch"][-1])
        return per_epoch * int(t["epochs"])
    except (OSError, KeyError, TypeError, ValueError, ZeroDivisionError, yaml.YAMLError):
        return done


def summary_markdown(summary: dict) -> str:
    """A Markdown table: per run, steps, samples, and per metric the last value and the verdict."""
    head = "| run | steps | samples seen | " + " | ".join(f"{m} (last; tail change)" for m, _ in METRICS) + " |"
    lines = [head, "|" + "---|" * (3 + len(METRICS))]
    for n, r in summary["runs"].items():
        cells = []
        for m, _ in METRICS:
            f = r["flatness"][m]
            cells.append(f"{f['last']:.5f}; {100 * f['tail_improvement']:+.1f}% ({f['verdict']})")
        lines.append(
            f"| {n} | {r['steps']:,.0f} of {r['planned_steps']:,.0f} | {r['samples_seen']:,.0f} | "
            + " | ".join(cells)
            + " |"
        )
    return "\n".join(lines) + "\n"
