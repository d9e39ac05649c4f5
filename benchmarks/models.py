"""Benchmark of the learning side (issue 5): model latency, Chamfer loss paths, training-step cost.

Measured in one run, same torch thread count for everything (the machine is
shared and noisy: compare ratios, not absolute numbers):

* ``bench_models``: parameters (encoder / decoder) and median inference latency of
  the five models at batch 1 and 32 (the same code as ``spotlights bench models``);
* the Chamfer loss for a batch of 32 pairs of 2048 points, forward + backward:
  KD-tree indices + gather (the CPU path), batched ``cdist`` + ``argmin`` indices
  (the GPU path), and autograd through ``torch.cdist`` + ``amin`` (the reference);
* one training step (forward, loss, backward, Adam) of every model at batch 32,
  median over a few steps, from which the per-epoch time of a CPU schedule is
  estimated (``--train-models`` models x ``--views`` views per epoch); the four
  baselines are also timed with the code concatenated to every point as in the
  original papers (``MLP.materialise_concat``; same function) beside our broadcast
  form, round-robin in the same run.

Usage: ``python benchmarks/models.py [--threads 2] [--json docs/results/bench_models.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import torch

from spotlights.geometry.rig import make_rig
from spotlights.learning.bench import bench_markdown, bench_models, cpu_name, median_latency
from spotlights.learning.losses import chamfer_distance
from spotlights.learning.models import MODEL_NAMES, build_model, load_config


def chamfer_timing(batch: int = 32, n: int = 2048, repeats: int = 3) -> dict:
    g = torch.Generator().manual_seed(0)
    pred0 = torch.rand(batch, n, 3, generator=g) * 2 - 1
    gt = torch.rand(batch, n, 3, generator=g) * 2 - 1
    out = {}
    for method in ("kdtree", "argmin", "cdist"):
        pred = pred0.clone().requires_grad_(True)
        value = {}

        def step():
            pred.grad = None
            loss = chamfer_distance(pred, gt, "l2", method)
            loss.backward()
            value["loss"] = float(loss.detach())

        t = median_latency(step, repeats=repeats, warmup=1)
        out[method] = {"seconds": t, "loss_l2": value["loss"]}
    return out


def train_step_timing(batch: int = 32, steps: int = 3) -> dict:
    rig = make_rig(32, 64, 60.0)
    g = torch.Generator().manual_seed(0)
    data = {
        "partial": (torch.rand(batch, 256, 3, generator=g) * 2 - 1) * 0.57,
        "gt_points": (torch.rand(batch, 2048, 3, generator=g) * 2 - 1) * 0.57,
        "depths": torch.rand(batch, rig.n_rays, generator=g) * 0.6,
    }
    from spotlights.learning.models.base import MLP

    steps_fn = {}
    for name in MODEL_NAMES:
        torch.manual_seed(0)
        model = build_model(load_config(name), rig=rig).train()
        opt = torch.optim.Adam(model.parameters(), lr=1e-4)

        def step(model=model, opt=opt):
            res = model(data["partial"])
            loss, _ = model.loss(res, data, 0.5)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()

        steps_fn[name] = step
        step()  # warm-up
        if name != "sanet":
            def concat_step(step=step):
                MLP.materialise_concat = True
                try:
                    step()
                finally:
                    MLP.materialise_concat = False

            steps_fn[f"{name} (concatenation)"] = concat_step
            concat_step()  # warm-up
    times = {name: [] for name in steps_fn}
    for _ in range(steps):  # round-robin, as in bench_models
        for name, fn in steps_fn.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {name: {"seconds_per_step": statistics.median(t), "all_seconds": t} for name, t in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=10, help="timed inference runs per model and batch")
    ap.add_argument("--train-steps", type=int, default=3, help="timed training steps per model")
    ap.add_argument("--train-models", type=int, default=64, help="training models per epoch (for the estimate)")
    ap.add_argument("--views", type=int, nargs="+", default=[100, 200], help="views per model for the epoch estimate")
    ap.add_argument("--json", default=None, help="write all numbers here")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    t0 = time.time()
    load0 = os.getloadavg()[0]
    inf = bench_models(batches=(1, 32), repeats=args.repeats, warmup=2, threads=args.threads,
                       progress=lambda m: print(m, flush=True))
    print(bench_markdown(inf))
    ch = chamfer_timing()
    print("Chamfer loss, batch 32 x 2048 vs 2048 points, forward + backward:")
    for k, v in ch.items():
        print(f"  {k:7s} {v['seconds'] * 1e3:9.1f} ms   loss {v['loss_l2']:.8f}")
    tr = train_step_timing(steps=args.train_steps)
    print("Training step at batch 32 (forward, loss, backward, Adam) and epoch estimates:")
    for name, v in tr.items():
        s = v["seconds_per_step"]
        est = {vw: s * args.train_models * vw / 32 / 60 for vw in args.views}
        v["epoch_minutes"] = {str(k): m for k, m in est.items()}
        print(f"  {name:24s} {s * 1e3:8.0f} ms/step  " +
              "  ".join(f"{args.train_models}x{vw} views: {m:6.1f} min/epoch" for vw, m in est.items()))
    ratios = {n: tr[f"{n} (concatenation)"]["seconds_per_step"] / tr[n]["seconds_per_step"]
              for n in MODEL_NAMES if f"{n} (concatenation)" in tr}
    print("Training step, concatenated code / broadcast code (same run): "
          + ", ".join(f"{n} {r:.2f}x" for n, r in ratios.items()))
    result = {
        "machine": {"cpu": cpu_name(), "cores": os.cpu_count(), "threads": args.threads,
                    "torch": torch.__version__, "load_average_at_start": load0, "load_average_at_end": os.getloadavg()[0]},
        "inference": inf, "chamfer_batch32_2048": ch, "train_step_batch32": tr,
        "train_step_concat_over_broadcast": ratios,
        "train_models": args.train_models, "wall_seconds": time.time() - t0,
    }
    if args.json:
        from spotlights.utils import atomic_output

        with atomic_output(args.json) as tmp:
            tmp.write_text(json.dumps(result, indent=2))
        print(f"-> {args.json}")
    print(f"load average {load0:.1f} at start, {os.getloadavg()[0]:.1f} at end ({os.cpu_count()} cores)")


if __name__ == "__main__":
    main()
