"""The work steps of ``spotlights reproduce``: the car dataset, training, evaluation, real scans, consistency, rig study.

Each step is a ``run(ctx) -> info`` function, its equivalent command and, where artifacts
made outside the reproduction can stand in for it, a ``reuse`` check; :func:`work_steps`
lists them as :class:`~.pipeline.Step` records (the real scans and consistency are in
:mod:`.steps_real`, the figures in :mod:`.figures`, the table steps in :mod:`.tables`).
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

from ...data.store import open_dataset
from ...data.synthetic import BuildConfig, add_rig, build_dataset
from ...errors import SpotlightsError
from ...learning import evaluate as learning_evaluate
from ...learning.bench import model_latency
from ...learning.checkpoint import load_checkpoint, model_from_checkpoint
from ...learning.evaluate import evaluate_checkpoints
from ...learning.models import load_config, load_schedule
from ...outputs import atomic_output
from ..rig_study import BOX_RIGS, PAPER_RIGS, find_meshes, run_study, study_rigs, summarize
from .pipeline import Context, Step, shell_quote
from .settings import (
    ABLATION_RAYS,
    BOX_RIG,
    BOX_STUDY_LABELS,
    DENSE_RIG,
    PEER_RUNS,
    PRODUCT_RUNS,
    REQUIRED_RIGS,
    RIG_STEPS,
    RUNS,
    TABLE1_RUNS,
    Settings,
)

# the real-data steps live in .steps_real; their public names stay importable from here
from .steps_real import CONSISTENCY_OPTIONS as CONSISTENCY_OPTIONS
from .steps_real import REAL_SOURCES as REAL_SOURCES
from .steps_real import FirstFrames as FirstFrames
from .steps_real import completers as completers
from .steps_real import real_classes as real_classes
from .steps_real import real_frames as real_frames
from .steps_real import real_min_points as real_min_points
from .steps_real import real_steps


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
    kw = dict(
        meshes=str(ctx.s.cars_meshes),
        views=ctx.s.views,
        seed=ctx.s.seed,
        extra_rigs=["64x32@60", "256x64@60", BOX_RIG, DENSE_RIG],
    )
    if ctx.s.quick:
        kw.update(manifest=str(ctx.out / "data" / "quick-cars.csv"), split="3/3/3")
    else:
        kw.update(split="64/8/7")
    return BuildConfig(**kw)


def _cars_command(ctx: Context) -> str:
    if ctx.s.cars_data is not None:
        return f"(given with --cars-data {shell_quote(ctx.s.cars_data)})"
    cmd = (
        f"spotlights dataset build --meshes {shell_quote(ctx.s.cars_meshes)} --out {shell_quote(ctx.s.cars_path)} "
        f"--views {ctx.s.views} --split {'3/3/3' if ctx.s.quick else '64/8/7'} --rig 64x32@60 --rig 256x64@60 --rig {BOX_RIG} --rig {DENSE_RIG} "
        f"--seed {ctx.s.seed}"
    )
    if ctx.s.quick:
        cmd += f" --manifest {shell_quote(ctx.out / 'data' / 'quick-cars.csv')}"
    return cmd


def _check_cars(path: Path) -> dict:
    with open_dataset(path) as ds:
        info = ds.info()
    missing = [r for r in REQUIRED_RIGS if r not in info["rigs"]]
    if missing:
        raise SpotlightsError(
            f"{path}: the car dataset lacks the rig(s) {', '.join(missing)} that Tables 1 and 5 need "
            "(build it with --rig 64x32@60 --rig 256x64@60)"
        )
    return {
        "n_models": info["n_models"],
        "n_samples": info["n_samples"],
        "views_per_model": info["views_per_model"],
        "splits": {k: v["models"] for k, v in info["splits"].items()},
        "categories": info["categories"],
        "seed": info["seed"],
        "rigs": list(info["rigs"]),
    }


def _has_rig(path: Path, name: str) -> bool:
    with open_dataset(path) as ds:
        return name in ds.rig_names


def _reuse_cars_rig(ctx: Context, rig: str):
    if _has_rig(ctx.s.cars_path, rig):
        return f"the car dataset {ctx.s.cars_path} holds rig {rig}", {"rig": rig, "added": False}
    return None


def _cars_rig_command(ctx: Context, rig: str) -> str:
    return f"spotlights dataset add-rig {shell_quote(ctx.s.cars_path)} --rig {rig} -j {ctx.s.workers} (only if the file lacks it)"


def _run_cars_rig(ctx: Context, rig: str) -> dict:
    """Add rig ``rig``'s ground truth to a car dataset that lacks it (``spotlights dataset add-rig``; atomic)."""
    rep = add_rig(ctx.s.cars_path, rig, workers=ctx.s.workers, progress=ctx.s.progress, log=ctx.log)
    return {"rig": rig, "added": not rep.already_present, "hit_ratio": rep.hit_ratio}


def _reuse_cars(ctx: Context):
    p = ctx.s.cars_path
    if p.is_file():
        return f"reusing the car dataset {p}", _check_cars(p)
    if ctx.s.cars_data is not None:
        raise SpotlightsError(f"{p}: --cars-data names no such file")
    return None


def _run_cars(ctx: Context) -> dict:
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
        ck = load_checkpoint(last)
        done, total = int(ck.get("epoch", 0)), int(ck["config"]["train"]["epochs"])
    return {"state": "finished" if done >= total else "unfinished", "epochs": done, "epochs_total": total}


def run_info(run_dir: Path) -> dict:
    """Facts of a finished run for the report: model, rig, epochs, steps, schedule-relevant config, best epoch."""
    ck = load_checkpoint(run_dir / "last.pt")
    cfg = ck["config"]
    hist = ck.get("history") or []
    return {
        "model": ck["model_name"],
        "rig": (ck.get("dataset") or {}).get("rig"),
        "epochs": int(ck["epoch"]),
        "steps": int(ck["global_step"]),
        "batch_size": int(cfg["train"]["batch_size"]),
        "max_views": cfg["data"].get("max_views"),
        "lr": cfg["train"].get("lr"),
        "seed": cfg["train"].get("seed"),
        "n_train": (ck.get("dataset") or {}).get("n_train"),
        "best": ck.get("best"),
        "train_seconds": float(sum(float(r.get("epoch_seconds") or 0) for r in hist)),
        "data": (ck.get("dataset") or {}).get("path"),
    }


def pass_steps_per_epoch(ctx: Context, run: str) -> int | None:
    """The ``train.steps_per_epoch`` the reproduction sets for ``run``, or None (the run's config as it is).

    A packaged run config may fix ``train.steps_per_epoch`` for the fair protocol (the default model's
    ``variants/sanet-hit-dense.yaml``: 700, i.e. 17,500 steps in the fair schedule's 25 epochs). Under a
    schedule that gives the model no ``steps_per_epoch`` of its own (``budget``, ``quick``, ``cpu``,
    ``paper``: an epoch is one pass over the training views), that value would multiply the schedule's
    budget, so the run gets the steps of one such pass instead (training samples of the car dataset
    with view < the schedule's ``max_views``, divided by its batch size), as every other run of that
    schedule. Reads the car dataset's sample table (it must exist).
    """
    import yaml

    spec = RUNS[run]
    if spec.config is None:
        return None
    fixed = ((yaml.safe_load(spec.config_path.read_text()) or {}).get("train") or {}).get("steps_per_epoch")
    sched = load_schedule(ctx.s.schedule, spec.model)
    if fixed is None or (sched.get("train") or {}).get("steps_per_epoch") is not None:
        return None
    cfg = load_config(spec.model, spec.config_path, schedule=ctx.s.schedule)
    max_views, batch = cfg["data"].get("max_views"), int(cfg["train"]["batch_size"])
    with open_dataset(ctx.s.cars_path) as ds:
        views = ds.sample_view[ds.split_indices("train")]
    n = int((views < int(max_views)).sum()) if max_views else len(views)
    return n // batch if n >= batch else max(1, math.ceil(n / batch))


def train_overrides(ctx: Context, run: str) -> dict | None:
    """The ``overrides`` of ``train()`` for ``run``: its rig and, where needed, :func:`pass_steps_per_epoch`."""
    spec = RUNS[run]
    out: dict = {}
    if spec.rig:
        out["data"] = {"rig": spec.rig}
    steps = pass_steps_per_epoch(ctx, run)
    if steps is not None:
        out["train"] = {"steps_per_epoch": steps}
    return out or None


def train_command(ctx: Context, run: str, resume: bool = False) -> str:
    """The shell command that trains ``run`` as this reproduction does (shown in the report's steps):
    ``spotlights train`` with its model, data, output folder, schedule, config, rig and, where the run
    needs one, ``--steps-per-epoch`` (:func:`pass_steps_per_epoch`); with ``resume`` the command that continues it."""
    spec = RUNS[run]
    cmd = f"spotlights train --model {spec.model} --data {shell_quote(ctx.s.cars_path)} --out {shell_quote(ctx.run_dir(run))}"
    if resume:
        return cmd + " --resume"
    cmd += f" --schedule {shell_quote(ctx.s.schedule)}"
    if spec.config_path is not None:
        cmd += f" --config {shell_quote(spec.config_path)}"
    if spec.rig:
        cmd += f" --rig {spec.rig}"
    if spec.config is not None:
        try:
            steps = pass_steps_per_epoch(ctx, run)
        except SpotlightsError:  # no car dataset yet: say what the number will be
            return cmd + " [--steps-per-epoch <one pass of the training views>]"
        if steps is not None:
            cmd += f" --steps-per-epoch {steps}"
    return cmd


def _reuse_train(ctx: Context, run: str):
    st = run_state(ctx.run_dir(run))
    if st["state"] == "finished":
        info = run_info(ctx.run_dir(run))
        msg = f"reusing run {run}: {st['epochs']}/{st['epochs_total']} epochs done"
        if info.get("data") and Path(info["data"]).resolve() != Path(ctx.s.cars_path).resolve():
            msg += f" (warning: trained on {info['data']}, not on {ctx.s.cars_path})"
        return msg, info
    return None


def _run_train(ctx: Context, run: str) -> dict:
    from ...learning.train import train

    spec = RUNS[run]
    d = ctx.run_dir(run)
    st = run_state(d)
    if st["state"] == "unfinished":
        ctx.log(f"resuming run {run} after epoch {st['epochs']}/{st['epochs_total']}")
        train(spec.model, ctx.s.cars_path, d, resume=True, progress=ctx.s.progress, log=ctx.log)
        ctx.records.setdefault(f"train-{run}", {})["command"] = train_command(ctx, run, resume=True)
    else:
        train(
            spec.model,
            ctx.s.cars_path,
            d,
            config=spec.config_path,
            schedule=ctx.s.schedule,
            overrides=train_overrides(ctx, run),
            overwrite=(d / "last.pt").exists(),
            progress=ctx.s.progress,
            log=ctx.log,
        )
    return run_info(d)


# --- evaluation -------------------------------------------------------------------------------
TIMED_RUNS = TABLE1_RUNS + PRODUCT_RUNS + PEER_RUNS
"""The runs whose evaluation measures latency (Table 1's runtime columns)."""


def _eval_command(ctx: Context, run: str) -> str:
    views = f" --max-views {ctx.s.eval_views}" if ctx.s.eval_views else ""
    lat = " --latency" if run in TIMED_RUNS and not ctx.s.quick else ""
    return (
        f"spotlights evaluate --data {shell_quote(ctx.s.cars_path)} --checkpoint {shell_quote(ctx.run_dir(run) / 'best.pt')} "
        f"--split test{views}{lat} --out {shell_quote(ctx.out / 'eval' / run)}"
    )


def _run_eval(ctx: Context, run: str) -> dict:
    timed = run in TIMED_RUNS
    rep = evaluate_checkpoints(
        [ctx.run_dir(run) / "best.pt"],
        ctx.s.cars_path,
        split="test",
        max_views=ctx.s.eval_views,
        latency=timed and not ctx.s.quick,
        latency_repeats=10,
        progress=ctx.s.progress,
    )
    if timed and ctx.s.quick:  # a short timing at batch 1 (the full run times batch 1 and 32, 10 repeats)
        import torch

        dev = torch.device("cpu")
        model = model_from_checkpoint(load_checkpoint(ctx.run_dir(run) / "best.pt"), dev)
        res = rep["results"][0]
        res["latency_ms"] = model_latency(model, dev, batches=(1,), repeats=3, warmup=1)
        res["latency_device"], res["threads"] = str(dev), torch.get_num_threads()
    learning_evaluate.write_report(rep, ctx.out / "eval" / run)
    return {"n_samples": rep["n_samples"], "n_models": rep["n_models"]}


# --- rig study (Tables 3 and 4) ------------------------------------------------------------------
def study_meshes(s: Settings) -> list:
    """The rig study's meshes: category folders with >= 5 meshes, then the cars (--quick: a few of each)."""
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
    return tuple(PAPER_RIGS) + tuple(v for v in BOX_RIGS if v[0] in BOX_STUDY_LABELS)


def _study_command(ctx: Context) -> str:
    return (
        "python -c 'from spotlights.experiments import rig_study as r; "
        f'r.run_study(r.find_meshes(["{ctx.s.category_meshes}", "{ctx.s.cars_meshes}"]), '
        f"r.study_rigs({list(ABLATION_RAYS)}, variants=r.PAPER_RIGS + [v for v in r.BOX_RIGS if v[0] in "
        f"{list(BOX_STUDY_LABELS)}]), seed={ctx.s.seed})'"
        + (" (--quick: the first 2 meshes of each category)" if ctx.s.quick else "")
        + "; the same rigs are part of 'spotlights study rigs'"
    )


def _run_study(ctx: Context) -> dict:
    meshes = study_meshes(ctx.s)
    rigs = study_rigs(ABLATION_RAYS, variants=study_variants())
    d = ctx.out / "rig_study"
    df = run_study(
        meshes, rigs, seed=ctx.s.seed, workers=ctx.s.workers, cache_dir=d / ".cache", progress=ctx.s.progress
    )
    summary = summarize(df)
    d.mkdir(parents=True, exist_ok=True)
    with atomic_output(d / "per_mesh.csv", suffix=".csv") as tmp:
        df.to_csv(tmp, index=False, float_format="%.6f")
    with atomic_output(d / "summary.csv", suffix=".csv") as tmp:
        summary.to_csv(tmp, index=False, float_format="%.6f")
    counts = df.drop_duplicates(["mesh_set", "mesh"]).groupby(["mesh_set", "category"]).size()
    return {"meshes": {f"{a}/{b}": int(n) for (a, b), n in counts.items()}}


def _cars_steps() -> list[Step]:
    """The car dataset step and one step per box rig that adds its ground truth to a dataset lacking it."""
    steps = [
        Step("cars-data", _run_cars, _cars_command, lambda c: [c.s.cars_path], reuse=_reuse_cars),
    ]
    # the box rigs' ground truth: built into new datasets; added to an existing file that lacks them
    for rig, name in RIG_STEPS.items():
        steps.append(
            Step(
                name,
                (lambda c, g=rig: _run_cars_rig(c, g)),
                (lambda c, g=rig: _cars_rig_command(c, g)),
                lambda c: [c.s.cars_path],
                needs=("cars-data",),
                inputs=lambda c: [c.s.cars_path],
                reuse=(lambda c, g=rig: _reuse_cars_rig(c, g)),
            )
        )
    return steps


def _train_step(run: str) -> Step:
    """The step that trains (or resumes, or reuses) run ``run``."""
    needs = ("cars-data",) + ((RIG_STEPS[RUNS[run].rig],) if RUNS[run].rig in RIG_STEPS else ())
    return Step(
        f"train-{run}",
        (lambda c, r=run: _run_train(c, r)),
        (lambda c, r=run: train_command(c, r)),
        (lambda c, r=run: [c.run_dir(r) / "last.pt", c.run_dir(r) / "best.pt"]),
        needs=needs,
        reuse=(lambda c, r=run: _reuse_train(c, r)),
    )


def _eval_step(run: str) -> Step:
    """The step that evaluates run ``run``'s ``best.pt`` on the car dataset's test split."""
    return Step(
        f"eval-{run}",
        (lambda c, r=run: _run_eval(c, r)),
        (lambda c, r=run: _eval_command(c, r)),
        (lambda c, r=run: [c.eval_json(r)]),
        needs=("cars-data", f"train-{run}"),
        inputs=(lambda c, r=run: [c.s.cars_path, c.run_dir(r) / "best.pt"]),
        params=lambda c: {"eval_views": c.s.eval_views, "quick": c.s.quick},
    )


def _study_step() -> Step:
    """The rig study step (Tables 3, 4 and the box table)."""
    return Step(
        "rig-study",
        _run_study,
        _study_command,
        lambda c: [c.out / "rig_study" / "summary.csv", c.out / "rig_study" / "per_mesh.csv"],
        params=lambda c: {
            "quick": c.s.quick,
            "seed": c.s.seed,
            "meshes": [str(c.s.category_meshes), str(c.s.cars_meshes)],
            "rigs": [label for label, _ in study_variants()],
        },
    )


def work_steps() -> list[Step]:
    """The steps that compute (datasets, runs, evaluations, real data, consistency, rig study), in execution order."""
    return [
        *_cars_steps(),
        *(_train_step(run) for run in RUNS),
        *(_eval_step(run) for run in RUNS),
        *real_steps(),
        _study_step(),
    ]
