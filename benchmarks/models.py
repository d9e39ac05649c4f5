"""Benchmark of the learning side: latency, Chamfer loss paths, training-step cost, bf16 vs fp32, dense rigs.

Measured in one run, same torch thread count for everything (the machine is shared and
noisy: compare ratios measured side by side, not absolute numbers). Sections (``--only``
picks some; the JSON file keeps the sections not rerun):

* ``inference``: parameters and median inference latency of every registered model at
  batch 1 and 32 (the same code as ``spotlights bench models``);
* ``chamfer``: the Chamfer loss for a batch of 32 pairs of 2048 points, forward + backward,
  by its three paths (KD-tree indices, batched cdist + argmin, autograd through cdist);
* ``train``: one training step (forward, loss, backward, Adam) of every model at batch 32,
  the point baselines also with the code concatenated to every point (the original papers'
  form, ``MLP.materialise_concat``), round-robin, with per-epoch estimates;
* ``precision``: one training step at fp32 and at bf16 autocast (``train --precision``) for
  every model, SA-Net variants on the paper's cap rig, the box rig (2,048 rays) and the
  dense box rig (16,384 rays); the calls alternate (model by model, fp32 then bf16, every
  repeat), medians and their ratio are reported; ``--compile`` adds ``torch.compile``d
  steps beside them;
* ``dense``: what the hit-aware SA-Net's last decoder layer costs at 2,048 vs 16,384 rays:
  parameters, the layer alone and the whole network, batch 1 and 32, inference;
* ``quality`` (needs ``--data``): short training runs at fp32 and at bf16 with the same
  seed and the same number of steps (``spotlights.learning.train.train``), then the
  validation CD-L1 / accuracy / completeness of both and their relative difference;
* ``runtime``: the shipped SA-Net (``--checkpoint``, default ``paper``) completing scans at
  batch 1 and 32 with torch fp32, torch bf16 autocast and onnxruntime (``spotlights export``),
  alternating, medians, per scan (forward + decoding + split into clouds); a class-conditioned
  model (``--checkpoint classes``) gets each scan's class (its vocabulary in turn) in both runtimes.

The ``precision``, ``dense`` and ``runtime`` sections report the **CPU time** of each call
(``time.process_time``) beside its wall time: on a machine shared with other work, a
low-priority benchmark's wall time mostly measures its waiting for a core, its CPU time the
work. Run them with ``--threads 1`` there (CPU time = the latency on one idle core; with two
threads OpenMP's spin-waiting would be counted); on a quiet machine the wall times are the
latencies.

Usage::

    nice -n 15 python benchmarks/models.py --threads 2 --json docs/results/bench_models.json
    nice -n 15 python benchmarks/models.py --only precision dense --json docs/results/bench_models.json
    nice -n 15 python benchmarks/models.py --only quality --data cars.h5 --json docs/results/bench_models.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from spotlights.geometry.boxes import unit_extents
from spotlights.geometry.rig import RigSpec, make_rig
from spotlights.learning.bench import bench_markdown, bench_models, cpu_name, median_latency
from spotlights.learning.device import autocast
from spotlights.learning.losses import chamfer_distance
from spotlights.learning.models import MODEL_NAMES, build_model, load_config
from spotlights.learning.models.base import MLP
from spotlights.learning.rays import TIMING_BOX_SIZE

SECTIONS = ("inference", "chamfer", "train", "precision", "dense", "quality", "runtime")
BOX, DENSE = "box-32x64-ellipsoid-s1", "box-128x128-ellipsoid-s1"


def chamfer_timing(batch: int = 32, n: int = 2048, repeats: int = 3) -> dict:
    g = torch.Generator().manual_seed(0)
    pred0 = torch.rand(batch, n, 3, generator=g) * 2 - 1
    gt = torch.rand(batch, n, 3, generator=g) * 2 - 1
    out = {}
    for method in ("kdtree", "argmin", "cdist"):
        pred = pred0.clone().requires_grad_(True)
        value = {}

        def step(pred=pred, method=method, value=value):
            pred.grad = None
            loss = chamfer_distance(pred, gt, "l2", method)
            loss.backward()
            value["loss"] = float(loss.detach())

        t = median_latency(step, repeats=repeats, warmup=1)
        out[method] = {"seconds": t, "loss_l2": value["loss"]}
    return out


def _batch(n_rays: int, batch: int = 32) -> dict:
    """A fixed random training batch: partial (B, 256, 3), gt_points (B, 2048, 3), depths (B, n_rays) with ~35% hits."""
    g = torch.Generator().manual_seed(0)
    hits = torch.rand(batch, n_rays, generator=g) < 0.35
    return {
        "partial": (torch.rand(batch, 256, 3, generator=g) * 2 - 1) * 0.57,
        "gt_points": (torch.rand(batch, 2048, 3, generator=g) * 2 - 1) * 0.57,
        "depths": torch.where(hits, 0.1 + 0.8 * torch.rand(batch, n_rays, generator=g), torch.zeros(())),
    }


def _step_fn(model, data: dict, precision: str, net=None):
    """One training step (forward under ``precision``, float32 loss, backward, Adam) as a closure."""
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    net = model if net is None else net
    cpu = torch.device("cpu")

    def step():
        with autocast(precision, cpu):
            out = net(data["partial"])
        out = {k: v.float() for k, v in out.items()}
        loss, _ = model.loss(out, data, 0.5)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    return step


def _alternate(fns: dict, repeats: int, warmup: int = 1, progress=None) -> dict:
    """Median seconds of every closure, timed round-robin (every repeat runs each once, in order).

    Two clocks per call: wall time (``perf_counter``) and this process's CPU time (``process_time``,
    all its threads). On a machine shared with other work the wall time of a low-priority process
    mostly measures its waiting; its CPU time measures the work it did. With one torch thread the
    CPU time is the latency on one otherwise idle core (no OpenMP spin-waiting is counted).
    """
    for name, fn in fns.items():
        t0 = time.perf_counter()
        for _ in range(warmup):
            fn()
        if progress:
            progress(f"  warm-up {name}: {time.perf_counter() - t0:.1f} s")
    wall = {name: [] for name in fns}
    cpu = {name: [] for name in fns}
    for r in range(repeats):
        for name, fn in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
        if progress:
            progress(f"  repeat {r + 1}/{repeats} done")
    return {
        name: {
            "median_s": statistics.median(wall[name]),
            "all_s": wall[name],
            "median_cpu_s": statistics.median(cpu[name]),
            "all_cpu_s": cpu[name],
        }
        for name in fns
    }


def _variants(include_dense: bool = True) -> dict:
    """{label: (registry name, rig)}: every model, SA-Net variants on the cap, box and dense box rigs."""
    cap = make_rig(32, 64, 60.0)
    out = {}
    for name in MODEL_NAMES:
        if name.startswith("sanet"):
            out[name] = (name, cap)
            out[f"{name} box-2048"] = (name, RigSpec.from_name(BOX))
            if include_dense and name == "sanet-hit":
                out[f"{name} box-16384"] = (name, RigSpec.from_name(DENSE))
        else:
            out[name] = (name, None)
    return out


def train_step_timing(batch: int = 32, steps: int = 3) -> dict:
    """Training step of every model at batch 32 (fp32), the baselines also in the concatenating form."""
    data = _batch(2048, batch)
    fns = {}
    for name in MODEL_NAMES:
        torch.manual_seed(0)
        model = build_model(load_config(name), rig=make_rig(32, 64, 60.0)).train()
        step = _step_fn(model, data, "fp32")
        fns[name] = step
        if model.target == "points":

            def concat_step(step=step):
                MLP.materialise_concat = True
                try:
                    step()
                finally:
                    MLP.materialise_concat = False

            fns[f"{name} (concatenation)"] = concat_step
    res = _alternate(fns, steps)
    return {name: {"seconds_per_step": v["median_s"], "all_seconds": v["all_s"]} for name, v in res.items()}


def precision_timing(batch: int = 32, repeats: int = 5, compile_: bool = False, names=None, progress=None) -> dict:
    """Training step at fp32 and bf16 (and compiled, with ``compile_``) for every variant, alternating."""
    fns, meta = {}, {}
    for label, (name, rig) in _variants().items():
        if names and label not in names:
            continue
        torch.manual_seed(0)
        model = build_model(load_config(name), rig=rig).train()
        n_rays = model.rig.n_rays if model.target == "depths" else 2048
        data = _batch(n_rays, batch)
        meta[label] = {"model": name, "rig": getattr(rig, "name", None), "params": model.param_counts()["total"]}
        for prec in ("fp32", "bf16"):
            fns[(label, prec, "eager")] = _step_fn(model, data, prec)
            if compile_:
                fns[(label, prec, "compiled")] = _step_fn(model, data, prec, net=torch.compile(model))
    res = _alternate(fns, repeats, warmup=2 if compile_ else 1, progress=progress)
    out = {}
    for label, m in meta.items():
        row = dict(m)
        for mode in ("eager", "compiled"):
            if (label, "fp32", mode) not in res:
                continue
            a, b = res[(label, "fp32", mode)], res[(label, "bf16", mode)]
            row[mode] = {
                "fp32_s": a["median_cpu_s"],
                "bf16_s": b["median_cpu_s"],
                "speedup": a["median_cpu_s"] / b["median_cpu_s"],
                "fp32_wall_s": a["median_s"],
                "bf16_wall_s": b["median_s"],
                "speedup_wall": a["median_s"] / b["median_s"],
                "fp32_all_cpu_s": a["all_cpu_s"],
                "bf16_all_cpu_s": b["all_cpu_s"],
                "fp32_all_wall_s": a["all_s"],
                "bf16_all_wall_s": b["all_s"],
            }
        if "compiled" in row:
            row["compile_gain_fp32"] = row["eager"]["fp32_s"] / row["compiled"]["fp32_s"]
            row["compile_gain_bf16"] = row["eager"]["bf16_s"] / row["compiled"]["bf16_s"]
        out[label] = row
    return out


def dense_cost(repeats: int = 10) -> dict:
    """The hit-aware SA-Net's last decoder layer at 2,048 vs 16,384 rays: parameters and inference latency."""
    models, out = {}, {}
    for label, spec in (("2048", RigSpec.from_name(BOX)), ("16384", RigSpec.from_name(DENSE))):
        torch.manual_seed(0)
        m = build_model(load_config("sanet-hit"), rig=spec).eval()
        last = m.decoder.linears[-1]
        models[label] = m
        out[label] = {
            "rig": spec.name,
            "rays": spec.n_rays,
            "params_total": m.param_counts()["total"],
            "params_decoder": m.param_counts()["decoder"],
            "params_last_layer": sum(p.numel() for p in last.parameters()),
            "float16_megabytes": 2 * m.param_counts()["total"] / 1e6,
        }
    fns = {}
    g = torch.Generator().manual_seed(0)
    for b in (1, 32):
        x = (torch.rand(b, 256, 3, generator=g) * 2 - 1) * 0.57
        h = torch.rand(b, 256, generator=g)
        for label, m in models.items():
            fns[(label, b, "network")] = lambda m=m, x=x: m(x)
            fns[(label, b, "last_layer")] = lambda m=m, h=h: m.decoder.linears[-1](h)
    with torch.inference_mode():
        res = _alternate(fns, repeats, warmup=2)
    for (label, b, what), v in res.items():
        lat = out[label].setdefault("latency_ms", {}).setdefault(str(b), {})
        lat[what] = v["median_cpu_s"] * 1e3
        lat[f"{what}_wall"] = v["median_s"] * 1e3
    for b in ("1", "32"):
        for label in out:
            lat = out[label]["latency_ms"][b]
            lat["last_layer_share"] = lat["last_layer"] / lat["network"]
    return out


def quality_check(data: str, steps: dict, val_views: int = 10, seed: int = 0, progress=None) -> dict:
    """Train every model ``steps[name]`` steps at fp32 and at bf16 (same seed), then compare validation metrics."""
    from spotlights.learning.train import train

    out = {}
    with tempfile.TemporaryDirectory(prefix="bench-quality-") as tmp:
        for name, n in steps.items():
            row = {"steps": n}
            for prec in ("fp32", "bf16"):
                ov = {
                    "train": {
                        "epochs": 1,
                        "steps_per_epoch": n,
                        "precision": prec,
                        "seed": seed,
                        "lr_schedule": {"kind": "constant"},
                    },
                    "data": {"val_max_views": val_views},
                }
                t0 = time.perf_counter()
                res = train(
                    name,
                    data,
                    Path(tmp) / f"{name}-{prec}",
                    overrides=ov,
                    schedule="cpu",
                    progress=False,
                    log=lambda m: None,
                )
                h = res["history"][-1]
                row[prec] = {
                    k: h[k]
                    for k in ("train_loss", "val_loss", "val_accuracy", "val_completeness", "val_chamfer_l1", "val_n")
                    if k in h
                }
                if "val_threshold" in h:
                    row[prec]["val_threshold"] = h["val_threshold"]
                row[prec]["seconds"] = time.perf_counter() - t0
                if progress:
                    progress(
                        f"  {name} {prec}: {n} steps, val CD-L1 {h['val_chamfer_l1']:.5f} "
                        f"({row[prec]['seconds']:.0f} s)"
                    )
            for k in ("val_chamfer_l1", "val_accuracy", "val_completeness"):
                row[f"{k}_rel_diff"] = (row["bf16"][k] - row["fp32"][k]) / row["fp32"][k]
            out[name] = row
    return out


def runtime_latency(
    checkpoint: str = "paper", batches=(1, 32), repeats: int = 20, threads: int = 2, progress=None
) -> dict:
    """Per-scan completion latency of one checkpoint: torch fp32, torch bf16 autocast, onnxruntime; alternating."""
    from spotlights.learning.export import export_onnx, load_onnx_completer, parity
    from spotlights.learning.inference import load_completer

    ref = load_completer(checkpoint, device="cpu")
    # box-targeted rigs aim each scan's rays at its box: time them on a typical car's box
    ext = unit_extents(TIMING_BOX_SIZE) if getattr(ref, "needs_box", False) else None
    cpu = torch.device("cpu")
    with tempfile.TemporaryDirectory(prefix="bench-onnx-") as tmp:
        t0 = time.perf_counter()
        onx_path = export_onnx(checkpoint, Path(tmp) / "model.onnx")
        export_s = time.perf_counter() - t0
        onx = load_onnx_completer(onx_path, threads=threads)
        g = np.random.default_rng(0)
        inputs = {b: (g.normal(size=(b, 256, 3)) * 0.3).astype(np.float32) for b in batches}
        diff = parity(checkpoint, onx, inputs[max(batches)])

        def names(b):  # a class-conditioned model: each scan its class, the vocabulary in turn (both runtimes)
            return [ref.classes[i % len(ref.classes)] for i in range(b)] if ref.classes else None

        def torch_call(x, prec):
            def f():
                with autocast(prec, cpu):
                    ref.complete(x, extents=ext, classes=names(len(x)))

            return f

        fns = {}
        for b, x in inputs.items():
            fns[(b, "torch fp32")] = torch_call(x, "fp32")
            fns[(b, "torch bf16")] = torch_call(x, "bf16")
            fns[(b, "onnxruntime")] = lambda x=x: onx.complete(x, extents=ext, classes=names(len(x)))
        res = _alternate(fns, repeats, warmup=3, progress=progress)
    out = {
        "checkpoint": str(checkpoint),
        "model": ref.model_name,
        "box_size_m": list(TIMING_BOX_SIZE) if ext is not None else None,
        "export_seconds": export_s,
        "parity": diff,
        "onnxruntime": __import__("onnxruntime").__version__,
        "latency_ms_per_scan": {},
    }
    for (b, path), v in res.items():
        out["latency_ms_per_scan"].setdefault(str(b), {})[path] = v["median_cpu_s"] * 1e3 / b
        out.setdefault("wall_ms_per_scan", {}).setdefault(str(b), {})[path] = v["median_s"] * 1e3 / b
    return out


QUALITY_STEPS = {"sanet": 400, "sanet-hit": 400, "topnet": 120, "pcn": 80, "foldingnet": 50, "atlasnet": 50}
"""Steps of the short fp32-vs-bf16 runs: about 2-3 minutes of fp32 training each on a quiet 2-core machine."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--only",
        nargs="+",
        choices=SECTIONS,
        default=None,
        help="sections to run (default: all but quality unless --data is given)",
    )
    ap.add_argument("--repeats", type=int, default=10, help="timed inference runs per model and batch")
    ap.add_argument("--train-steps", type=int, default=3, help="timed training steps per model (train section)")
    ap.add_argument("--precision-repeats", type=int, default=5, help="timed steps per model and precision")
    ap.add_argument("--compile", action="store_true", help="precision section: time torch.compile'd steps too")
    ap.add_argument("--models", nargs="+", default=None, help="precision section: only these variant labels")
    ap.add_argument("--train-models", type=int, default=64, help="training models per epoch (for the estimate)")
    ap.add_argument("--views", type=int, nargs="+", default=[100, 200], help="views per model for the epoch estimate")
    ap.add_argument("--data", default=None, help="dataset for the quality section (e.g. cars.h5)")
    ap.add_argument("--quality-val-views", type=int, default=10, help="validation views per model (quality)")
    ap.add_argument(
        "--quality-seed",
        type=int,
        default=0,
        help="quality section: seed of both runs of a model (another seed tells a precision gap from run-to-run spread)",
    )
    ap.add_argument(
        "--quality-steps",
        nargs="+",
        default=None,
        metavar="MODEL=N",
        help="quality section: steps per model (default: QUALITY_STEPS); only the models named are run",
    )
    ap.add_argument("--checkpoint", default="paper", help="runtime section: checkpoint or short name (default paper)")
    ap.add_argument("--runtime-repeats", type=int, default=20, help="runtime section: timed completions per path")
    ap.add_argument("--json", default=None, help="write the numbers here (sections not rerun are kept)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    sections = args.only or [s for s in SECTIONS if s != "quality" or args.data]
    t0 = time.time()
    load0 = os.getloadavg()
    log = lambda m: print(m, flush=True)  # noqa: E731
    result = {}
    if args.json and Path(args.json).exists():
        result = json.loads(Path(args.json).read_text())
    result.setdefault("sections", {})
    machine = {"cpu": cpu_name(), "cores": os.cpu_count(), "threads": args.threads, "torch": torch.__version__}

    def done(section: str, payload: dict, t_start: float, l_start):
        l_end = os.getloadavg()
        result["sections"][section] = {
            "machine": {
                **machine,
                "load_average_1_5_15_at_start": list(l_start),
                "load_average_1_5_15_at_end": list(l_end),
                "nice": os.nice(0),
            },
            "wall_seconds": time.time() - t_start,
            "date": time.strftime("%Y-%m-%d %H:%M"),
            **payload,
        }
        log(
            f"[{section}] load average {l_start[0]:.1f} at start, {l_end[0]:.1f} at end ({os.cpu_count()} cores), "
            f"{time.time() - t_start:.0f} s"
        )

    if "inference" in sections:
        ts, ls = time.time(), os.getloadavg()
        inf = bench_models(batches=(1, 32), repeats=args.repeats, warmup=2, threads=args.threads, progress=log)
        print(bench_markdown(inf))
        done("inference", {"inference": inf}, ts, ls)
    if "chamfer" in sections:
        ts, ls = time.time(), os.getloadavg()
        ch = chamfer_timing()
        print("Chamfer loss, batch 32 x 2048 vs 2048 points, forward + backward:")
        for k, v in ch.items():
            print(f"  {k:7s} {v['seconds'] * 1e3:9.1f} ms   loss {v['loss_l2']:.8f}")
        done("chamfer", {"chamfer_batch32_2048": ch}, ts, ls)
    if "train" in sections:
        ts, ls = time.time(), os.getloadavg()
        tr = train_step_timing(steps=args.train_steps)
        print("Training step at batch 32 (forward, loss, backward, Adam) and epoch estimates:")
        for name, v in tr.items():
            s = v["seconds_per_step"]
            est = {vw: s * args.train_models * vw / 32 / 60 for vw in args.views}
            v["epoch_minutes"] = {str(k): m for k, m in est.items()}
            print(
                f"  {name:24s} {s * 1e3:8.0f} ms/step  "
                + "  ".join(f"{args.train_models}x{vw} views: {m:6.1f} min/epoch" for vw, m in est.items())
            )
        ratios = {
            n: tr[f"{n} (concatenation)"]["seconds_per_step"] / tr[n]["seconds_per_step"]
            for n in MODEL_NAMES
            if f"{n} (concatenation)" in tr
        }
        print(
            "Training step, concatenated code / broadcast code (same run): "
            + ", ".join(f"{n} {r:.2f}x" for n, r in ratios.items())
        )
        done(
            "train",
            {"train_step_batch32": tr, "train_step_concat_over_broadcast": ratios, "train_models": args.train_models},
            ts,
            ls,
        )
    if "precision" in sections:
        ts, ls = time.time(), os.getloadavg()
        log("Training step at batch 32, fp32 vs bf16 autocast, alternating:")
        pr = precision_timing(repeats=args.precision_repeats, compile_=args.compile, names=args.models, progress=log)
        for label, r in pr.items():
            e = r["eager"]
            line = (
                f"  {label:24s} fp32 {e['fp32_s'] * 1e3:8.0f} ms  bf16 {e['bf16_s'] * 1e3:8.0f} ms  {e['speedup']:.2f}x"
            )
            if "compiled" in r:
                c = r["compiled"]
                line += (
                    f" | compiled fp32 {c['fp32_s'] * 1e3:8.0f} ms ({r['compile_gain_fp32']:.2f}x), "
                    f"bf16 {c['bf16_s'] * 1e3:8.0f} ms ({r['compile_gain_bf16']:.2f}x)"
                )
            print(line)
        done("precision", {"train_step_fp32_vs_bf16": pr, "compile": bool(args.compile)}, ts, ls)
    if "dense" in sections:
        ts, ls = time.time(), os.getloadavg()
        dc = dense_cost(args.repeats)
        for label, r in dc.items():
            lat = r["latency_ms"]
            print(
                f"  sanet-hit {label} rays: {r['params_total']:,} parameters (last layer {r['params_last_layer']:,}); "
                + "; ".join(
                    f"b{b}: network {lat[b]['network']:.2f} ms, last layer {lat[b]['last_layer']:.3f} ms "
                    f"({100 * lat[b]['last_layer_share']:.0f}%)"
                    for b in ("1", "32")
                )
            )
        done("dense", {"sanet_hit_last_layer": dc}, ts, ls)
    if "quality" in sections:
        if not args.data:
            ap.error("the quality section needs --data DATASET.h5")
        ts, ls = time.time(), os.getloadavg()
        log("Short training runs, fp32 vs bf16, same seed and steps:")
        steps = QUALITY_STEPS
        if args.quality_steps:
            steps = {k: int(v) for k, v in (item.split("=", 1) for item in args.quality_steps)}
        q = quality_check(args.data, steps, args.quality_val_views, seed=args.quality_seed, progress=log)
        for name, r in q.items():
            print(
                f"  {name:12s} {r['steps']:4d} steps: val CD-L1 fp32 {r['fp32']['val_chamfer_l1']:.5f}, "
                f"bf16 {r['bf16']['val_chamfer_l1']:.5f} ({100 * r['val_chamfer_l1_rel_diff']:+.1f}%)"
            )
        done(
            "quality",
            {
                "data": str(args.data),
                "val_views_per_model": args.quality_val_views,
                "seed": args.quality_seed,
                "fp32_vs_bf16": q,
            },
            ts,
            ls,
        )
    if "runtime" in sections:
        ts, ls = time.time(), os.getloadavg()
        log(f"Completion latency per scan, {args.checkpoint}: torch fp32, torch bf16, onnxruntime, alternating:")
        rt = runtime_latency(args.checkpoint, repeats=args.runtime_repeats, threads=args.threads, progress=log)
        for b, v in rt["latency_ms_per_scan"].items():
            print(f"  batch {b:>2}: " + ", ".join(f"{k} {ms:.2f} ms" for k, ms in v.items()))
        print("  parity: " + ", ".join(f"{k} {v:.1e}" for k, v in rt["parity"].items()))
        done("runtime", {"runtime": rt}, ts, ls)
    if args.json:
        from spotlights.outputs import atomic_output

        with atomic_output(args.json) as tmp:
            tmp.write_text(json.dumps(result, indent=2))
        print(f"-> {args.json}")
    print(
        f"load average {load0[0]:.1f} at start, {os.getloadavg()[0]:.1f} at end ({os.cpu_count()} cores), "
        f"{time.time() - t0:.0f} s"
    )


if __name__ == "__main__":
    main()
