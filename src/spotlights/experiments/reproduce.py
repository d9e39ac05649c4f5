"""``spotlights reproduce``: every table of the paper, recomputed, beside the paper's values.

:func:`reproduce` runs the *steps* each selected *table* needs (build or reuse the car
dataset, train or reuse the checkpoints, evaluate them, extract the real scans, run the
rig study, draw the figures) and writes, under ``OUT``::

    OUT/REPORT.md                 every table, ours beside the paper's, differences explained,
                                  figures, commands, versions, seeds, wall time of every step
    OUT/results.json              every number of the report (ours and the paper's)
    OUT/tables/table<K>.json|csv  one table each (CSV: table, row, column, ours, paper)
    OUT/figures/*.png             the figures
    OUT/steps.json                one record per step: status, seconds, command, inputs
    OUT/data/cars.h5              the car dataset (or --cars-data FILE), kitti.h5, av2.h5
    OUT/runs/<run>/               checkpoints: sanet pcn foldingnet topnet atlasnet (Table 1),
                                  sanet-64x32 sanet-256x64 (Table 5; its 32x64 row is run sanet),
                                  sanet-box (the box table: SA-Net on box-32x64-ellipsoid-s1)
    OUT/eval/<run>.md|json        'spotlights evaluate' report of each checkpoint
    OUT/rig_study/                the per-mesh rig study behind Tables 3, 4 and box (cached per mesh)

Resuming: every output is written atomically and each finished step is recorded in
``steps.json`` with the signature of its inputs (file sizes and times, parameters); a
rerun reuses every step whose record, inputs and outputs still hold, so an interrupted run
continues at its first unfinished step. Datasets and checkpoints that exist are reused
even without a record (a run whose ``last.pt`` finished its epochs as is, an unfinished
one is resumed).

Tables are a registry (:data:`TABLES`): a table is one function that turns its steps'
outputs into rows, plus the list of steps it needs. Adding a table is adding one
:class:`Table` entry (and its steps, if they are new).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import platform
import shlex
import sys
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import ParameterError, SpotlightsError
from ..utils import atomic_output, exclusive_lock
from . import paper_tables as paper

STEPS_FORMAT = "spotlights-reproduce-steps"

# Table 1 runs in the paper's row order, and every run: name -> (model, rig or None = default rig).
TABLE1_RUNS = ("atlasnet", "pcn", "foldingnet", "topnet", "sanet")
TABLE5_RUNS = {"32x64": "sanet", "64x32": "sanet-64x32", "256x64": "sanet-256x64"}
RUNS = {
    "sanet": ("sanet", None), "pcn": ("pcn", None), "foldingnet": ("foldingnet", None),
    "topnet": ("topnet", None), "atlasnet": ("atlasnet", None),
    "sanet-64x32": ("sanet", "cap-64x32-60"), "sanet-256x64": ("sanet", "cap-256x64-60"),
    "sanet-box": ("sanet", "box-32x64-ellipsoid-s1"),
}
BOX_RIG = "box-32x64-ellipsoid-s1"
"""The box-targeted rig of the box table (issue 8): ``--rig-kind box`` at 2048 rays, the default box rig."""
BOX_RUNS = {"paper": "sanet", "box": "sanet-box"}  # the box table's SA-Net pair: paper rig (Table 1 run) vs box rig
DISPLAY = {"sanet": "SA-Net", "sanet-box": "SA-Net (box rig)", "pcn": "PCN", "foldingnet": "FoldingNet", "topnet": "TopNet", "atlasnet": "AtlasNet"}
ANGLE_LABELS = {"cap 30": 30, "cap 60": 60, "cap 83 (r = R/4)": 83}
BOX_STUDY_LABELS = ("box ellipsoid s1", "box volume s0.9")
"""Box rigs of ``rig_study.BOX_RIGS`` studied beside the cap rigs (the default box rig and the issue's Halton s0.9)."""
ABLATION_RAYS = (2048, 4096, 8192)
HIT_RATIO_RAYS = 2048


@dataclass(frozen=True)
class Settings:
    """What a reproduction computes (all paths as the user gave them).

    quick : small data and the tiny ``quick`` schedule (a smoke run of every stage).
    schedule : training schedule of new runs (packaged name or YAML).
    cars_meshes, category_meshes, lidar : the shared data folders.
    cars_data : an existing car dataset to use instead of building ``OUT/data/cars.h5``.
    eval_views : test views per test car scored in Tables 1 and 5 (None: all).
    workers : processes for the dataset build and the rig study (results do not depend on it).
    """

    out: Path
    quick: bool = False
    schedule: str = "budget"
    cars_meshes: Path = Path("../shared/data/meshes/apolloscape-cars")
    category_meshes: Path = Path("../shared/data/meshes/categories")
    lidar: Path = Path("../shared/data/lidar")
    cars_data: Path | None = None
    eval_views: int | None = 200
    workers: int = 1
    seed: int = 0
    progress: bool = True

    # --- sizes of the two modes -----------------------------------------------------------
    @property
    def views(self) -> int:
        """Partial observations per car of a dataset we build (the paper: 2000)."""
        return 16 if self.quick else 2000

    @property
    def cars_per_category(self) -> int | None:
        """--quick: cars of each body type in the small dataset (one train, val, test each)."""
        return 3 if self.quick else None

    @property
    def meshes_per_category(self) -> int | None:
        """--quick: meshes per category in the rig study (None: all)."""
        return 2 if self.quick else None

    @property
    def cars_path(self) -> Path:
        return Path(self.cars_data) if self.cars_data is not None else self.out / "data" / "cars.h5"

    @property
    def mode(self) -> str:
        return "quick" if self.quick else "full"


# ----------------------------------------------------------------------------------------------
# steps
# ----------------------------------------------------------------------------------------------
@dataclass
class Step:
    """One unit of work: ``run(ctx) -> info dict``; reused when its record, inputs and outputs hold.

    ``inputs``: files whose size and time enter the step's signature (a retrained checkpoint
    makes its evaluation stale). ``params``: anything else the result depends on.
    ``reuse``: optional check for artifacts made outside a recorded run (existing datasets
    and checkpoints); returns a message when the step can be skipped.
    """

    name: str
    run: Callable
    command: Callable
    outputs: Callable
    needs: tuple = ()
    inputs: Callable = lambda ctx: []
    params: Callable = lambda ctx: {}
    reuse: Callable | None = None


@dataclass(frozen=True)
class Table:
    """A table of the report: the steps it needs and the function that builds it.

    ``build(ctx) -> dict`` with ``markdown`` (the section of REPORT.md), ``rows`` (dicts
    ``row, column, ours, paper`` for the CSV), ``checks`` (the paper's expectations, each
    ``{"claim", "holds", "detail"}``) and anything else worth keeping in the JSON.
    """

    key: str
    title: str
    steps: Callable
    build: Callable


class Context:
    """A reproduction in progress: settings, step records and logging."""

    def __init__(self, settings: Settings, log=None):
        self.s = settings
        self.out = Path(settings.out)
        self.log = log or _tqdm_print
        self.records: dict = {}
        self.invocations: list = []

    # paths
    def run_dir(self, run: str) -> Path:
        return self.out / "runs" / run

    def eval_json(self, run: str) -> Path:
        return self.out / "eval" / f"{run}.json"

    def table_json(self, key: str) -> Path:
        return self.out / "tables" / f"table{key}.json"

    @property
    def figures(self) -> Path:
        return self.out / "figures"

    def rel(self, p) -> str:
        """``p`` relative to OUT when inside it (for REPORT.md links), else as given."""
        try:
            return Path(p).resolve().relative_to(self.out.resolve()).as_posix()
        except ValueError:
            return str(p)


def _tqdm_print(msg: str) -> None:
    from tqdm import tqdm

    tqdm.write(msg, file=sys.stdout)
    sys.stdout.flush()


def _signature(paths) -> dict:
    sig = {}
    for p in paths:
        p = Path(p)
        if p.is_file():
            st = p.stat()
            sig[str(p)] = [st.st_size, st.st_mtime_ns]
        else:
            sig[str(p)] = None
    return sig


def _write_json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path, suffix=".json") as tmp:
        Path(tmp).write_text(json.dumps(_clean(obj), indent=1) + "\n")


def _clean(x):
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, Path):
        return str(x)
    return x


def _q(p) -> str:
    return shlex.quote(str(p))


# --- car dataset ------------------------------------------------------------------------------
def _quick_manifest(ctx: Context) -> Path:
    """--quick: the first cars of each body type (sorted by file), one per split, as a manifest CSV."""
    src = Path(ctx.s.cars_meshes) / "manifest.csv"
    if not src.is_file():
        raise SpotlightsError(f"{src}: the car manifest is missing (is ../shared/data there?)")
    with open(src, newline="") as fh:
        rows = list(csv.DictReader(fh))
    by_cat: dict = {}
    for r in sorted(rows, key=lambda r: r["file"]):
        by_cat.setdefault(r["category"], []).append(r["file"])
    out = ctx.out / "data" / "quick-cars.csv"
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["file", "category", "split"])
    splits = ("train", "val", "test")
    for cat in sorted(by_cat):
        for j, f in enumerate(by_cat[cat][: ctx.s.cars_per_category]):
            w.writerow([f, cat, splits[j % 3]])
    out.parent.mkdir(parents=True, exist_ok=True)
    if not out.exists() or out.read_text() != buf.getvalue():
        with atomic_output(out, suffix=".csv") as tmp:
            Path(tmp).write_text(buf.getvalue())
    return out


def _cars_config(ctx: Context):
    from ..data.synthetic import BuildConfig

    kw = dict(meshes=str(ctx.s.cars_meshes), views=ctx.s.views, seed=ctx.s.seed,
              extra_rigs=["64x32@60", "256x64@60", BOX_RIG])
    if ctx.s.quick:
        kw.update(manifest=str(ctx.out / "data" / "quick-cars.csv"), split="3/3/3")
    else:
        kw.update(split="64/8/7")
    return BuildConfig(**kw)


def _cars_command(ctx: Context) -> str:
    if ctx.s.cars_data is not None:
        return f"(given with --cars-data {_q(ctx.s.cars_data)})"
    cmd = (f"spotlights dataset build --meshes {_q(ctx.s.cars_meshes)} --out {_q(ctx.s.cars_path)} "
           f"--views {ctx.s.views} --split {'3/3/3' if ctx.s.quick else '64/8/7'} --rig 64x32@60 --rig 256x64@60 --rig {BOX_RIG} "
           f"--seed {ctx.s.seed}")
    if ctx.s.quick:
        cmd += f" --manifest {_q(ctx.out / 'data' / 'quick-cars.csv')}"
    return cmd


REQUIRED_RIGS = ("cap-32x64-60", "cap-64x32-60", "cap-256x64-60")


def _check_cars(path: Path) -> dict:
    from ..data.store import open_dataset

    with open_dataset(path) as ds:
        info = ds.info()
    missing = [r for r in REQUIRED_RIGS if r not in info["rigs"]]
    if missing:
        raise SpotlightsError(f"{path}: the car dataset lacks the rig(s) {', '.join(missing)} that Tables 1 and 5 need "
                              "(build it with --rig 64x32@60 --rig 256x64@60)")
    return {"n_models": info["n_models"], "n_samples": info["n_samples"], "views_per_model": info["views_per_model"],
            "splits": {k: v["models"] for k, v in info["splits"].items()}, "categories": info["categories"],
            "seed": info["seed"], "rigs": list(info["rigs"])}


def _has_rig(path: Path, name: str) -> bool:
    from ..data.store import open_dataset

    with open_dataset(path) as ds:
        return name in ds.rig_names


def _reuse_cars_box(ctx: Context):
    if _has_rig(ctx.s.cars_path, BOX_RIG):
        return f"the car dataset {ctx.s.cars_path} holds rig {BOX_RIG}", {"rig": BOX_RIG, "added": False}
    return None


def _cars_box_command(ctx: Context) -> str:
    return f"spotlights dataset add-rig {_q(ctx.s.cars_path)} --rig {BOX_RIG} -j {ctx.s.workers} (only if the file lacks it)"


def _run_cars_box(ctx: Context) -> dict:
    """Add the box rig's ground truth to a car dataset that lacks it (``spotlights dataset add-rig``; atomic)."""
    from ..data.synthetic import add_rig

    rep = add_rig(ctx.s.cars_path, BOX_RIG, workers=ctx.s.workers, progress=ctx.s.progress, log=ctx.log)
    return {"rig": BOX_RIG, "added": not rep.already_present, "hit_ratio": rep.hit_ratio}


def _reuse_cars(ctx: Context):
    p = ctx.s.cars_path
    if p.is_file():
        return f"reusing the car dataset {p}", _check_cars(p)
    if ctx.s.cars_data is not None:
        raise SpotlightsError(f"{p}: --cars-data names no such file")
    return None


def _run_cars(ctx: Context) -> dict:
    from ..data.synthetic import build_dataset

    if ctx.s.quick:
        _quick_manifest(ctx)
    cfg = _cars_config(ctx)
    ctx.s.cars_path.parent.mkdir(parents=True, exist_ok=True)
    rep = build_dataset(cfg, ctx.s.cars_path, workers=ctx.s.workers, progress=ctx.s.progress, log=ctx.log)
    return _check_cars(ctx.s.cars_path) | {"build_seconds": rep.seconds_total}


# --- training ---------------------------------------------------------------------------------
def run_state(run_dir: Path) -> dict:
    """State of a training run folder without loading its weights.

    Returns ``{"state": "missing" | "unfinished" | "finished", "epochs": done, "epochs_total": planned}``;
    epochs done = rows of ``log.csv`` (written after ``last.pt`` each epoch), planned =
    ``train.epochs`` of ``config.yaml``.
    """
    import yaml

    last, cfg_path, log = run_dir / "last.pt", run_dir / "config.yaml", run_dir / "log.csv"
    if not last.is_file():
        return {"state": "missing", "epochs": 0, "epochs_total": None}
    total = None
    if cfg_path.is_file():
        try:
            total = int(yaml.safe_load(cfg_path.read_text())["train"]["epochs"])
        except (yaml.YAMLError, KeyError, TypeError, ValueError):
            total = None
    done = 0
    if log.is_file():
        with open(log, newline="") as fh:
            done = sum(1 for _ in csv.DictReader(fh))
    if total is None or not log.is_file():  # fall back on the checkpoint itself
        from ..learning.checkpoint import load_checkpoint

        ck = load_checkpoint(last)
        done, total = int(ck.get("epoch", 0)), int(ck["config"]["train"]["epochs"])
    return {"state": "finished" if done >= total else "unfinished", "epochs": done, "epochs_total": total}


def _run_info(run_dir: Path) -> dict:
    """Facts of a finished run for the report: model, rig, epochs, steps, schedule-relevant config, best epoch."""
    import torch

    ck = torch.load(run_dir / "last.pt", map_location="cpu", weights_only=True)
    cfg = ck["config"]
    hist = ck.get("history") or []
    return {
        "model": ck["model_name"], "rig": (ck.get("dataset") or {}).get("rig"), "epochs": int(ck["epoch"]),
        "steps": int(ck["global_step"]), "batch_size": int(cfg["train"]["batch_size"]),
        "max_views": cfg["data"].get("max_views"), "lr": cfg["train"].get("lr"), "seed": cfg["train"].get("seed"),
        "n_train": (ck.get("dataset") or {}).get("n_train"), "best": ck.get("best"),
        "train_seconds": float(sum(float(r.get("epoch_seconds") or 0) for r in hist)),
        "data": (ck.get("dataset") or {}).get("path"),
    }


def _train_command(ctx: Context, run: str, resume: bool = False) -> str:
    model, rig = RUNS[run]
    cmd = f"spotlights train --model {model} --data {_q(ctx.s.cars_path)} --out {_q(ctx.run_dir(run))}"
    if resume:
        return cmd + " --resume"
    cmd += f" --schedule {_q(ctx.s.schedule)}"
    return cmd + (f" --rig {rig}" if rig else "")


def _reuse_train(ctx: Context, run: str):
    st = run_state(ctx.run_dir(run))
    if st["state"] == "finished":
        info = _run_info(ctx.run_dir(run))
        msg = f"reusing run {run}: {st['epochs']}/{st['epochs_total']} epochs done"
        if info.get("data") and Path(info["data"]).resolve() != Path(ctx.s.cars_path).resolve():
            msg += f" (warning: trained on {info['data']}, not on {ctx.s.cars_path})"
        return msg, info
    return None


def _run_train(ctx: Context, run: str) -> dict:
    from ..learning.train import train

    model, rig = RUNS[run]
    d = ctx.run_dir(run)
    st = run_state(d)
    if st["state"] == "unfinished":
        ctx.log(f"resuming run {run} after epoch {st['epochs']}/{st['epochs_total']}")
        train(model, ctx.s.cars_path, d, resume=True, progress=ctx.s.progress, log=ctx.log)
        ctx.records.setdefault(f"train-{run}", {})["command"] = _train_command(ctx, run, resume=True)
    else:
        train(model, ctx.s.cars_path, d, schedule=ctx.s.schedule, overrides={"data": {"rig": rig}} if rig else None,
              overwrite=(d / "last.pt").exists(), progress=ctx.s.progress, log=ctx.log)
    return _run_info(d)


# --- evaluation -------------------------------------------------------------------------------
def _eval_command(ctx: Context, run: str) -> str:
    views = f" --max-views {ctx.s.eval_views}" if ctx.s.eval_views else ""
    lat = " --no-latency" if run not in TABLE1_RUNS or ctx.s.quick else ""
    return (f"spotlights evaluate --data {_q(ctx.s.cars_path)} --checkpoint {_q(ctx.run_dir(run) / 'best.pt')} "
            f"--split test{views}{lat} --out {_q(ctx.out / 'eval' / run)}")


def _run_eval(ctx: Context, run: str) -> dict:
    from ..learning.evaluate import evaluate_checkpoints, write_report

    timed = run in TABLE1_RUNS
    rep = evaluate_checkpoints([ctx.run_dir(run) / "best.pt"], ctx.s.cars_path, split="test", max_views=ctx.s.eval_views,
                               latency=timed and not ctx.s.quick, latency_repeats=10, progress=ctx.s.progress)
    if timed and ctx.s.quick:  # a short timing at batch 1 (the full run times batch 1 and 32, 10 repeats)
        import torch

        from ..learning.checkpoint import load_checkpoint, model_from_checkpoint
        from ..learning.bench import model_latency

        dev = torch.device("cpu")
        model = model_from_checkpoint(load_checkpoint(ctx.run_dir(run) / "best.pt"), dev)
        res = rep["results"][0]
        res["latency_ms"] = model_latency(model, dev, batches=(1,), repeats=3, warmup=1)
        res["latency_device"], res["threads"] = str(dev), torch.get_num_threads()
    write_report(rep, ctx.out / "eval" / run)
    return {"n_samples": rep["n_samples"], "n_models": rep["n_models"]}


# --- real data ----------------------------------------------------------------------------------
REAL_SOURCES = {  # name -> (folder under --lidar, format)
    "kitti": ("kitti-object/training-fov-cropped", "kitti"),
    "av2": ("argoverse2", "av2"),
}


def _real_command(ctx: Context, name: str) -> str:
    folder, fmt = REAL_SOURCES[name]
    return f"spotlights real extract {_q(Path(ctx.s.lidar) / folder)} --format {fmt} --out {_q(ctx.out / 'data' / f'{name}.h5')}"


def _run_real(ctx: Context, name: str) -> dict:
    from ..data.real import open_reader
    from ..data.real.extract import ExtractConfig, extract, write_observations

    folder, fmt = REAL_SOURCES[name]
    src = Path(ctx.s.lidar) / folder
    if not src.exists():
        raise SpotlightsError(f"{src}: real LiDAR data not found (pass --lidar DIR, the folder of the shared lidar data)")
    obs = extract(open_reader(src, fmt), ExtractConfig(seed=ctx.s.seed), progress=ctx.s.progress)
    write_observations(ctx.out / "data" / f"{name}.h5", obs)
    return {"observations": len(obs), "frames": int(obs.meta["n_frames"])}


def _skip_reasons() -> list[str]:
    """The extraction's skip reasons: a new one (e.g. duplicate_box) changes what is extracted, so it re-runs the step."""
    from ..data.real.extract import SKIP_REASONS

    return list(SKIP_REASONS)


def _consistency_command(ctx: Context) -> str:
    ck = " ".join(_q(ctx.run_dir(r) / "best.pt") for r in TABLE1_RUNS)
    return (f"spotlights real evaluate {_q(ctx.out / 'data' / 'av2.h5')} --checkpoint {ck} --out {_q(ctx.out / 'eval' / 'av2_consistency')} "
            f"--reference {_q(ctx.s.cars_path)}")


def _run_consistency(ctx: Context) -> dict:
    from .real_evaluation import evaluate_consistency, reference_shapes, write_report
    from ..learning.inference import load_completer

    completers = [load_completer(ctx.run_dir(r) / "best.pt", device="cpu") for r in TABLE1_RUNS]
    refs, ref_info = reference_shapes(ctx.s.cars_path)
    rep = evaluate_consistency(ctx.out / "data" / "av2.h5", completers, names=list(TABLE1_RUNS),
                               checkpoints=[str(ctx.run_dir(r) / "best.pt") for r in TABLE1_RUNS], progress=ctx.s.progress,
                               references=refs, reference_info=ref_info)
    write_report(rep, ctx.out / "eval" / "av2_consistency")
    return {"objects": rep["data"]["n_objects_tracked"], "pairs": rep["data"]["n_pairs"]}


def _consistency_box_command(ctx: Context) -> str:
    ck = " ".join(_q(ctx.run_dir(r) / "best.pt") for r in BOX_RUNS.values())
    return (f"spotlights real evaluate {_q(ctx.out / 'data' / 'av2.h5')} --checkpoint {ck} "
            f"--out {_q(ctx.out / 'eval' / 'av2_consistency_box')}")


def _run_consistency_box(ctx: Context) -> dict:
    """Consistency on the AV2 tracks of SA-Net on the paper's rig and on the box rig (each observation's own box)."""
    from .real_evaluation import evaluate_consistency, write_report

    runs = list(BOX_RUNS.values())
    rep = evaluate_consistency(ctx.out / "data" / "av2.h5", _completers(ctx, runs), names=runs,
                               checkpoints=[str(ctx.run_dir(r) / "best.pt") for r in runs], progress=ctx.s.progress)
    write_report(rep, ctx.out / "eval" / "av2_consistency_box")
    return {"objects": rep["data"]["n_objects_tracked"], "pairs": rep["data"]["n_pairs"]}


# --- rig study (Tables 3 and 4) ------------------------------------------------------------------
def study_meshes(s: Settings) -> list:
    """The rig study's meshes: category folders with >= 5 meshes, then the cars (--quick: a few of each)."""
    from .rig_study import find_meshes

    out = []
    for folder in (s.category_meshes, s.cars_meshes):
        entries = find_meshes([folder])
        k = s.meshes_per_category
        if k is not None:
            taken: dict = {}
            kept = []
            for e in entries:
                if taken.get(e.category, 0) < k:
                    kept.append(e)
                    taken[e.category] = taken.get(e.category, 0) + 1
            entries = kept
        out += entries
    return out


def study_variants() -> tuple:
    """The rig study's variants: the paper's cap rigs (Tables 3, 4) and the box rigs of the box table, in one pass."""
    from .rig_study import BOX_RIGS, PAPER_RIGS

    return tuple(PAPER_RIGS) + tuple(v for v in BOX_RIGS if v[0] in BOX_STUDY_LABELS)


def _study_command(ctx: Context) -> str:
    return ("python -c 'from spotlights.experiments import rig_study as r; "
            f"r.run_study(r.find_meshes([\"{ctx.s.category_meshes}\", \"{ctx.s.cars_meshes}\"]), "
            f"r.study_rigs({list(ABLATION_RAYS)}, variants=r.PAPER_RIGS + [v for v in r.BOX_RIGS if v[0] in "
            f"{list(BOX_STUDY_LABELS)}]), seed={ctx.s.seed})'"
            + (" (--quick: the first 2 meshes of each category)" if ctx.s.quick else "")
            + "; the same rigs are part of 'spotlights study rigs'")


def _run_study(ctx: Context) -> dict:
    from .rig_study import run_study, study_rigs, summarize

    meshes = study_meshes(ctx.s)
    rigs = study_rigs(ABLATION_RAYS, variants=study_variants())
    d = ctx.out / "rig_study"
    df = run_study(meshes, rigs, seed=ctx.s.seed, workers=ctx.s.workers, cache_dir=d / ".cache", progress=ctx.s.progress)
    summary = summarize(df)
    d.mkdir(parents=True, exist_ok=True)
    with atomic_output(d / "per_mesh.csv", suffix=".csv") as tmp:
        df.to_csv(tmp, index=False, float_format="%.6f")
    with atomic_output(d / "summary.csv", suffix=".csv") as tmp:
        summary.to_csv(tmp, index=False, float_format="%.6f")
    counts = df.drop_duplicates(["mesh_set", "mesh"]).groupby(["mesh_set", "category"]).size()
    return {"meshes": {f"{a}/{b}": int(n) for (a, b), n in counts.items()}}


# --- figures -------------------------------------------------------------------------------------
def _cloud_grid(path: Path, rows: Sequence[Sequence[tuple]], title: str, row_labels: Sequence[str] | None = None,
                elev: float = 22.0, azim: float = -60.0) -> Path:
    """A grid of 3-D scatter panels, axes fixed to the unit sphere (see :func:`spotlights.viz.render_cloud_grid`)."""
    from ..viz import render_cloud_grid

    return render_cloud_grid(path, rows, title, row_labels, elev, azim)


def _figure_meshes(s: Settings) -> list:
    """A car and two category meshes for the pictures (first of their folders, sorted)."""
    from .rig_study import find_meshes

    cars = find_meshes([s.cars_meshes])
    cats = find_meshes([s.category_meshes])
    pick = [cars[0]]
    for c in ("chair", "lamp"):
        pick += [e for e in cats if e.category == c][:1]
    return pick


def _load_unit_mesh(entry):
    from ..geometry.encode import MeshProbe
    from ..geometry.io import load_mesh
    from .rig_study import _mesh_axes

    mesh = load_mesh(entry.path, **_mesh_axes(entry.path))
    return mesh, MeshProbe(mesh)


def _run_fig_rig(ctx: Context) -> dict:
    """The rig with one viewpoint's rays on a car: hits (green) end on the surface, misses (orange) cross the sphere."""
    from ..geometry.rig import make_rig
    from ..geometry.sampling import sample_surface
    from ..viz import render_rig_rays

    entry = _figure_meshes(ctx.s)[0]
    mesh, probe = _load_unit_mesh(entry)
    rig = make_rig(32, 64, angle=60.0)
    depth = probe.encode(rig).reshape(rig.n_primary, rig.n_secondary)
    share = (depth > 0).mean(axis=1)
    i = int(np.argmin(np.abs(share - 0.5)))  # a viewpoint with about half of its rays on the car
    surf = probe.normalization.to_unit(sample_surface(mesh, 4000, ctx.s.seed))
    render_rig_rays(ctx.figures / "rig.png", rig, depth, i, surf,
                    f"{rig.name}: the {rig.n_primary} viewpoints (black) and the {rig.n_secondary} rays of viewpoint {i} (red):\n"
                    f"{int((depth[i] > 0).sum())} hit the car (green), the others cross the sphere (orange)")
    return {"mesh": entry.mesh_id, "viewpoint": i}


def _run_fig_density(ctx: Context) -> dict:
    from ..analysis.report import DensityConfig, run_density_analysis

    summary, _ = run_density_analysis(ctx.figures / "density", DensityConfig(angles=(60.0, 90.0), mc=False),
                                      progress=False, log=lambda *a: None)
    return {"uniformity_max_over_min": {k: v["uniformity_max_over_min"] for k, v in summary["angles"].items()}}


def _run_fig_gt(ctx: Context) -> dict:
    """Uniform surface samples beside Spotlights points at 2048, 4096 and 8192 rays (cap 60)."""
    from ..geometry.encode import decode
    from ..geometry.rig import make_rig
    from ..geometry.sampling import sample_surface

    rows, labels = [], []
    for entry in _figure_meshes(ctx.s):
        mesh, probe = _load_unit_mesh(entry)
        uni = probe.normalization.to_unit(sample_surface(mesh, 2048, ctx.s.seed))
        row = [("uniform, 2048 points", [(uni, "#8c8c8c", 1.2)])]
        for rays in ABLATION_RAYS:
            rig = make_rig(rays // 64, 64, angle=60.0)
            pts, mask = decode(probe.encode(rig), rig)
            row.append((f"Spotlights {rays} rays ({int(mask.sum())} hits)", [(pts[mask], "#2a9d3f", 1.2)]))
        rows.append(row)
        labels.append(f"{entry.mesh_set}/{entry.mesh_id}")
    _cloud_grid(ctx.figures / "gt_clouds.png", rows, "Ground truth: uniform sampling vs Spotlights (32..128 x 64 rays, 60 deg)",
                labels)
    return {"meshes": labels}


def _run_fig_box(ctx: Context) -> dict:
    """One car's Spotlights points at 2048 rays: the paper's 60-degree cap rig beside the box rigs of the box table."""
    from ..geometry.encode import decode
    from ..geometry.rig import make_rig_spec
    from ..geometry.sampling import sample_surface
    from .rig_study import BOX_RIGS

    entry = _figure_meshes(ctx.s)[0]
    mesh, probe = _load_unit_mesh(entry)
    uni = probe.normalization.to_unit(sample_surface(mesh, 2048, ctx.s.seed))
    row = [("uniform, 2048 points", [(uni, "#8c8c8c", 1.2)])]
    variants = [("paper, cap 60", dict(angle=60.0))] + [(lab, kw) for lab, kw in BOX_RIGS if lab in BOX_STUDY_LABELS]
    hits = {}
    for label, kw in variants:
        rig = probe.rig_for(make_rig_spec(32, 64, **kw))
        pts, mask = decode(probe.encode(rig), rig)
        hits[rig.name] = int(mask.sum())
        row.append((f"{label}: {rig.name}\n{int(mask.sum())} of {rig.n_rays} rays hit", [(pts[mask], "#2a9d3f", 1.2)]))
    _cloud_grid(ctx.figures / "box_rig_clouds.png", [row], "2048 rays (32 x 64): the paper's cap rig vs box-targeted rigs",
                [f"{entry.mesh_set}/{entry.mesh_id}"])
    return {"mesh": entry.mesh_id, "hits": hits}


def _completers(ctx: Context, runs) -> list:
    from ..learning.inference import load_completer

    return [load_completer(ctx.run_dir(r) / "best.pt", device="cpu") for r in runs]


def _run_fig_synthetic(ctx: Context) -> dict:
    """Test samples (one per car category): partial, each model's completion, ground truth."""
    from ..data.store import open_dataset

    runs = ["sanet", "pcn", "foldingnet", "topnet", "atlasnet"]
    comps = _completers(ctx, runs)
    rows, labels = [], []
    with open_dataset(ctx.s.cars_path) as ds:
        test = ds.split_indices("test")
        cats = ds.categories[ds.sample_model[test]]
        picks = []
        for c in sorted(set(cats.tolist())):
            picks.append(int(test[np.flatnonzero(cats == c)[0]]))
        for i in picks:
            smp = ds.sample(i)
            row = [(f"partial ({len(smp['partial'])} pts)", [(smp["partial"], "#7b2cbf", 2.0)])]
            for r, c in zip(runs, comps):
                out = c.complete(smp["partial"][None])[0]
                row.append((f"{DISPLAY[c.model_name]} ({len(out)} pts)", [(out, "#2a9d3f", 1.0)]))
            row.append(("ground truth (2048)", [(smp["gt_points"], "#8c8c8c", 1.0)]))
            rows.append(row)
            labels.append(f"{smp['model']} ({smp['category']}), view {smp['view']}")
    _cloud_grid(ctx.figures / "completions_synthetic.png", rows, "Completions of synthetic test scans (unit frame)", labels)
    return {"samples": labels}


def _run_fig_real(ctx: Context) -> dict:
    """KITTI and AV2: the frame with most vehicles, SA-Net completions drawn back in the scan."""
    from .real_evaluation import complete_all
    from ..data.real.extract import read_observations
    from ..data.real.frames import frame_rows
    from ..viz import render_frame

    sanet = _completers(ctx, ["sanet"])[0]
    done = {}
    for name in ("kitti", "av2"):
        obs = read_observations(ctx.out / "data" / f"{name}.h5")
        rows = sorted(frame_rows(obs), key=lambda i: -int(obs.n_points_raw[i]))[:6]
        comps = complete_all(sanet, obs.partial[rows], progress=False)
        i0 = rows[0]
        render_frame(ctx.figures / f"completions_{name}.png", obs, rows, comps,
                     title=f"{name}: frame {obs.frame_id[i0]}, SA-Net completions (green), partial inputs (purple)")
        done[name] = {"frame": obs.frame_id[i0], "objects": len(rows)}
    return done


# --- table steps -------------------------------------------------------------------------------
def _run_table(ctx: Context, key: str) -> dict:
    t = TABLES[key]
    res = t.build(ctx)
    res = {"key": key, "title": t.title, **res}
    _write_json(ctx.table_json(key), res)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=["table", "row", "column", "ours", "paper"], lineterminator="\n")
    w.writeheader()
    for r in res.get("rows", []):
        w.writerow({"table": key, **{k: _clean(r.get(k)) for k in ("row", "column", "ours", "paper")}})
    with atomic_output(ctx.out / "tables" / f"table{key}.csv", suffix=".csv") as tmp:
        Path(tmp).write_text(buf.getvalue())
    return {"checks": [c["holds"] for c in res.get("checks", [])]}


def all_steps(ctx: Context) -> dict:
    """Every step of a reproduction, by name (in execution order)."""
    s = ctx.s
    steps = [Step("cars-data", _run_cars, _cars_command, lambda c: [c.s.cars_path], reuse=_reuse_cars),
             # the box rig's ground truth: built into new datasets; added to an existing file that lacks it
             Step("cars-data-box", _run_cars_box, _cars_box_command, lambda c: [c.s.cars_path], needs=("cars-data",),
                  inputs=lambda c: [c.s.cars_path], reuse=_reuse_cars_box)]
    for run in RUNS:
        needs = ("cars-data",) + (("cars-data-box",) if RUNS[run][1] == BOX_RIG else ())
        steps.append(Step(f"train-{run}", (lambda c, r=run: _run_train(c, r)), (lambda c, r=run: _train_command(c, r)),
                          (lambda c, r=run: [c.run_dir(r) / "last.pt", c.run_dir(r) / "best.pt"]), needs=needs,
                          reuse=(lambda c, r=run: _reuse_train(c, r))))
    for run in RUNS:
        steps.append(Step(f"eval-{run}", (lambda c, r=run: _run_eval(c, r)), (lambda c, r=run: _eval_command(c, r)),
                          (lambda c, r=run: [c.eval_json(r)]), needs=("cars-data", f"train-{run}"),
                          inputs=(lambda c, r=run: [c.s.cars_path, c.run_dir(r) / "best.pt"]),
                          params=lambda c: {"eval_views": c.s.eval_views, "quick": c.s.quick}))
    for name in REAL_SOURCES:
        steps.append(Step(f"real-{name}", (lambda c, n=name: _run_real(c, n)), (lambda c, n=name: _real_command(c, n)),
                          (lambda c, n=name: [c.out / "data" / f"{n}.h5"]),
                          params=lambda c: {"lidar": str(c.s.lidar), "skip_reasons": _skip_reasons()}))
    steps.append(Step("consistency-av2", _run_consistency, _consistency_command,
                      lambda c: [c.out / "eval" / "av2_consistency.json"],
                      needs=("real-av2", "cars-data") + tuple(f"train-{r}" for r in TABLE1_RUNS),
                      inputs=lambda c: [c.out / "data" / "av2.h5", c.s.cars_path] + [c.run_dir(r) / "best.pt" for r in TABLE1_RUNS],
                      params=lambda c: {"scores": ["consistency", "fidelity", "mmd", "diversity"]}))
    box_runs = tuple(BOX_RUNS.values())
    steps.append(Step("consistency-av2-box", _run_consistency_box, _consistency_box_command,
                      lambda c: [c.out / "eval" / "av2_consistency_box.json"],
                      needs=("real-av2",) + tuple(f"train-{r}" for r in box_runs),
                      inputs=lambda c: [c.out / "data" / "av2.h5"] + [c.run_dir(r) / "best.pt" for r in box_runs]))
    steps.append(Step("rig-study", _run_study, _study_command,
                      lambda c: [c.out / "rig_study" / "summary.csv", c.out / "rig_study" / "per_mesh.csv"],
                      params=lambda c: {"quick": c.s.quick, "seed": c.s.seed, "meshes": [str(c.s.category_meshes), str(c.s.cars_meshes)],
                                        "rigs": [label for label, _ in study_variants()]}))
    fig_cmd = lambda c: "(drawn by spotlights reproduce; helpers in spotlights.experiments.reproduce)"  # noqa: E731
    steps += [
        Step("fig-rig", _run_fig_rig, fig_cmd, lambda c: [c.figures / "rig.png"]),
        Step("fig-density", _run_fig_density,
             lambda c: f"spotlights analyze density --angle 60 90 --no-mc --out {_q(c.figures / 'density')}",
             lambda c: [c.figures / "density" / "density_heatmap.png"]),
        Step("fig-gt", _run_fig_gt, fig_cmd, lambda c: [c.figures / "gt_clouds.png"]),
        Step("fig-box", _run_fig_box, fig_cmd, lambda c: [c.figures / "box_rig_clouds.png"]),
        Step("fig-synthetic", _run_fig_synthetic, fig_cmd, lambda c: [c.figures / "completions_synthetic.png"],
             needs=("cars-data",) + tuple(f"train-{r}" for r in TABLE1_RUNS),
             inputs=lambda c: [c.s.cars_path] + [c.run_dir(r) / "best.pt" for r in TABLE1_RUNS]),
        Step("fig-real", _run_fig_real, fig_cmd,
             lambda c: [c.figures / "completions_kitti.png", c.figures / "completions_av2.png"],
             needs=("real-kitti", "real-av2", "train-sanet"),
             inputs=lambda c: [c.out / "data" / "kitti.h5", c.out / "data" / "av2.h5", c.run_dir("sanet") / "best.pt"]),
    ]
    for key, t in TABLES.items():
        steps.append(Step(f"table-{key}", (lambda c, k=key: _run_table(c, k)),
                          lambda c: "(assembled by spotlights reproduce from the steps above)",
                          (lambda c, k=key: [c.table_json(k)]), needs=tuple(t.steps(s)),
                          inputs=(lambda c, k=key: _table_inputs(c, k)), params=lambda c: {"code": _code_version()}))
    return {st.name: st for st in steps}


def _code_version() -> str:
    """Hash of this module and the paper's values: a table is rebuilt (cheap) when the code that writes it changed."""
    import hashlib

    h = hashlib.sha256(Path(__file__).read_bytes())
    h.update(Path(paper.__file__).read_bytes())
    return h.hexdigest()[:16]


def _table_inputs(ctx: Context, key: str) -> list:
    files = []
    for name in TABLES[key].steps(ctx.s):
        st = ctx.steps[name]
        if not name.startswith(("train-", "cars-data", "fig-")):
            files += list(st.outputs(ctx))
    return files


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------
def _v(x) -> float:
    """A value for comparisons: None / NaN (e.g. every completion empty) -> +inf."""
    return float("inf") if x is None or not math.isfinite(float(x)) else float(x)


def _fmt(x, digits=5) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}f}"


def _diff(ours, ref) -> str:
    if ours is None or ref is None or not math.isfinite(ours) or not ref:
        return "-"
    return f"{100.0 * (ours / ref - 1.0):+.0f}%"


def _md_table(head: list, body: list) -> list:
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(map(str, r)) + " |" for r in body]


def _load(path: Path) -> dict:
    if not path.is_file():
        raise SpotlightsError(f"{path}: missing (its step did not finish; rerun to resume)")
    return json.loads(path.read_text())


def _eval_rows(ctx: Context, run: str) -> dict:
    """{row name: {category..., average, n, params_m, latency}} from one run's evaluate report."""
    rep = _load(ctx.eval_json(run))
    res = rep["results"][0]
    out = {}
    for row in res["rows"]:
        name = res["model"] + (f" ({row['variant']})" if row["variant"] else "")
        s = row["summary"]
        lat = res.get("latency_ms") or {}
        key = "complete_ms" if (row["clip"] is not None or res["model"] != "sanet") else "forward_ms"
        out[name] = {
            **{c: s["per_category"].get(c, {}).get("accuracy") for c in paper.CAR_CATEGORIES},
            "average": s["mean_over_samples"]["accuracy"],
            "average_categories": s["mean_over_categories"]["accuracy"],
            "completeness": s["mean_over_samples"].get("completeness"),
            "completeness_per_category": {c: s["per_category"].get(c, {}).get("completeness") for c in paper.CAR_CATEGORIES},
            "n_points": s["mean_over_samples"].get("n_points"),
            "chamfer_l1": s["mean_over_samples"].get("chamfer_l1"),
            "hit_ratio": s["mean_over_samples"].get("hit_ratio"),
            "params_m": res["params"]["total"] / 1e6,
            "runtime_ms": (lat.get("1") or {}).get(key),
            "runtime_b32_ms": (lat.get("32") or {}).get(key),
            "n_samples": rep["n_samples"], "n_models": rep["n_models"], "epochs": res["trained_epochs"],
            "latency_device": res.get("latency_device"), "threads": res.get("threads"),
        }
    return out


def _run_facts(ctx: Context, runs) -> dict:
    out = {}
    for r in runs:
        rec = ctx.records.get(f"train-{r}", {})
        info = rec.get("info") or {}
        if not info and (ctx.run_dir(r) / "last.pt").is_file():
            info = _run_info(ctx.run_dir(r))
        out[r] = info
    return out


def _training_note(ctx: Context, runs) -> str:
    facts = _run_facts(ctx, runs)
    def dur(sec):
        return f"{sec:.0f} s" if sec < 120 else f"{sec / 60:.0f} min"

    parts = [f"{r}: {f.get('steps', 0):,} steps of {f.get('batch_size', '?')} ({f.get('epochs', '?')} epochs, "
             f"{dur(float(f.get('train_seconds') or 0))} of training)" if f else f"{r}: ?" for r, f in facts.items()]
    return "; ".join(parts)


def build_table1(ctx: Context) -> dict:
    ours = {}
    for run in TABLE1_RUNS:
        ours.update(_eval_rows(ctx, run))
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
        body.append([f"**{label}**", "ours", *[_fmt(o[c]) for c in cols], f"{o['params_m']:.2f}M",
                     _fmt(o["runtime_ms"], 2)])
        body.append(["", "paper", *[_fmt(p[c]) for c in cols], f"{p['params_m']:.1f}M", _fmt(p["runtime_ms"], 2)])
        body.append(["", "ours vs paper", *[_diff(o[c], p[c]) for c in cols], "", ""])
        for c in cols + ["params_m", "runtime_ms"]:
            rows.append({"row": name, "column": c, "ours": o.get(c), "paper": p.get(c)})
    avg = {n: _v(ours[n]["average"]) for n in order if n in ours}
    best = min(avg, key=lambda n: avg[n]) if avg else None
    checks = [
        {"claim": "SA-Net with clip is the most accurate method (lowest Average)", "holds": best == clipped,
         "detail": f"lowest Average: {best} ({_fmt(avg.get(best))})" if best else "-"},
        {"claim": "the clip improves SA-Net's accuracy",
         "holds": bool(avg.get(clipped, math.inf) < avg.get("sanet (no clip)", math.inf)),
         "detail": f"no clip {_fmt(avg.get('sanet (no clip)'))}, {clipped[7:-1]} {_fmt(avg.get(clipped))}"},
        {"claim": "SA-Net has the fewest parameters and the shortest runtime",
         "holds": bool(ours and min(ours, key=lambda n: ours[n]["params_m"]).startswith("sanet")
                       and min(ours, key=lambda n: _v(ours[n]["runtime_ms"])).startswith("sanet")),
         "detail": ", ".join(f"{n}: {ours[n]['params_m']:.2f}M / {_fmt(ours[n]['runtime_ms'], 2)} ms" for n in order if n in ours)},
    ]
    any_row = next(iter(ours.values())) if ours else {}
    md = [f"Accuracy = one-sided CD prediction -> 16,384-point dense ground truth (unit frame, lower is better), on the "
          f"test split: {any_row.get('n_samples', '?')} scans of {any_row.get('n_models', '?')} cars. Average = mean over scans "
          "(the paper's Average). Runtime: median time of one scan (batch 1), forward pass (SA-Net no clip) or forward + "
          f"decoding (the others), on {any_row.get('latency_device') or '?'} with {any_row.get('threads') or '?'} threads "
          "(the paper: a GPU).", ""]
    md += _md_table(head, body)
    md += ["", f"Training (schedule `{ctx.s.schedule}` for new runs; each run's own config kept when reused): "
           + _training_note(ctx, TABLE1_RUNS) + "."]
    return {"ours": ours, "paper": paper.TABLE1, "rows": rows, "checks": checks, "markdown": "\n".join(md)}


def build_table2(ctx: Context) -> dict:
    rep = _load(ctx.out / "eval" / "av2_consistency.json")
    classes = list(paper.REAL_CLASSES)
    ours = {}
    for m in rep["models"]:
        ours[m["name"]] = {**{c: (m["classes"].get(c) or {}).get("cd") for c in classes},
                           "average": m["average"]["cd"], "all_objects": m["all_objects"]["cd"],
                           "points_per_completion": m["mean_points_per_completion"],
                           "fidelity": m["average"].get("fidelity"), "mmd": m["average"].get("mmd"),
                           "diversity": m.get("diversity"),
                           "objects": {c: (m["classes"].get(c) or {}).get("n_objects") for c in classes}}
    d = rep["data"]
    head = ["Model", "", "Car", "Truck", "Caravan", "Trailer", "Average", "All objects"]
    body, rows = [], []
    for name in TABLE1_RUNS:
        o, p = ours.get(name), paper.TABLE2[name]
        if o is None:
            continue
        body.append([f"**{DISPLAY[name]}**", "ours (AV2)", *[_fmt(o[c], 4) for c in classes + ["average"]], _fmt(o["all_objects"], 4)])
        body.append(["", "paper (KITTI-360)", *[_fmt(p[c], 4) for c in classes + ["average"]], ""])
        for c in classes + ["average"]:
            rows.append({"row": name, "column": c, "ours": o[c], "paper": p[c]})
    avg = {n: _v(ours[n]["average"]) for n in ours}
    best = min(avg, key=lambda n: avg[n]) if avg else None
    kitti_obs = None
    kp = ctx.out / "data" / "kitti.h5"
    if kp.is_file():
        from ..data.real.extract import read_observations

        kitti_obs = len(read_observations(kp))
    checks = [{"claim": "SA-Net's completions are the most consistent (lowest Average)", "holds": best == "sanet",
               "detail": f"lowest Average: {best} ({_fmt(avg.get(best), 4)})" if best else "-"}]
    md = [f"Consistency = CD between the completions of the same object in consecutive frames (Eq. 1, unsquared, both "
          f"directions summed), object frame / the box's half diagonal, mean per object then per class (lower is better). "
          f"Ours: Argoverse 2, {d['n_objects_tracked']} vehicles seen in both of the two consecutive sweeps "
          f"({', '.join(f'{c} {n}' for c, n in d['objects_per_class'].items())}); the paper: KITTI-360 "
          "(4,382 observations of many tracked vehicles). Classes with no object here are '-'; our Average is the mean over "
          "the classes present (the paper's: over its 4 classes). A model that predicts nearly the same shape whatever "
          "its input is trivially consistent, so read this table with Table 1: under-trained models score well here.", ""]
    md += _md_table(head, body)
    md += ["", "Beside consistency, two scores of PCN's real-data evaluation that a model ignoring its input cannot "
           "fake (Average over classes; lower is better): **fidelity**, the one-sided mean distance from each observed "
           "point to the nearest completion point (does the completion keep what the LiDAR saw?), and **MMD**, the "
           "Chamfer distance (Eq. 1) to the nearest complete car of the synthetic dataset (does it look like a car?); "
           "and **diversity**, the mean Chamfer distance between completions of *different* objects (near 0: the same "
           "shape whatever the input).", ""]
    md += _md_table(["Model", "Consistency", "Fidelity", "MMD", "Diversity", "points per completion"],
                    [[f"**{DISPLAY[n]}**", _fmt(ours[n]["average"], 4), _fmt(ours[n]["fidelity"], 4), _fmt(ours[n]["mmd"], 4),
                      _fmt(ours[n]["diversity"], 4), f"{ours[n]['points_per_completion']:.0f}"] for n in TABLE1_RUNS if n in ours])
    md += ["", f"KITTI: the shipped KITTI object frames ({kitti_obs if kitti_obs is not None else '?'} vehicles) carry no track ids, "
           "so no object is seen twice and consistency cannot be computed there; they appear in the qualitative figure."]
    return {"ours": ours, "paper": paper.TABLE2, "rows": rows, "checks": checks, "markdown": "\n".join(md),
            "data": {k: d.get(k) for k in ("n_objects_tracked", "n_pairs", "objects_per_class", "n_observations")}}


def _study_summary(ctx: Context):
    import pandas as pd

    s = pd.read_csv(ctx.out / "rig_study" / "summary.csv")
    s["angle"] = s["label"].map(ANGLE_LABELS)
    return s[s["angle"].notna()]


def _ablation_values(ctx: Context, metric: str, rays_list) -> tuple[dict, list, list, dict]:
    """{(rays, angle): {category: mean, "average": mean over the paper's 6, "average_all": over ours, "cars": ...}}."""
    from .rig_study import CARS

    s = _study_summary(ctx)
    cats_set = s[(s.mesh_set != CARS) & (s.category != "all")]
    cats = sorted(set(cats_set.category))
    extra = [c for c in cats if c not in paper.ABLATION_CATEGORIES]
    counts = {str(k): int(v) for k, v in cats_set.drop_duplicates(["category"]).set_index("category")["n_meshes"].items()}
    out = {}
    scale = 100.0 if metric == "hit_ratio" else 1.0
    for rays in rays_list:
        for angle in (30, 60, 83):
            sub = cats_set[(cats_set.rays == rays) & (cats_set.angle == angle)]
            vals = {c: float(sub[sub.category == c][metric].iloc[0]) * scale for c in cats if (sub.category == c).any()}
            six = [vals[c] for c in paper.ABLATION_CATEGORIES if c in vals]
            car = s[(s.mesh_set == CARS) & (s.category == "all") & (s.rays == rays) & (s.angle == angle)]
            out[(rays, angle)] = {**vals, "average": float(np.mean(six)) if six else None,
                                  "average_all": float(np.mean(list(vals.values()))) if vals else None,
                                  "cars": float(car[metric].iloc[0]) * scale if len(car) else None}
    return out, cats, extra, counts


def build_table3(ctx: Context) -> dict:
    vals, cats, extra, counts = _ablation_values(ctx, "completeness", ABLATION_RAYS)
    p6 = list(paper.ABLATION_CATEGORIES)
    head = ["#Rays", "Angle", "", *[c.capitalize() for c in p6], "Average (6)", *[c.capitalize() for c in extra],
            f"Average ({len(cats)})", "Cars"]
    body, rows = [], []
    for (rays, angle), o in vals.items():
        p = paper.TABLE3[(rays, angle)]
        body.append([f"**{rays}**", f"{angle}°", "ours", *[_fmt(o.get(c), 4) for c in p6], _fmt(o["average"], 4),
                     *[_fmt(o.get(c), 4) for c in extra], _fmt(o["average_all"], 4), _fmt(o["cars"], 4)])
        body.append(["", "", "paper", *[_fmt(p[c], 4) for c in p6], _fmt(p["average"], 4), *[""] * len(extra), "", ""])
        for c in p6 + ["average"]:
            rows.append({"row": f"{rays} rays {angle} deg", "column": c, "ours": o.get(c), "paper": p.get(c)})
        for c in extra + ["average_all", "cars"]:
            rows.append({"row": f"{rays} rays {angle} deg", "column": c, "ours": o.get(c), "paper": None})
    checks = []
    for key, lab in (("average", "the paper's 6 categories"), ("average_all", f"all {len(cats)} categories"), ("cars", "the cars")):
        if any(vals[k][key] is None for k in vals):
            continue
        for angle in (30, 60, 83):
            seq = [vals[(r, angle)][key] for r in ABLATION_RAYS]
            checks.append({"claim": f"completeness improves with the ray count ({angle}°, {lab})",
                           "holds": all(a > b for a, b in zip(seq, seq[1:])), "detail": " > ".join(_fmt(v, 4) for v in seq)})
        for rays in ABLATION_RAYS:
            c30, c60, c83 = (vals[(rays, a)][key] for a in (30, 60, 83))
            checks.append({"claim": f"at {rays} rays, 60° beats 30° and 83° ({lab})", "holds": bool(c60 < c30 and c60 < c83),
                           "detail": f"30°: {_fmt(c30, 4)}, 60°: {_fmt(c60, 4)}, 83°: {_fmt(c83, 4)}"})
    md = ["Completeness = mean distance from 16,384 uniform surface points to the Spotlights points (one-sided, "
          "unsquared, unit frame; lower is better), N x 64 rays (N = rays / 64), each object normalised by its own box. "
          f"Ours on `{ctx.s.category_meshes}`: the categories with at least 5 meshes ({', '.join(f'{c} {counts.get(c, 0)}' for c in cats)} "
          f"meshes{' used by --quick' if ctx.s.quick else ''}); the paper's 6 ShapeNet categories first, 'Average (6)' over them as "
          "in the paper, then our other categories, the average over all of ours, and the cars of the car dataset "
          "(mean over the cars). 83° = r = R/4 (82.8°).", ""]
    md += _md_table(head, body)
    return {"ours": {f"{r}x{a}": v for (r, a), v in vals.items()},
            "paper": {f"{r}x{a}": v for (r, a), v in paper.TABLE3.items()}, "categories": cats, "meshes": counts,
            "rows": rows, "checks": checks, "markdown": "\n".join(md)}


def build_table4(ctx: Context) -> dict:
    vals, cats, extra, counts = _ablation_values(ctx, "hit_ratio", ABLATION_RAYS)
    p6 = list(paper.ABLATION_CATEGORIES)
    head = ["Angle", "", *[c.capitalize() for c in p6], "Average (6)", *[c.capitalize() for c in extra],
            f"Average ({len(cats)})", "Cars"]
    body, rows = [], []
    for angle in (30, 60, 83):
        o, p = vals[(HIT_RATIO_RAYS, angle)], paper.TABLE4[angle]
        body.append([f"**{angle}°**", "ours", *[_fmt(o.get(c), 1) for c in p6], _fmt(o["average"], 1),
                     *[_fmt(o.get(c), 1) for c in extra], _fmt(o["average_all"], 1), _fmt(o["cars"], 1)])
        body.append(["", "paper", *[_fmt(p[c], 1) for c in p6], _fmt(p["average"], 1), *[""] * len(extra), "", ""])
        for c in p6 + ["average"]:
            rows.append({"row": f"{angle} deg", "column": c, "ours": o.get(c), "paper": p.get(c)})
        for c in extra + ["average_all", "cars"]:
            rows.append({"row": f"{angle} deg", "column": c, "ours": o.get(c), "paper": None})
    spread = max(abs(vals[(r, a)]["average_all"] - vals[(HIT_RATIO_RAYS, a)]["average_all"]) for r in ABLATION_RAYS for a in (30, 60, 83))
    checks = []
    for key in ["average", "average_all", "cars"] + cats:
        seq = [vals[(HIT_RATIO_RAYS, a)].get(key) for a in (30, 60, 83)]
        if None in seq:
            continue
        checks.append({"claim": f"the hit ratio falls as the angle grows ({key})", "holds": bool(seq[0] > seq[1] > seq[2]),
                       "detail": " > ".join(f"{v:.1f}%" for v in seq)})
    ours_avg = [vals[(HIT_RATIO_RAYS, a)]["average"] for a in (30, 60, 83)]
    md = [f"Hit ratio = rays that hit the object / all rays (%), at {HIT_RATIO_RAYS} rays (the paper does not give the ray "
          f"count; at 4096 and 8192 rays our averages differ by at most {spread:.1f} points). Same meshes and columns as "
          f"Table 3. Paper averages 78.6 / 50.9 / 34.8 %; ours (6 categories) {' / '.join(_fmt(v, 1) for v in ours_avg)} %.", ""]
    md += _md_table(head, body)
    lower = [a for a, o in zip((30, 60, 83), ours_avg) if o is not None and o < paper.TABLE4[a]["average"] - 2.0]
    if lower:
        md += ["", f"Our hit ratios are lower than the paper's at {', '.join(f'{a}°' for a in lower)}: each of our objects is "
               "normalised by its axis-aligned box (centre and half diagonal, the paper's step 1), so it fills less of the "
               "unit sphere the wider the cap looks around it; different meshes and the paper's unstated details of the "
               "normalisation can account for the gap. The ordering by angle is the paper's."]
    return {"ours": {str(a): vals[(HIT_RATIO_RAYS, a)] for a in (30, 60, 83)},
            "ours_by_rays": {f"{r}x{a}": v for (r, a), v in vals.items()},
            "paper": {str(a): v for a, v in paper.TABLE4.items()}, "rows": rows, "checks": checks, "markdown": "\n".join(md)}


def build_table5(ctx: Context) -> dict:
    cols = list(paper.CAR_CATEGORIES) + ["average"]
    ours = {}
    for res_name, run in TABLE5_RUNS.items():
        ev = _eval_rows(ctx, run)
        row = next((v for k, v in ev.items() if "clip" in k and "no clip" not in k), None)
        if row is None:
            raise SpotlightsError(f"{ctx.run_dir(run)}: run {run} has no clipped SA-Net row to put in Table 5 "
                                  "(its checkpoint sets no clip); retrain it with the default clip")
        ours[res_name] = row
    head = ["Resolution", "", "Hatchback", "Sedan", "SUV", "Average", "hit ratio (clip)"]
    body, rows = [], []
    for name, o in ours.items():
        p = paper.TABLE5[name]
        body.append([f"**{name.replace('x', '*')}**", "ours", *[_fmt(o[c]) for c in cols], _fmt(o.get("hit_ratio"), 3)])
        body.append(["", "paper", *[_fmt(p[c]) for c in cols], ""])
        body.append(["", "ours vs paper", *[_diff(o[c], p[c]) for c in cols], ""])
        for c in cols:
            rows.append({"row": name, "column": c, "ours": o[c], "paper": p[c]})
    a = {k: _v(v["average"]) for k, v in ours.items()}
    rel = abs(a["64x32"] / a["32x64"] - 1.0) if math.isfinite(a["64x32"] + a["32x64"]) else math.inf
    checks = [
        {"claim": "32*64 and 64*32 (same ray count) perform alike (within 5%)", "holds": bool(rel < 0.05),
         "detail": f"{_fmt(a['32x64'])} vs {_fmt(a['64x32'])} ({100 * rel:.1f}% apart; paper 2.2%)"},
        {"claim": "256*64 (8x the rays) is the most accurate", "holds": bool(a["256x64"] < min(a["32x64"], a["64x32"])),
         "detail": ", ".join(f"{k}: {_fmt(v)}" for k, v in a.items())},
    ]
    md = ["SA-Net (with clip 0.2) trained on the Spotlights ground truth of three rigs (N*M: N viewpoints, M rays each, "
          "60°; 2048, 2048 and 16,384 rays), accuracy as in Table 1 on the same test scans. The 32*64 row is the Table 1 "
          "run. hit ratio (clip) = share of the rig's rays kept after the clip.", ""]
    md += _md_table(head, body)
    md += ["", "Training: " + _training_note(ctx, TABLE5_RUNS.values()) + "."]
    return {"ours": ours, "paper": paper.TABLE5, "rows": rows, "checks": checks, "markdown": "\n".join(md)}


BOX_HIT_TARGET = 0.90
BOX_COMPLETENESS_GAIN = 0.15  # the target: completeness at least 15% better (lower) than cap 60


def _box_study_values(ctx: Context) -> dict:
    """{(set, label, rays): {"hit_ratio", "completeness", "rig", "n_meshes"}} for the box table's rigs;
    set = "cars" (mean over the cars) or "categories" (mean of the category means)."""
    import pandas as pd

    from .rig_study import CARS

    s = pd.read_csv(ctx.out / "rig_study" / "summary.csv")
    s = s[(s.category == "all") & s.label.isin(list(ANGLE_LABELS) + list(BOX_STUDY_LABELS))]
    out = {}
    for _, r in s.iterrows():
        key = ("cars" if r.mesh_set == CARS else "categories", r.label, int(r.rays))
        out[key] = {"hit_ratio": float(r.hit_ratio), "completeness": float(r.completeness), "rig": r.rig,
                    "n_meshes": int(r.n_meshes)}
    return out


def _box_study_section(vals: dict, mesh_set: str, ctx: Context) -> tuple[list, list]:
    labels = list(ANGLE_LABELS) + list(BOX_STUDY_LABELS)
    head = ["rig", "name (2048 rays)"] + [f"{r} rays: hit ratio / completeness (vs cap 60)" for r in ABLATION_RAYS]
    body, rows = [], []
    for label in labels:
        if (mesh_set, label, ABLATION_RAYS[0]) not in vals:
            continue
        cells = []
        for rays in ABLATION_RAYS:
            v, ref = vals.get((mesh_set, label, rays)), vals.get((mesh_set, "cap 60", rays))
            if v is None:
                cells.append("-")
                continue
            gain = _diff(v["completeness"], ref["completeness"]) if ref else "-"
            cells.append(f"{v['hit_ratio']:.3f} / {v['completeness']:.4f} ({gain})")
            for m in ("hit_ratio", "completeness"):
                rows.append({"row": f"rig study {mesh_set}: {label} @ {rays} rays", "column": m, "ours": v[m], "paper": None})
        name = vals[(mesh_set, label, ABLATION_RAYS[0])]["rig"]
        bold = label == BOX_STUDY_LABELS[0]
        body.append([f"**{label}**" if bold else label, f"`{name}`", *cells])
    return _md_table(head, body), rows


def build_table_box(ctx: Context) -> dict:
    """Beyond the paper (issue 8): box-targeted rigs against the paper's cap rigs, geometry and learning."""
    vals = _box_study_values(ctx)
    n = {k: v["n_meshes"] for (k, lab, r), v in vals.items() if lab == "cap 60" and r == ABLATION_RAYS[0]}
    md = ["Beyond the paper (issue 8, `docs/box-rig.md`): a box-targeted rig keeps the paper's N Fibonacci viewpoints "
          "and the fixed ray order but aims each viewpoint's M rays at the object's box. The paper's rig stays the "
          "default; this table sets the box rigs beside it.", "",
          "**Rig study** (no learning; the `rig-study` step of Tables 3-4, same meshes, surface samples and metric): hit "
          "ratio = rays with a hit / all rays; completeness = mean distance from 16,384 uniform surface points to the "
          "Spotlights points (one-sided, unsquared, unit frame, lower is better); 'vs cap 60' = relative completeness "
          "change against the paper's 60° rig at the same ray count (negative = better). N x 64 rays.", ""]
    rows = []
    for mesh_set, title in (("cars", f"{n.get('cars', '?')} cars (mean over the cars)"),
                            ("categories", f"{n.get('categories', '?')} category meshes (mean of the category means, "
                                           "the categories of Table 3)")):
        tab, r = _box_study_section(vals, mesh_set, ctx)
        md += [f"*{title}*", ""] + tab + [""]
        rows += r
    checks = []
    ref = vals.get(("cars", "cap 60", 2048))
    target_lines = []
    for label in BOX_STUDY_LABELS:
        v = vals.get(("cars", label, 2048))
        if v is None or ref is None:
            continue
        gain = 1.0 - v["completeness"] / ref["completeness"]
        ok = v["hit_ratio"] >= BOX_HIT_TARGET and gain >= BOX_COMPLETENESS_GAIN
        checks.append({"claim": f"issue 8 target, {label} (`{v['rig']}`) at 2048 rays on the cars: hit ratio >= "
                                f"{BOX_HIT_TARGET:.2f} and completeness >= {100 * BOX_COMPLETENESS_GAIN:.0f}% better than cap 60",
                       "holds": bool(ok), "detail": f"hit ratio {v['hit_ratio']:.3f}, completeness {v['completeness']:.4f} vs "
                                                    f"{ref['completeness']:.4f} ({100 * gain:.1f}% better)"})
        target_lines.append(f"{label} (`{v['rig']}`): hit ratio {v['hit_ratio']:.3f} (target >= {BOX_HIT_TARGET:.2f}), "
                            f"completeness {v['completeness']:.4f} against cap 60's {ref['completeness']:.4f}, "
                            f"{100 * gain:.1f}% better (target >= {100 * BOX_COMPLETENESS_GAIN:.0f}%): "
                            f"**{'met' if ok else 'not met'}**.")
    if target_lines:
        md += ["The issue's geometric target at 2048 rays on the cars:", ""] + [f"- {t}" for t in target_lines] + [""]

    # --- learning: SA-Net on the box rig's ground truth vs on the paper's rig --------------------------
    ev = {k: _eval_rows(ctx, run) for k, run in BOX_RUNS.items()}
    facts = _run_facts(ctx, BOX_RUNS.values())
    cats = list(paper.CAR_CATEGORIES)
    head = ["SA-Net trained on", "clip", *[f"acc. {c}" for c in cats], "acc. average", *[f"compl. {c}" for c in cats],
            "compl. average", "CD-L1", "hit ratio", "points"]
    body = []
    variants = [k for k in ev["paper"] if k in ev["box"]]
    for variant in variants:
        clip = variant.split("(", 1)[1].rstrip(")") if "(" in variant else "-"
        for k, run in BOX_RUNS.items():
            o = ev[k][variant]
            rig = (facts.get(run) or {}).get("rig") or RUNS[run][1] or "cap-32x64-60"
            body.append([f"{'paper rig' if k == 'paper' else '**box rig**'} `{rig}` ({run})", clip,
                         *[_fmt(o[c]) for c in cats], _fmt(o["average"]),
                         *[_fmt(o["completeness_per_category"].get(c)) for c in cats], _fmt(o["completeness"]),
                         _fmt(o["chamfer_l1"]), _fmt(o["hit_ratio"], 3), _fmt(o["n_points"], 0)])
            for c in cats + ["average", "completeness", "chamfer_l1", "hit_ratio", "n_points"]:
                rows.append({"row": f"{run} ({clip})", "column": c, "ours": o.get(c), "paper": None})
            for c in cats:
                rows.append({"row": f"{run} ({clip})", "column": f"completeness {c}",
                             "ours": o["completeness_per_category"].get(c), "paper": None})
    learn_lines = []
    for variant in variants:
        p, b = ev["paper"][variant], ev["box"][variant]
        acc_ok = _v(b["average"]) <= _v(p["average"])
        com_ok = _v(b["completeness"]) <= _v(p["completeness"])
        ok = acc_ok and com_ok
        checks.append({"claim": f"issue 8 target, SA-Net {variant.split(' ', 1)[1] if ' ' in variant else variant}: the box "
                                "rig's test accuracy and completeness are no worse than the paper rig's (same schedule, "
                                "2048 outputs)", "holds": bool(ok),
                       "detail": f"accuracy {_fmt(b['average'])} vs {_fmt(p['average'])} ({_diff(b['average'], p['average'])}), "
                                 f"completeness {_fmt(b['completeness'])} vs {_fmt(p['completeness'])} "
                                 f"({_diff(b['completeness'], p['completeness'])})"})
        learn_lines.append(
            f"{variant}: accuracy {_fmt(b['average'])} (box) vs {_fmt(p['average'])} (paper rig), "
            f"{_diff(b['average'], p['average'])}; completeness {_fmt(b['completeness'])} vs {_fmt(p['completeness'])}, "
            f"{_diff(b['completeness'], p['completeness'])}: the target is **"
            + ("met" + (" (both better)" if _v(b["average"]) < _v(p["average"]) and _v(b["completeness"]) < _v(p["completeness"]) else "")
               if ok else "not met" + ("" if acc_ok or com_ok else " (both worse)")
               + (" (accuracy worse)" if com_ok and not acc_ok else "") + (" (completeness worse)" if acc_ok and not com_ok else ""))
            + "**.")
    any_row = next(iter(ev["paper"].values()), {})
    md += ["**SA-Net on the box rig's ground truth** (run `sanet-box`: `--rig " + BOX_RIG + "`) against SA-Net on the "
           "paper's rig (the Table 1 run `sanet`), same schedule, same network (2048 outputs, one depth per ray), same "
           f"test scans as Table 1 ({any_row.get('n_samples', '?')} scans of {any_row.get('n_models', '?')} cars). The box "
           "run decodes each scan with the rays of its own box. Accuracy = one-sided CD prediction -> 16,384-point dense "
           "ground truth; completeness = the other direction (dense ground truth -> prediction); CD-L1 = their mean; hit "
           "ratio = rays kept (not a miss, within the clip) / 2048; points = points per completion; all mean over scans, "
           "unit frame, lower is better except hit ratio and points.", ""]
    md += _md_table(head, body)
    md += ["", "The issue's learning target (accuracy and completeness no worse, ideally better, at the same number of "
           "outputs):", ""] + [f"- {t}" for t in learn_lines]
    md += ["", "Training: " + _training_note(ctx, BOX_RUNS.values()) + "."]

    # --- consistency on the real AV2 tracks ---------------------------------------------------------------
    cons = _load(ctx.out / "eval" / "av2_consistency_box.json")
    d = cons["data"]
    classes = list(d["objects_per_class"])
    head = ["SA-Net trained on", *[c.capitalize() for c in classes], "Average", "All objects", "points per completion"]
    body = []
    cvals = {}
    for m in cons["models"]:
        k = "box" if m["name"] == BOX_RUNS["box"] else "paper"
        cvals[k] = m["average"]["cd"]
        body.append([f"{'paper rig' if k == 'paper' else '**box rig**'} ({m['name']})",
                     *[_fmt((m["classes"].get(c) or {}).get("cd"), 4) for c in classes], _fmt(m["average"]["cd"], 4),
                     _fmt(m["all_objects"]["cd"], 4), _fmt(m["mean_points_per_completion"], 0)])
        for c in classes + ["average"]:
            v = m["average"]["cd"] if c == "average" else (m["classes"].get(c) or {}).get("cd")
            rows.append({"row": f"consistency {m['name']}", "column": c, "ours": v, "paper": None})
    md += ["", f"**Consistency on the real Argoverse 2 tracks** (as Table 2: CD between completions of the same object in "
           f"consecutive frames, box half-diagonal units, mean per object then per class; lower is better; "
           f"{d['n_objects_tracked']} tracked vehicles). The box rig's rays follow each observation's detector box, so a "
           "box that changes between frames moves the rays with it; the paper's rig does not depend on the box.", ""]
    md += _md_table(head, body)
    if "box" in cvals and "paper" in cvals:
        md += ["", f"Average consistency: box rig {_fmt(cvals['box'], 4)} vs paper rig {_fmt(cvals['paper'], 4)} "
               f"({_diff(cvals['box'], cvals['paper'])}; not a target of the issue, reported)."]
    return {"study": {f"{a}|{b}|{c}": v for (a, b, c), v in vals.items()}, "sanet": ev, "consistency": cvals,
            "rows": rows, "checks": checks, "markdown": "\n".join(md)}


TABLES = {
    "1": Table("1", "Table 1: completion accuracy and efficiency on the synthetic cars",
               lambda s: [f"eval-{r}" for r in TABLE1_RUNS] + ["fig-synthetic"], build_table1),
    "2": Table("2", "Table 2: consistency on real scans",
               lambda s: ["consistency-av2", "real-kitti", "fig-real"], build_table2),
    "3": Table("3", "Table 3: completeness of the Spotlights point cloud",
               lambda s: ["rig-study", "fig-rig", "fig-density", "fig-gt"], build_table3),
    "4": Table("4", "Table 4: hit ratio of the rays", lambda s: ["rig-study"], build_table4),
    "5": Table("5", "Table 5: sampling resolution", lambda s: [f"eval-{r}" for r in TABLE5_RUNS.values()], build_table5),
    "box": Table("box", "Beyond the paper: box-targeted rigs (issue 8)",
                 lambda s: ["rig-study", "fig-box"] + [f"eval-{r}" for r in BOX_RUNS.values()] + ["consistency-av2-box"],
                 build_table_box),
}
"""Table key -> :class:`Table`; ``--tables`` selects from these keys."""

FIGURES = {  # figure step -> (file under figures/, caption)
    "fig-rig": ("rig.png", "The rig (32 x 64 rays, 60°): the viewpoints on the unit sphere and one viewpoint's bundle of rays on a car."),
    "fig-density": ("density/density_heatmap.png", "Ray density per unit N*M over the sphere (radius r, angle alpha to the radial) "
                    "for a 60° cap and the paper's hemisphere (90°) (spotlights.analysis)."),
    "fig-gt": ("gt_clouds.png", "Ground truth from uniform sampling (grey) and from Spotlights at 2048, 4096 and 8192 rays (green)."),
    "fig-synthetic": ("completions_synthetic.png", "Completions of synthetic test scans: partial input (purple), each model's "
                      "completion (green), the uniform ground truth (grey)."),
    "fig-box": ("box_rig_clouds.png", "One car's Spotlights points at 2048 rays (32 x 64): the paper's 60° cap rig and the "
                "box-targeted rigs of the box table (green), beside uniform surface samples (grey)."),
    "fig-real": ("completions_kitti.png", "KITTI: raw scan (grey), partial inputs (purple), SA-Net completions (green)."),
}
EXTRA_FIGURES = {"fig-real": [("completions_av2.png", "Argoverse 2: raw scan (grey), partial inputs (purple), SA-Net completions (green).")]}


def parse_tables(text: str | Sequence | None) -> list[str]:
    """``"1,2,5"`` -> ``["1", "2", "5"]`` (registry order); None or "all" -> every table.

    Raises :class:`ParameterError` for an unknown or empty selection.
    """
    if text is None:
        return list(TABLES)
    items = [str(x).strip() for x in (text.split(",") if isinstance(text, str) else text)]
    if [x.lower() for x in items] == ["all"]:
        return list(TABLES)
    bad = [x for x in items if x not in TABLES]
    if bad or not items or not all(items):
        what = f"unknown table {bad[0]!r}" if bad and bad[0] else "empty table list"
        raise ParameterError(f"--tables: {what}; choose from {', '.join(TABLES)} (comma-separated, e.g. --tables 1,3)")
    return [k for k in TABLES if k in items]


def plan(ctx: Context, tables: Sequence[str]) -> list[Step]:
    """The steps the tables need, their dependencies included, in execution order."""
    want: set = set()

    def add(name):
        if name in want:
            return
        want.add(name)
        for n in ctx.steps[name].needs:
            add(n)

    for k in tables:
        add(f"table-{k}")
    return [st for name, st in ctx.steps.items() if name in want]


# ----------------------------------------------------------------------------------------------
# the runner
# ----------------------------------------------------------------------------------------------
def _versions() -> dict:
    from importlib import metadata

    from .._version import __version__

    out = {"python": platform.python_version(), "spotlights": __version__, "platform": platform.platform(),
           "cpus": os.cpu_count()}
    for pkg in ("numpy", "scipy", "torch", "trimesh", "embreex", "h5py", "pykdtree", "pandas", "matplotlib", "pyarrow"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def _load_records(ctx: Context) -> None:
    p = ctx.out / "steps.json"
    if not p.is_file():
        return
    try:
        d = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError):
        raise SpotlightsError(f"{p}: unreadable step record; remove it to start the bookkeeping again") from None
    if d.get("format") != STEPS_FORMAT:
        raise SpotlightsError(f"{p}: not a spotlights reproduce step record")
    if d.get("mode") != ctx.s.mode:
        raise SpotlightsError(f"{ctx.out}: holds a {d.get('mode')} reproduction; use another --out for a {ctx.s.mode} one")
    ctx.records = d.get("steps", {})
    ctx.invocations = d.get("invocations", [])


def _save_records(ctx: Context) -> None:
    _write_json(ctx.out / "steps.json", {"format": STEPS_FORMAT, "mode": ctx.s.mode, "steps": ctx.records,
                                         "invocations": ctx.invocations})


def _now() -> str:
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _execute(ctx: Context, st: Step) -> str:
    """Run or reuse one step; returns "ran" or "reused"."""
    key = {"inputs": _signature(st.inputs(ctx)), "params": _clean(st.params(ctx))}
    rec = ctx.records.get(st.name)
    outputs_ok = all(Path(p).exists() for p in st.outputs(ctx))
    if rec and rec.get("status") == "done" and rec.get("key") == key and outputs_ok:
        ctx.log(f"[{st.name}] reusing the result of {rec.get('finished', '?')} ({rec.get('seconds', 0):.1f} s then)")
        rec["reused"] = True
        return "reused"
    if st.reuse is not None:
        found = st.reuse(ctx)
        if found:
            msg, info = found
            ctx.log(f"[{st.name}] {msg}")
            prev = rec if rec and rec.get("status") == "done" else {}
            ctx.records[st.name] = {"status": "done", "seconds": prev.get("seconds", 0.0), "command": prev.get("command", st.command(ctx)),
                                    "reused": True, "finished": prev.get("finished", _now()), "key": key, "info": info,
                                    "note": prev.get("note", "made outside this reproduction (or in an earlier run) and reused")}
            return "reused"
    ctx.log(f"[{st.name}] running: {st.command(ctx)}")
    ctx.records[st.name] = {"status": "running", "started": _now(), "command": st.command(ctx), "key": key}
    _save_records(ctx)
    t0 = time.perf_counter()
    info = st.run(ctx)
    dt = time.perf_counter() - t0
    cmd = ctx.records[st.name].get("command", st.command(ctx))
    # a step's inputs may be its own products (train -> best.pt): sign them after the run
    key = {"inputs": _signature(st.inputs(ctx)), "params": _clean(st.params(ctx))}
    ctx.records[st.name] = {"status": "done", "seconds": round(dt, 2), "command": cmd, "reused": False,
                            "finished": _now(), "key": key, "info": _clean(info or {})}
    _save_records(ctx)
    ctx.log(f"[{st.name}] done in {dt:.1f} s")
    return "ran"


@dataclass
class ReproduceResult:
    """What :func:`reproduce` did: the report's path, the steps run and reused, the wall time."""

    report: Path
    results: Path
    ran: list = field(default_factory=list)
    reused: list = field(default_factory=list)
    seconds: float = 0.0


def reproduce(out, tables=None, quick: bool = False, schedule: str | None = None, cars_data=None,
              cars_meshes=None, category_meshes=None, lidar=None, eval_views: int | None | str = "default",
              workers: int | None = None, seed: int = 0, progress: bool = True, log=None,
              argv: Sequence[str] | None = None) -> ReproduceResult:
    """Run (or resume) the reproduction of ``tables`` into ``out``; see the module docstring.

    Parameters
    ----------
    tables : keys of :data:`TABLES` or a "1,2,5" string (default: all).
    quick : small data and the ``quick`` schedule (minutes; its numbers only show that all runs).
    schedule : schedule of new training runs (default ``budget``; ``quick`` with ``quick``).
    cars_data : an existing car dataset (with rigs cap-32x64-60, cap-64x32-60, cap-256x64-60; the box
        table adds box-32x64-ellipsoid-s1 with dataset add-rig when the file lacks it).
    cars_meshes, category_meshes, lidar : shared data folders (default ``../shared/data/...``).
    eval_views : test views per test car for Tables 1 and 5 (default 200, --quick 4; None = all).
    workers : processes for the dataset build and the rig study (default 1).
    argv : the command line, recorded in the report.
    """
    t_start = time.perf_counter()
    keys = parse_tables(tables)
    if eval_views == "default":
        eval_views = 4 if quick else 200
    if eval_views is not None and int(eval_views) < 1:
        raise ParameterError(f"--eval-views must be >= 1, got {eval_views}")
    if workers is not None and int(workers) < 1:
        raise ParameterError(f"--workers must be >= 1, got {workers}")
    kw = {k: Path(v) for k, v in (("cars_meshes", cars_meshes), ("category_meshes", category_meshes), ("lidar", lidar))
          if v is not None}
    s = Settings(out=Path(out), quick=quick, schedule=schedule or ("quick" if quick else "budget"),
                 cars_data=Path(cars_data) if cars_data else None, eval_views=None if eval_views is None else int(eval_views),
                 workers=int(workers or 1), seed=int(seed), progress=progress, **kw)
    from ..learning.models import schedule_path

    schedule_path(s.schedule)  # an unknown schedule fails now, not after an hour
    if s.out.exists() and not s.out.is_dir():
        raise SpotlightsError(f"{s.out}: exists and is not a folder")
    if s.cars_data is not None and not s.cars_data.is_file():  # fails before the output folder is made
        raise SpotlightsError(f"{s.cars_data}: --cars-data names no such file")
    ctx = Context(s, log)
    ctx.steps = all_steps(ctx)
    s.out.mkdir(parents=True, exist_ok=True)
    with exclusive_lock(s.out / ".reproduce.lock", f"{s.out}: another 'spotlights reproduce' is running in this folder"):
        _load_records(ctx)
        inv = {"started": _now(), "argv": list(argv) if argv is not None else None, "tables": keys, "seconds": None}
        ctx.invocations.append(inv)
        todo = plan(ctx, keys)
        ran, reused = [], []
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="reproduce", unit="step", disable=not progress, position=0, dynamic_ncols=True)
        try:
            for st in todo:
                bar.set_postfix_str(st.name)
                (ran if _execute(ctx, st) == "ran" else reused).append(st.name)
                bar.update()
        finally:
            bar.close()
            inv["seconds"] = round(time.perf_counter() - t_start, 2)
            _save_records(ctx)
        report, results = write_report(ctx, keys, time.perf_counter() - t_start)
        inv["seconds"] = round(time.perf_counter() - t_start, 2)
        _save_records(ctx)
    return ReproduceResult(report, results, ran, reused, time.perf_counter() - t_start)


# ----------------------------------------------------------------------------------------------
# the report
# ----------------------------------------------------------------------------------------------
DIFFERENCES = [
    "**Meshes.** The paper used 79 CARLA vehicles (Tables 1, 5) and 6 ShapeNet categories (Tables 3, 4); we use the 79 "
    "ApolloScape car CAD models (hatchback 15, sedan 30, SUV 34; not watertight, some inner parts no ray reaches) and 130 "
    "meshes of 9 everyday categories (PartNet, PartNet-Mobility, ModelNet10, Kenney and others): other shapes, other "
    "tessellations, other category mixes.",
    "**LiDAR simulation.** The paper rendered HDL-64 scans in Blender; we simulate an HDL-64E ray caster (Embree) with "
    "range noise 0.02 m, vehicles 4-40 m away (spotlights.data.lidar). Partial scans differ in density and occlusion.",
    "**Training.** The paper trained on a GPU to convergence. Here every model gets a short, stated CPU budget (schedule "
    "`budget`, batch 32; each run's steps and minutes are listed under Tables 1 and 5), far below the paper's "
    "(~160,000 steps); the baselines are the most under-trained (they cost 4-12x more per step on a CPU). "
    "Accuracies "
    "are therefore higher (worse) than the paper's and the ranking among the baselines is not meaningful.",
    "**Models.** The paper does not give its layer widths; ours follow the original papers with the PCN encoder "
    "for all (docs/learning.md), so parameter counts differ (PCN 5.3M, FoldingNet 2.4M, TopNet 10.0M, AtlasNet 7.7M, "
    "SA-Net 1.7M with a 1024-256-256-N*M decoder; the paper: 7.6M, 8.5M, 7.5M, 8.3M, 0.9M). Point models output 2048 "
    "points, SA-Net one depth per ray (2048 rays, 32 x 64 at 60°).",
    "**Evaluation.** Accuracy is scored on a fixed subset of the test views (first V views of each test car, stated "
    "under Table 1) instead of all 2,000; timing is CPU time on a shared 2-core machine (the paper: a GPU), so the "
    "runtime column is only comparable between rows.",
    "**Real data.** The paper's Table 2 is on KITTI-360 (4,382 observations); KITTI-360 is not on this machine, so "
    "consistency is measured on the two consecutive Argoverse 2 sweeps shipped in ../shared/data (a few dozen tracked "
    "vehicles, mostly cars). The KITTI object frames have no track ids and are shown, not scored.",
    "**Ablation metric details.** 16,384 surface samples per mesh (seeded), each mesh normalised by its own axis-aligned "
    "box into the unit sphere, rigs of N x 64 rays. The paper does not say which ray count Table 4 uses; we give 2048.",
]

QUICK_NOTE = ("**This is a --quick run**: 9 cars (3 per body type, one each for train/val/test), 16 views each, the "
              "tiny `quick` schedule (a few training steps per model), 4 test views per test car, 2 meshes per category "
              "in the rig study. Its numbers only show that every stage runs; they say nothing about the methods.")


def write_report(ctx: Context, keys: Sequence[str], seconds: float) -> tuple[Path, Path]:
    """Write ``OUT/results.json`` and ``OUT/REPORT.md`` from the table JSONs and the step records."""
    tables = {k: _load(ctx.table_json(k)) for k in keys}
    versions = _versions()
    results = {"format": "spotlights-reproduce-results", "mode": ctx.s.mode, "tables": tables,
               "paper": {str(k): {("x".join(map(str, kk)) if isinstance(kk, tuple) else str(kk)): v for kk, v in t.items()}
                         for k, t in paper.PAPER_TABLES.items() if str(k) in keys},
               "steps": ctx.records, "versions": versions,
               "seeds": {"dataset": ctx.s.seed, "training": "train.seed of each run's config (0)",
                         "rig_study": ctx.s.seed, "real_extraction": ctx.s.seed},
               "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in ctx.s.__dict__.items()}}
    res_path = ctx.out / "results.json"
    _write_json(res_path, results)

    inv = ctx.invocations[-1] if ctx.invocations else {}
    argv = inv.get("argv")
    cmdline = "spotlights " + " ".join(shlex.quote(a) for a in argv) if argv else "spotlights reproduce --out " + _q(ctx.out)
    total = sum(float(r.get("seconds") or 0) for r in ctx.records.values())
    L = [f"# Spotlights: the paper's tables reproduced ({ctx.s.mode} run)", ""]
    if ctx.s.quick:
        L += [QUICK_NOTE, ""]
    L += [f"Generated {_now()} by `{cmdline}` (spotlights {versions['spotlights']}). Tables: "
          f"{', '.join(keys)}. Total compute recorded over all steps: {total / 60:.1f} min; this invocation: {seconds:.1f} s.", ""]
    # expectations
    L += ["## The paper's claims" + (" and issue 8's targets" if "box" in tables else "") + ", checked", "", "| table | claim | holds here | numbers |", "|---|---|---|---|"]
    for k, t in tables.items():
        for c in t.get("checks", []):
            L.append(f"| {k} | {c['claim']} | {'yes' if c['holds'] else '**no**'} | {c['detail']} |")
    L += [""]
    for k, t in tables.items():
        L += [f"## {t['title']}", "", t["markdown"], ""]
        for fig in TABLES[k].steps(ctx.s):
            if fig in FIGURES and (ctx.figures / FIGURES[fig][0]).is_file():
                for f, cap in [FIGURES[fig]] + EXTRA_FIGURES.get(fig, []):
                    if (ctx.figures / f).is_file():
                        L += [f"![{cap}](figures/{f})", "", f"*{cap}*", ""]
    L += ["## Why our numbers differ from the paper's", ""] + [f"- {d}" for d in DIFFERENCES] + [""]
    L += ["## Steps, commands and wall time", "",
          "Each step's equivalent command (paths as given); 'reused' = taken from an earlier run or from files that existed. "
          "Seconds are those of the run that computed the step.", "", "| step | seconds | this run | command |", "|---|---|---|---|"]
    for name, r in ctx.records.items():
        if r.get("status") != "done":
            L.append(f"| {name} | - | {r.get('status')} | `{r.get('command', '')}` |")
            continue
        L.append(f"| {name} | {float(r.get('seconds') or 0):.1f} | {'reused' if r.get('reused') else 'ran'} | `{r.get('command', '')}` |")
    L += ["", "## Versions and seeds", ""]
    L += [f"- {k}: {v}" for k, v in versions.items()]
    L += [f"- seeds: dataset {ctx.s.seed} (every random number of a view derives from it and the model name), training "
          f"`train.seed` = 0 of each run's config, rig study {ctx.s.seed} (surface samples per mesh), real extraction "
          f"{ctx.s.seed} (resampling); evaluation is deterministic.",
          "- all numbers: `results.json`; per table: `tables/table<K>.json` and `.csv`; per checkpoint: `eval/<run>.md`.", ""]
    md_path = ctx.out / "REPORT.md"
    with atomic_output(md_path, suffix=".md") as tmp:
        Path(tmp).write_text("\n".join(L) + "\n")
    return md_path, res_path


PUBLISHED = ("REPORT.md", "results.json", "steps.json", "tables", "figures")
"""What :func:`publish` copies: the report, its numbers and its pictures (no data, checkpoints or caches)."""


def publish(out, dest) -> Path:
    """Copy a finished reproduction's report, numbers and figures from ``out`` into ``dest``
    (e.g. ``docs/results/reproduction``), replacing what ``dest`` held of them.

    The report's figure links are relative (``figures/...``), so they work in ``dest``.
    Raises :class:`SpotlightsError` when ``out`` holds no report.
    """
    import shutil

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
