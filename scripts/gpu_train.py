"""The GPU recipe: build the training set from carried meshes, time a step, train what fits a time budget.

Run through ``scripts/gpu_train.sh MODEL_CONFIG [MINUTES] [options]`` (which first installs missing packages from
the carried wheels); docs/training.md, "GPU recipe". On a machine with one GPU and a hard limit per run:

1. **data**: ``spotlights dataset build`` of the meshes it carries (``--meshes``; default the first of
   ``$GPU_MESHES``, ``.whl/meshes/apolloscape-cars``, ``shared/data/...`` and ``../shared/data/...``), the paper's
   64/8/7 split, ``--views`` views per car, with the rig the configuration trains on, all cores; with ``--source``
   (more mesh folders) and ``--procedural N`` (procedural vehicles per class) a training set of every class,
   ``WORK/union.h5`` (docs/studies/one-model.md);
2. **step time**: a few warm-up steps, then ``--probe-steps`` timed training steps (batch, precision and
   optimizer of the run, CUDA synchronised);
3. **plan**: the steps that fit what is left of ``MINUTES`` (less a reserve for the last interval's validation
   and the copies; ``--overhead`` covers data loading and validation), at most the paper's 160,000;
   ``--intervals`` validation intervals (checkpoints);
4. **training**: the fair protocol (``configs/schedules/fair.yaml``: Adam 1e-3, cosine to 5e-5, batch 32, bf16
   autocast) with the planned steps, one interval per call of ``spotlights.learning.train.train`` (resumed
   from ``last.pt``); after every interval, whose wall time (its steps, data loading, validation and checkpoint)
   is measured, the schedule is shortened to the intervals that fit at the slowest interval so far (the
   learning-rate schedule is recomputed for the new total, so the cosine decay still ends); with ``--steps``, the
   run stops early when the next interval would pass the deadline;
5. **outputs** in ``--out`` (default ``$OUT``): ``best.pt`` (the project's checkpoint, loadable with
   ``spotlights.learning.checkpoint.load_checkpoint``; float16 weights when the float32 file would pass
   ``--max-file-mb``), ``last.pt`` when it fits that size too, ``log.csv``, ``config.yaml``, ``gpu_train.log``
   and ``plan.json`` (device, build, step time, planned and done steps, timings).

MODEL_CONFIG: ``default`` (the default model: ``sanet-hit`` with ``configs/variants/sanet-hit-dense.yaml``),
a registered model name (``snowflakenet``, ``foldingnet``...; its packaged config), or a YAML config (its
``model.name``, or ``--model``). Bad input exits with code 2 and one line.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PAPER_STEPS = 160_000
"""The paper's scale: 40 epochs of 4,000 steps of 32 (docs/training.md, "Schedules")."""
DEFAULT_VARIANT = "variants/sanet-hit-dense.yaml"
MESH_CANDIDATES = (
    REPO / ".whl" / "meshes" / "apolloscape-cars",
    REPO / "shared" / "data" / "meshes" / "apolloscape-cars",
    REPO.parent / "shared" / "data" / "meshes" / "apolloscape-cars",
)


class Log:
    """Timestamped lines to stdout and to a file."""

    def __init__(self, path: Path | None = None):
        self.path = path
        self.t0 = time.perf_counter()

    def __call__(self, msg: str) -> None:
        line = f"[gpu_train {time.perf_counter() - self.t0:7.1f} s] {msg}"
        print(line, flush=True)
        if self.path is not None:
            with open(self.path, "a") as f:
                f.write(line + "\n")


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="gpu_train", description=__doc__.split("\n\n")[0])
    ap.add_argument("model_config", help="'default', a registered model name, or a YAML config")
    ap.add_argument("minutes", nargs="?", type=float, default=float(os.environ.get("GPU_MINUTES", 7)))
    ap.add_argument("--model", default=None, help="the model of a YAML config without model.name")
    ap.add_argument("--out", default=os.environ.get("OUT"), help="output folder (default $OUT)")
    ap.add_argument("--work", default=None, help="work folder for the dataset and the run (default OUT/../work)")
    ap.add_argument("--meshes", default=os.environ.get("GPU_MESHES"), help="mesh folder (see the docstring)")
    ap.add_argument("--views", type=int, default=400, help="views per car of the training set (default 400)")
    ap.add_argument("--split", default="64/8/7", help="train/val/test models (default the paper's 64/8/7)")
    ap.add_argument("--workers", type=int, default=None, help="dataset build processes (default all cores)")
    ap.add_argument(
        "--reuse-data",
        action="store_true",
        help="keep WORK/cars.h5 when an earlier run built it from the same meshes, views, split and seed with the rig "
        "this model needs (a second model in the same call: no second build)",
    )
    ap.add_argument(
        "--source",
        action="append",
        default=[],
        metavar="DIR[,key=value...]",
        help="another mesh folder of the training set, as `spotlights dataset build --meshes` takes it (repeatable; "
        "e.g. DIR,manifest=CSV,split=train,name=NAME; DIR may name a folder of the carried meshes, kenney-vehicles); "
        "the carried meshes then keep --split as their own split",
    )
    ap.add_argument(
        "--procedural",
        type=int,
        default=0,
        metavar="N",
        help="add N procedural vehicles per class of --classes to the training set (0..10000; default 0: none)",
    )
    ap.add_argument(
        "--classes", default="car,van,truck,bus,trailer", help="classes of --procedural (default every class)"
    )
    ap.add_argument(
        "--procedural-split", default="0.8/0.1/0.1", help="split of the procedural vehicles (default 0.8/0.1/0.1)"
    )
    ap.add_argument("--cpu", action="store_true", help="force the CPU (tests; the GPU otherwise)")
    ap.add_argument("--precision", default="bf16", choices=["bf16", "fp32"], help="autocast of training")
    ap.add_argument("--batch-size", type=int, default=None, help="batch size (default the fair protocol's 32)")
    ap.add_argument(
        "--loader-workers", type=int, default=None, help="DataLoader processes (default 4 on GPU, 0 on CPU)"
    )
    ap.add_argument("--probe-steps", type=int, default=20, help="timed steps of the step-time probe")
    ap.add_argument("--steps", type=int, default=None, help="train exactly this many steps (no planning)")
    ap.add_argument("--intervals", type=int, default=10, help="validation intervals (checkpoints) of the run")
    ap.add_argument("--val-views", type=int, default=25, help="validation views per validation car")
    ap.add_argument("--overhead", type=float, default=1.3, help="wall time per step / probed step time")
    ap.add_argument("--reserve", type=float, default=None, help="seconds kept for the end (default 8%%, >= 20)")
    ap.add_argument("--max-file-mb", type=float, default=15.5, help="largest output file (the $OUT limit: 16 MiB)")
    ap.add_argument("--seed", type=int, default=0)
    return ap.parse_args(argv)


def resolve_model(spec: str, model: str | None) -> tuple[str, Path | None]:
    """(registry name, config YAML or None) of MODEL_CONFIG."""
    from importlib import resources

    import yaml

    from spotlights.errors import InputFileError, ParameterError
    from spotlights.learning.models import MODEL_NAMES, check_model_name

    if spec == "default":
        return "sanet-hit", Path(str(resources.files("spotlights.learning") / "configs" / DEFAULT_VARIANT))
    if spec in MODEL_NAMES:
        return spec, None
    path = Path(spec)
    if path.suffix.lower() not in (".yaml", ".yml") and not path.is_file():
        raise ParameterError(
            f"unknown model {spec!r}; give 'default', one of {', '.join(MODEL_NAMES)}, or a YAML config"
        )
    if not path.is_file():
        raise InputFileError(path, "no such config file")
    try:
        name = ((yaml.safe_load(path.read_text()) or {}).get("model") or {}).get("name") or model
    except (yaml.YAMLError, AttributeError):
        raise InputFileError(path, "not a YAML mapping (model:, data:, train:)") from None
    if name is None:
        raise InputFileError(path, "names no model (model.name); pass --model NAME")
    return check_model_name(name), path


def find_meshes(given: str | None) -> Path:
    """The mesh folder: ``given``, else the first candidate that exists."""
    from spotlights.errors import InputFileError, SpotlightsError

    if given:
        if not Path(given).is_dir():
            raise InputFileError(Path(given), "no such mesh folder")
        return Path(given)
    for p in MESH_CANDIDATES:
        if p.is_dir():
            return p
    raise SpotlightsError(
        "no meshes found (looked in " + ", ".join(str(p) for p in MESH_CANDIDATES) + "); pass --meshes or run "
        "scripts/gpu_bundle.sh where the shared data is"
    )


def reuse_problem(path: Path, cfg, rig: str | None) -> str | None:
    """Why the dataset at ``path`` cannot stand in for a build of ``cfg`` (a ``BuildConfig``) with ``rig``, or None
    when it can: built from the same meshes, views, split and seed, and holding ``rig`` (None: any)."""
    from spotlights.data.store import open_dataset
    from spotlights.errors import SpotlightsError
    from spotlights.geometry.rig import parse_rig

    if not path.is_file():
        return "none there yet"
    try:
        store = open_dataset(path)
    except SpotlightsError as exc:
        return str(exc)
    want, have = cfg.to_dict(), store.config
    for key in ("meshes", "views", "split", "seed", "sources", "procedural"):
        if have.get(key) != want.get(key):
            return f"its {key} is {have.get(key)!r}, not {want.get(key)!r}"
    if rig and parse_rig(rig).name not in store.rig_names:
        return f"it has no rig {rig} (rigs: {', '.join(store.rig_names)})"
    return None


def build_data(meshes: Path, out: Path, args, rig: str | None, log) -> dict:
    """Build the training set (or, with ``--reuse-data``, keep one built the same way); returns {path, seconds,
    samples, views, rig, reused}."""
    from spotlights.data.store import open_dataset
    from spotlights.data.synthetic.config import BuildConfig
    from spotlights.data.synthetic.runner import build_dataset

    t0 = time.perf_counter()
    cfg = BuildConfig(
        meshes=str(meshes),
        views=int(args.views),
        split=args.split,
        seed=int(args.seed),
        extra_rigs=[rig] if rig else [],
    )
    if getattr(args, "source", None) or getattr(args, "procedural", 0):
        cfg = union_config(meshes, args, rig)
    if getattr(args, "reuse_data", False):
        why = reuse_problem(out, cfg, rig)
        if why is None:
            n = int(open_dataset(out).n_samples)
            log(f"dataset: {out} reused ({n:,} samples, {args.views} views per model, split {args.split})")
            return {
                "path": str(out),
                "seconds": 0.0,
                "views": int(args.views),
                "samples": n,
                "rig": rig,
                "reused": True,
            }
        log(f"dataset: {out} built again: {why}")
    rep = build_dataset(cfg, out, workers=args.workers or os.cpu_count(), overwrite=True, progress=False, log=log)
    seconds = time.perf_counter() - t0
    n = int(rep.n_samples)
    log(f"dataset: {out} built in {seconds:.1f} s ({args.views} views per model, split {args.split})")
    return {"path": str(out), "seconds": seconds, "views": int(args.views), "samples": n, "rig": rig, "reused": False}


def carried_source(source: str) -> str:
    """``--source DIR[,key=value...]`` with DIR a folder of the carried meshes (``$GPU_MESH_DIR``, where
    gpu_train.sh unpacked ``.whl/meshes.tar.xz``: ``kenney-vehicles``) when no folder DIR exists here."""
    folder, _, rest = source.partition(",")
    base = os.environ.get("GPU_MESH_DIR")
    if base and not Path(folder).exists() and (Path(base) / folder).is_dir():
        folder = str(Path(base) / folder)
    return folder + ("," + rest if rest else "")


def union_config(meshes: Path, args, rig: str | None):
    """The ``BuildConfig`` of a training set of several sources (the carried meshes with ``--split`` as their own
    split, every ``--source``) and ``--procedural`` N vehicles per class of ``--classes`` (as ``spotlights dataset
    build`` makes it: :class:`~spotlights.data.synthetic.request.BuildRequest`; bad values are a ParameterError)."""
    from spotlights.data.synthetic.request import BuildRequest

    n = int(args.procedural or 0)
    req = BuildRequest(
        out="unused.h5",
        meshes=[f"{meshes},split={args.split}", *args.source],
        views=int(args.views),
        seed=int(args.seed),
        rig=[rig] if rig else [],
        procedural=n,
        classes=args.classes if n else None,
        procedural_split=args.procedural_split if n else None,
    )
    return req.build_config()


def probe_step(name: str, cfg: dict, data: Path, device, precision: str, steps: int, log) -> float:
    """Mean seconds of one training step (forward under ``precision``, loss, backward, Adam) over ``steps``
    steps after 3 warm-up steps, CUDA synchronised."""
    import torch
    from torch.utils.data import DataLoader

    from spotlights.learning.data import TorchCompletionDataset
    from spotlights.learning.device import autocast
    from spotlights.learning.models import build_model, model_class
    from spotlights.learning.training_run import training_rays
    from spotlights.learning.validation import collate, float_outputs, to_device, with_boxes

    wants_depths = model_class(name).target == "depths"
    ds = TorchCompletionDataset(
        data, "train", rig=cfg["data"]["rig"] if wants_depths else False, partials_in_memory=True
    )
    torch.manual_seed(0)
    model = build_model(cfg, rig=ds.rig).to(device).train()
    rays = training_rays(model, ds.rig if wants_depths else None, ds)  # as the training loop: evidence, box loss
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    loader = DataLoader(ds, batch_size=int(cfg["train"]["batch_size"]), shuffle=True, collate_fn=collate)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    warmup, it, t0 = 3, iter(loader), 0.0
    for i in range(warmup + steps):
        try:
            batch = next(it)
        except StopIteration:
            it = iter(loader)
            batch = next(it)
        batch = with_boxes(to_device(batch, device), model, rays, ds.sizes)
        with autocast(precision, device):
            out = model(*model.forward_inputs(batch, rays))
        loss, _ = model.loss(float_outputs(out), batch, 0.5)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if i == warmup - 1:
            sync()
            t0 = time.perf_counter()
    sync()
    step_s = (time.perf_counter() - t0) / max(steps, 1)
    log(f"step time: {step_s * 1e3:.1f} ms per step of {cfg['train']['batch_size']} at {precision} on {device}")
    del model, opt
    return step_s


def plan_steps(args, step_s: float, left_s: float) -> tuple[int, int]:
    """(intervals, steps per interval) that fit ``left_s`` seconds at ``step_s * overhead`` per step."""
    if args.steps is not None:
        steps = int(args.steps)
    else:
        steps = min(PAPER_STEPS, int(max(left_s, 0.0) // (step_s * args.overhead)))
    steps = max(steps, 1)
    intervals = max(1, min(int(args.intervals), steps))
    return intervals, math.ceil(steps / intervals)


def fit_intervals(intervals: int, done: int, interval_s: float, left_s: float, margin: float = 1.05) -> int:
    """The total intervals of the run once ``done`` intervals took ``interval_s`` seconds each (measured wall
    time, validation and checkpoint included) and ``left_s`` seconds are left: ``done`` plus those that fit at
    ``margin`` x that time, at most ``intervals`` (the plan; never lengthened) and at least ``done``."""
    more = int(max(left_s, 0.0) // (margin * max(interval_s, 1e-9)))
    return max(done, min(intervals, done + more))


def copy_outputs(run: Path, out: Path, max_mb: float, log) -> list[str]:
    """best.pt (float16 when too large), last.pt when small enough, log.csv, config.yaml -> ``out``."""
    from spotlights.learning.checkpoint import export_weights

    done = []
    limit = max_mb * 2**20
    best = run / "best.pt"
    if best.is_file():
        if best.stat().st_size <= limit:
            shutil.copy2(best, out / "best.pt")
        else:
            export_weights(best, out / "best.pt", half=True)
            log(f"best.pt is {best.stat().st_size / 2**20:.1f} MiB: written with float16 weights")
        done.append("best.pt")
    last = run / "last.pt"
    if last.is_file() and last.stat().st_size <= limit:
        shutil.copy2(last, out / "last.pt")
        done.append("last.pt")
    for name in ("log.csv", "config.yaml"):
        if (run / name).is_file():
            shutil.copy2(run / name, out / name)
            done.append(name)
    return done


def main(argv=None) -> int:
    t_start = time.perf_counter()
    args = parse_args(argv)
    if not args.out:
        print("gpu_train: error: no output folder: set $OUT or pass --out", file=sys.stderr)
        return 2
    from spotlights.errors import InputFileError, ParameterError, SpotlightsError

    try:
        # the inputs first, before any folder is made or torch imported
        name, cfg_path = resolve_model(args.model_config, args.model)
        if args.minutes <= 0:
            raise ParameterError(f"MINUTES must be > 0, got {args.minutes}")
        meshes = find_meshes(args.meshes)
        if not 0 <= args.procedural <= 10_000:
            raise ParameterError(f"--procedural must be 0..10000 vehicles per class, got {args.procedural}")
        args.source = [carried_source(src) for src in args.source]
        for src in args.source:
            folder = Path(src.split(",")[0])
            if not folder.is_dir():
                raise InputFileError(folder, "no such mesh folder (--source)")
        if args.procedural:
            from spotlights.data.vehicle_classes import VEHICLE_CLASSES, canonical_class

            bad = [c for c in args.classes.split(",") if canonical_class(c) not in VEHICLE_CLASSES]
            if bad:
                raise ParameterError(f"--classes: {bad[0]!r} is not one of {', '.join(VEHICLE_CLASSES)} (or van)")
        if args.source or args.procedural:
            union_config(meshes, args, None)  # its values checked now, before any folder is made
        if not args.cpu:
            import torch

            if not torch.cuda.is_available():
                raise ParameterError("no CUDA device here; pass --cpu to train on the CPU")
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        return run(args, name, cfg_path, meshes, out, Log(out / "gpu_train.log"), t_start)
    except SpotlightsError as exc:
        print(f"gpu_train: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"gpu_train: error: {exc}", file=sys.stderr)
        return 2


def run(args, name: str, cfg_path: Path | None, meshes: Path, out: Path, log, t_start: float) -> int:
    """Build, probe, plan, train and copy (the inputs checked by :func:`main`); returns 0."""
    import torch

    from spotlights.learning.models import load_config
    from spotlights.learning.train import train

    deadline = t_start + 60.0 * args.minutes
    reserve = args.reserve if args.reserve is not None else max(20.0, 0.08 * 60.0 * args.minutes)
    device = torch.device("cpu" if args.cpu else "cuda")
    dev_name = "cpu" if args.cpu else torch.cuda.get_device_name(0)
    train_over = {"precision": args.precision, "seed": args.seed}
    if args.batch_size:
        train_over["batch_size"] = args.batch_size
    loader = args.loader_workers if args.loader_workers is not None else (0 if args.cpu else 4)
    overrides = {
        "data": {"max_views": None, "val_max_views": args.val_views, "num_workers": loader},
        "train": train_over,
    }
    cfg = load_config(name, cfg_path, overrides, schedule="fair")
    rig = cfg["data"].get("rig")
    log(
        f"model {name} (config {cfg_path or 'packaged'}), {args.minutes:g} minutes, device {dev_name}, torch {torch.__version__}"
    )

    work = Path(args.work) if args.work else out.parent / (out.name + "-work")
    work.mkdir(parents=True, exist_ok=True)
    union = bool(args.source or args.procedural)
    data = build_data(meshes, work / ("union.h5" if union else "cars.h5"), args, rig, log)

    step_s = probe_step(name, cfg, Path(data["path"]), device, args.precision, args.probe_steps, log)
    left = deadline - time.perf_counter() - reserve
    intervals, per = plan_steps(args, step_s, left)
    log(
        f"plan: {intervals} intervals x {per} steps = {intervals * per:,} steps "
        f"({left:.0f} s left for training at {args.overhead:g} x the step time; paper scale {PAPER_STEPS:,})"
    )
    plan = {
        "model": name,
        "config": str(cfg_path) if cfg_path else None,
        "device": dev_name,
        "torch": torch.__version__,
        "minutes": args.minutes,
        "dataset": data,
        "step_seconds": step_s,
        "batch_size": cfg["train"]["batch_size"],
        "precision": args.precision,
        "planned_steps": intervals * per,
        "intervals": intervals,
        "steps_per_interval": per,
    }
    run_dir = work / "run"
    run_over = {**overrides, "train": {**train_over, "epochs": intervals, "steps_per_epoch": per}}
    done, t_train, k, resize, slowest = 0, time.perf_counter(), 0, None, 0.0
    while k < intervals:
        t0 = time.perf_counter()
        res = train(
            name,
            data["path"],
            run_dir,
            config=cfg_path if k == 0 else None,
            overrides=run_over if k == 0 else resize,
            schedule="fair" if k == 0 else None,
            resume=k > 0,
            overwrite=k == 0,
            device=device,
            progress=False,
            log=log,
            stop_after=1,
        )
        done, k, resize = int(res["epochs"]), k + 1, None
        took = time.perf_counter() - t0
        slowest = max(slowest, took)
        if k == 1:
            plan["first_interval_seconds"] = took
            plan["interval_over_probe"] = took / (per * step_s)
        if k >= intervals:
            break
        left = deadline - reserve / 2 - time.perf_counter()
        if args.steps is not None:  # the steps asked for, exactly: stop only at the budget
            if 1.1 * took > left:
                log(f"stopping after interval {done} of {intervals}: the next ({took:.0f} s) would pass the budget")
                break
            continue
        # the probe times bare steps; an interval also loads data, validates and saves: after every interval, the
        # schedule is shortened to the intervals that fit at the slowest one so far (its cosine then still ends)
        fit = fit_intervals(intervals, done, slowest, left)
        if fit < intervals:
            log(
                f"re-plan after interval {done}: an interval takes up to {slowest:.1f} s ({slowest / (per * step_s):.2f}"
                f" x its probed steps): {fit} intervals of {per} steps fit"
                + ("; the schedule now ends there" if fit > done else "; no further interval fits")
            )
            intervals, resize = fit, {"train": {"epochs": fit}}
            plan["replanned_intervals"] = fit
    plan.update(
        {
            "intervals_done": done,
            "steps_done": done * per,
            "train_seconds": time.perf_counter() - t_train,
            "total_seconds": time.perf_counter() - t_start,
            "best": res.get("best") and str(res["best"]),
        }
    )
    files = copy_outputs(run_dir, out, args.max_file_mb, log)
    (out / "plan.json").write_text(json.dumps(plan, indent=1, default=str))
    log(f"done: {done * per:,} steps in {plan['train_seconds']:.0f} s; wrote {', '.join(files)}, plan.json to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
