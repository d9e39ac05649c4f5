"""The report of ``spotlights reproduce``: ``OUT/results.json`` and ``OUT/REPORT.md``, and :func:`publish`.

The prose is the Markdown template ``report.md`` beside this module; every fact in it (mesh
and track counts, parameter counts, the machine, the sensor) is computed here from the
settings, the step records and the steps' outputs, so the text says what this run did.
"""

from __future__ import annotations

import csv
import os
import platform
import re
import shlex
import shutil
import string
from collections import Counter
from collections.abc import Sequence
from functools import lru_cache
from importlib import resources
from pathlib import Path

from ..._version import __version__
from ...data.synthetic import BuildConfig
from ...errors import SpotlightsError
from ...learning.bench import cpu_name
from ...learning.models import load_config
from ...outputs import atomic_output
from .. import paper_tables as paper
from ..rig_study import N_SURFACE
from .figures import EXTRA_FIGURES, FIGURES
from .pipeline import Context, now, read_json, shell_quote, write_json
from .settings import DISPLAY, HIT_RATIO_RAYS, PRODUCT_RUNS, TABLE1_RUNS, Settings
from .tables import TABLES

RESULTS_FORMAT = "spotlights-reproduce-results"
PUBLISHED = ("REPORT.md", "results.json", "steps.json", "tables", "figures")
"""What :func:`publish` copies: the report, its numbers and its pictures (no data, checkpoints or caches)."""


@lru_cache(maxsize=1)
def template_blocks() -> dict[str, str]:
    """{block name: text} of the report template ``report.md`` (blocks start with ``<!-- block: NAME -->``)."""
    text = resources.files(__package__).joinpath("report.md").read_text(encoding="utf-8")
    parts = re.split(r"^<!-- block: (\w+) -->\n", text, flags=re.M)
    return {name: body.strip("\n") for name, body in zip(parts[1::2], parts[2::2])}


def _fill(block: str, **values) -> str:
    return string.Template(template_blocks()[block]).substitute(values)


def versions() -> dict:
    """The machine and the versions of Python, spotlights and its main dependencies."""
    from importlib import metadata

    out = {
        "python": platform.python_version(),
        "spotlights": __version__,
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "cpu": cpu_name(),
    }
    for pkg in ("numpy", "scipy", "torch", "trimesh", "embreex", "h5py", "pykdtree", "pandas", "matplotlib", "pyarrow"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


# --- facts of this run, for the prose -------------------------------------------------------------
def _car_meshes(s: Settings) -> str:
    """'the 79 ApolloScape car CAD models (hatchback 15, ...)' from the car manifest."""
    try:
        with open(Path(s.cars_meshes) / "manifest.csv", newline="") as fh:
            cats = Counter(r["category"] for r in csv.DictReader(fh))
    except (OSError, KeyError, csv.Error):
        return "ApolloScape car CAD models"
    parts = ", ".join(f"{'SUV' if c == 'suv' else c} {n}" for c, n in sorted(cats.items()))
    return (
        f"the {sum(cats.values())} ApolloScape car CAD models ({parts}; not watertight, some inner parts no "
        "ray reaches)"
    )


def _category_meshes(ctx: Context) -> str:
    """'130 meshes of 9 everyday categories (...)' from the rig study's record (what it used)."""
    info = (ctx.records.get("rig-study") or {}).get("info") or {}
    cars_set = Path(ctx.s.cars_meshes).name
    counts = {k.split("/", 1)[1]: n for k, n in (info.get("meshes") or {}).items() if not k.startswith(cars_set + "/")}
    what = "everyday categories (PartNet, PartNet-Mobility, ModelNet10, Kenney and others)"
    if not counts:
        return f"meshes of {what}"
    used = " in this --quick run" if ctx.s.quick else ""
    return f"{sum(counts.values())} meshes of {len(counts)} {what}{used}"


def _eval_results(ctx: Context) -> dict:
    """{run: first result of its evaluate report} for the Table 1 and product runs that have one."""
    out = {}
    for r in TABLE1_RUNS + PRODUCT_RUNS:
        p = ctx.eval_json(r)
        if p.is_file():
            out[r] = read_json(p)["results"][0]
    return out


def _param_counts(ctx: Context, results: dict) -> str:
    ours = [f"{DISPLAY[r]} {res['params']['total'] / 1e6:.1f}M" for r, res in results.items()]
    theirs = ", ".join(
        f"{DISPLAY[r]} {paper.TABLE1['sanet (clip 0.2)' if r == 'sanet' else r]['params_m']:.1f}M" for r in TABLE1_RUNS
    )
    decoder = ""
    try:
        m = load_config("sanet")["model"]
        decoder = f"; SA-Net's decoder {'-'.join(str(w) for w in [m['code_size'], *m['hidden']])}-N*M"
    except Exception:  # noqa: BLE001 - a fact of the prose, never a reason to fail the report
        pass
    return (f"ours: {', '.join(ours)}{decoder}; " if ours else "") + f"the paper: {theirs}"


def _step_costs(ctx: Context) -> str:
    """'the baselines cost 4-12x more per training step than SA-Net here' from the runs' records."""
    per_step = {}
    for r in TABLE1_RUNS:
        info = (ctx.records.get(f"train-{r}") or {}).get("info") or {}
        if info.get("steps") and info.get("train_seconds"):
            per_step[r] = float(info["train_seconds"]) / int(info["steps"])
    if "sanet" not in per_step or len(per_step) < 2:
        return "the baselines are the most under-trained (they cost more per step on a CPU)."
    ratios = [v / per_step["sanet"] for r, v in per_step.items() if r != "sanet"]
    return (
        f"the baselines are the most under-trained (they cost {min(ratios):.0f}-{max(ratios):.0f}x more per step "
        "than SA-Net in these runs)."
    )


def _machine(results: dict, vers: dict) -> str:
    res = next((r for r in results.values() if r.get("latency_device")), None)
    device = res["latency_device"] if res else "cpu"
    threads = f", {res['threads']} torch threads" if res and res.get("threads") else ""
    what = "CPU" if str(device).startswith("cpu") else str(device)
    return f"{what} time on this machine ({vers.get('cpu') or '?'}, {vers.get('cpus') or '?'} cores{threads})"


def _real_tracks(ctx: Context, key: str, where: str) -> str:
    """'21 tracked vehicles seen in both sweeps: car 20, truck 1' from the consistency report of real set ``key``."""
    p = ctx.out / "eval" / f"{key}_consistency.json"
    if not p.is_file():
        return f"the vehicles seen in {where}"
    d = read_json(p)["data"]
    per = ", ".join(f"{c} {n}" for c, n in (d.get("objects_per_class") or {}).items())
    return f"{d['n_objects_tracked']} tracked vehicles seen in {where}: {per}"


def _av2_tracks(ctx: Context) -> str:
    return _real_tracks(ctx, "av2", "both sweeps")


def _nuscenes_tracks(ctx: Context) -> str:
    return _real_tracks(ctx, "nuscenes", "two or more keyframes")


def facts(ctx: Context, vers: dict) -> dict:
    """The computed facts the template's prose names."""
    cfg = BuildConfig()
    results = _eval_results(ctx)
    cars_info = (ctx.records.get("cars-data") or {}).get("info") or {}
    return {
        "car_meshes": _car_meshes(ctx.s),
        "category_meshes": _category_meshes(ctx),
        "range_noise": f"{cfg.sensor['range_noise']:g}",
        "distance": f"{cfg.distance[0]:g}-{cfg.distance[1]:g}",
        "schedule": ctx.s.schedule,
        "step_costs": _step_costs(ctx),
        "param_counts": _param_counts(ctx, results),
        "machine": _machine(results, vers),
        "av2_tracks": _av2_tracks(ctx),
        "nuscenes_tracks": _nuscenes_tracks(ctx),
        "n_surface": f"{N_SURFACE:,}",
        "hit_ratio_rays": HIT_RATIO_RAYS,
        "seed": ctx.s.seed,
        "quick_cars": cars_info.get("n_models", "?"),
        "quick_per_category": ctx.s.cars_per_category,
        "views": ctx.s.views,
        "eval_views": ctx.s.eval_views,
        "meshes_per_category": ctx.s.meshes_per_category,
    }


# --- the report --------------------------------------------------------------------------------------
def _results(ctx: Context, keys: Sequence[str], tables: dict, vers: dict) -> dict:
    """The content of ``OUT/results.json``: the tables, the paper's values, the step records, versions, seeds."""
    return {
        "format": RESULTS_FORMAT,
        "mode": ctx.s.mode,
        "tables": tables,
        "paper": {
            str(k): {("x".join(map(str, kk)) if isinstance(kk, tuple) else str(kk)): v for kk, v in t.items()}
            for k, t in paper.PAPER_TABLES.items()
            if str(k) in keys
        },
        "steps": ctx.records,
        "versions": vers,
        "seeds": {
            "dataset": ctx.s.seed,
            "training": "train.seed of each run's config (0)",
            "rig_study": ctx.s.seed,
            "real_extraction": ctx.s.seed,
        },
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in ctx.s.__dict__.items()},
    }


def _command_line(ctx: Context) -> str:
    """The command of the last invocation (as recorded), or the plain command for this output folder."""
    inv = ctx.invocations[-1] if ctx.invocations else {}
    argv = inv.get("argv")
    if argv:
        return "spotlights " + " ".join(shlex.quote(a) for a in argv)
    return "spotlights reproduce --out " + shell_quote(ctx.out)


def _claim_lines(tables: dict) -> list:
    """One Markdown table line per check of every table: table, claim, holds, detail."""
    return [
        f"| {k} | {c['claim']} | {'yes' if c['holds'] else '**no**'} | {c['detail']} |"
        for k, t in tables.items()
        for c in t.get("checks", [])
    ]


def _figure_lines(ctx: Context, key: str) -> list:
    """The figures (image and caption) of table ``key`` that this output folder has."""
    lines = []
    for fig in TABLES[key].steps(ctx.s):
        if fig in FIGURES and (ctx.figures / FIGURES[fig][0]).is_file():
            for name, cap in [FIGURES[fig]] + EXTRA_FIGURES.get(fig, []):
                if (ctx.figures / name).is_file():
                    lines += [f"![{cap}](figures/{name})", "", f"*{cap}*", ""]
    return lines


def _step_lines(ctx: Context) -> list:
    """One Markdown table line per step record: name, seconds, ran or reused, command."""
    steps = []
    for name, r in ctx.records.items():
        if r.get("status") != "done":
            steps.append(f"| {name} | - | {r.get('status')} | `{r.get('command', '')}` |")
        else:
            steps.append(
                f"| {name} | {float(r.get('seconds') or 0):.1f} | {'reused' if r.get('reused') else 'ran'} | "
                f"`{r.get('command', '')}` |"
            )
    return steps


def write_report(ctx: Context, keys: Sequence[str], seconds: float) -> tuple[Path, Path]:
    """Write ``OUT/results.json`` and ``OUT/REPORT.md`` from the table JSONs and the step records."""
    tables = {k: read_json(ctx.table_json(k)) for k in keys}
    vers = versions()
    res_path = ctx.out / "results.json"
    write_json(res_path, _results(ctx, keys, tables, vers))

    total = sum(float(r.get("seconds") or 0) for r in ctx.records.values())
    f = facts(ctx, vers)
    sections = []
    for k, t in tables.items():
        sections += [f"## {t['title']}", "", t["markdown"], ""]
        sections += _figure_lines(ctx, k)
    text = _fill(
        "report",
        mode=ctx.s.mode,
        quick_note=_fill("quick_note", **f) + "\n\n" if ctx.s.quick else "",
        generated=now(),
        command=_command_line(ctx),
        version=vers["spotlights"],
        tables=", ".join(keys),
        total_minutes=f"{total / 60:.1f}",
        seconds=f"{seconds:.1f}",
        box_goals=_fill("box_goals") if "box" in tables else "",
        claims="\n".join(_claim_lines(tables)),
        table_sections="\n".join(sections),
        steps="\n".join(_step_lines(ctx)),
        versions="\n".join(f"- {k}: {v}" for k, v in vers.items()),
        **f,
    )
    md_path = ctx.out / "REPORT.md"
    with atomic_output(md_path, suffix=".md") as tmp:
        Path(tmp).write_text(text + "\n")
    return md_path, res_path


def publish(out, dest) -> Path:
    """Copy a finished reproduction's report, numbers and figures from ``out`` into ``dest``
    (e.g. ``docs/results/reproduction``), replacing what ``dest`` held of them.

    The report's figure links are relative (``figures/...``), so they work in ``dest``.
    Raises :class:`SpotlightsError` when ``out`` holds no report.
    """
    out, dest = Path(out), Path(dest)
    if not (out / "REPORT.md").is_file():
        raise SpotlightsError(f"{out}: no REPORT.md to publish (run the reproduction first)")
    dest.mkdir(parents=True, exist_ok=True)
    for name in PUBLISHED:
        src, dst = out / name, dest / name
        if src.is_dir():
            tmp = dest / f".{name}.tmp"
            shutil.rmtree(tmp, ignore_errors=True)
            shutil.copytree(src, tmp, ignore=shutil.ignore_patterns("*.csv") if name == "figures" else None)
            shutil.rmtree(dst, ignore_errors=True)
            tmp.rename(dst)
        elif src.is_file():
            with atomic_output(dst, suffix=src.suffix) as t:
                shutil.copyfile(src, t)
    return dest / "REPORT.md"
