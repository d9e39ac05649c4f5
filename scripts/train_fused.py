"""Fine-tune a hit-aware SA-Net checkpoint (default: the shipped default) on fused track windows.

Samples come from :mod:`spotlights.learning.fused`: simulated drive-past sequences of the paper split's
TRAIN cars (2 and 10 Hz, HDL-64E and HDL-32E), causal windows ``past:k`` with k uniform in 1..K, true
boxes (probability ``--p-true``) or detector-like noisy boxes (0.10 m, 2 deg, 3%; **not refined**), the
target being the mesh's depths in the box frame used. Validation: a fixed set of fused samples of the
VAL cars (hit-depth loss); ``best.pt`` is the lowest validation loss, an inference checkpoint that
``--checkpoint`` accepts (``last.pt`` adds the optimizer state for ``--resume``).

Usage::

    OMP_NUM_THREADS=1 nice -n 10 python scripts/train_fused.py --out runs/fused --minutes 55 \
        --steps 4000 --threads 1 [--resume]
"""

from __future__ import annotations

import argparse
import csv
import math
import pickle
import sys
import time
from pathlib import Path

import numpy as np
import torch

from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint, save_checkpoint
from spotlights.learning.fused import draw_batch, paper_split_meshes, simulate_pool

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "meshes" / "apolloscape-cars"
DROP = ("format", "format_version", "spotlights_version", "path")


def pools(args, out: Path):
    """The train and val pools, simulated once and cached in ``out``."""
    cache = out / "pools.pkl"
    if cache.exists():
        with open(cache, "rb") as fh:
            return pickle.load(fh)
    t0 = time.perf_counter()
    train = simulate_pool(paper_split_meshes(args.meshes, "train"), args.sequences, args.frames, seed=args.seed)
    val = simulate_pool(paper_split_meshes(args.meshes, "val"), 2, args.frames, seed=args.seed + 1)
    print(f"pools: {len(train.frames)} train / {len(val.frames)} val sequences in {time.perf_counter() - t0:.0f} s")
    tmp = cache.with_suffix(".tmp")
    with open(tmp, "wb") as fh:
        pickle.dump((train, val), fh)
    tmp.replace(cache)
    return train, val


def val_loss(model, val_batches) -> float:
    model.eval()
    tot = 0.0
    with torch.no_grad():
        for x, y in val_batches:
            loss, _ = model.loss(model(x), {"depths": y})
            tot += float(loss)
    model.train()
    return tot / len(val_batches)


def choose_threshold(model, val, max_window: int, p_true: float, seed: int, n: int = 96) -> dict:
    """The p(hit) threshold with the lowest validation CD-L1 ((accuracy + completeness) / 2, unit frame) on ``n``
    fixed fused samples of the VAL cars, the truth being the target depths decoded (every true hit), as
    ``spotlights train`` chooses it on its validation split. Returns the checkpoint's ``hit_threshold`` entry."""
    from spotlights.geometry.boxes import unit_extents
    from spotlights.geometry.distances import accuracy, completeness
    from spotlights.learning.rays import directions_for_extents

    rng = np.random.default_rng([seed, 4242])
    x, y, sz = draw_batch(val, rng, n, max_window, p_true)
    dirs = torch.from_numpy(directions_for_extents(model.rig, unit_extents(sz)))
    yt = torch.from_numpy(y)
    model.eval()
    with torch.no_grad():
        out = model(torch.from_numpy(x))
        gt_pts, gt_mask = model.decode(yt, None, dirs, keep=yt > 0)
    truth = [p[m].numpy() for p, m in zip(gt_pts, gt_mask)]
    scan = {}
    for t in model.threshold_grid:
        preds = model.outputs_to_points(out, clip=None, directions=dirs, threshold=t)
        acc = [accuracy(p.numpy(), g) if len(p) else np.nan for p, g in zip(preds, truth)]
        com = [completeness(p.numpy(), g) if len(p) else np.nan for p, g in zip(preds, truth)]
        a, c = float(np.nanmean(acc)), float(np.nanmean(com))
        scan[t] = dict(accuracy=a, completeness=c, chamfer_l1=(a + c) / 2, empty=int(np.isnan(acc).sum()))
    best = min(scan, key=lambda t: scan[t]["chamfer_l1"])
    model.train()
    return dict(value=float(best), chosen_on="val (fused samples)", criterion="chamfer_l1", scan=scan)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--init", default="default", help="checkpoint to start from (default: the shipped default)")
    ap.add_argument("--meshes", default=str(MESHES))
    ap.add_argument("--out", required=True)
    ap.add_argument("--steps", type=int, default=4000, help="cosine schedule length")
    ap.add_argument("--minutes", type=float, default=55.0, help="stop after this wall time (resume continues)")
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--lr", type=float, default=2e-4)
    ap.add_argument("--max-window", type=int, default=10)
    ap.add_argument("--p-true", type=float, default=0.3)
    ap.add_argument("--sequences", type=int, default=4, help="sequences per training car")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--val-every", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--precision", choices=("bf16", "fp32"), default="bf16")
    ap.add_argument("--resume", action="store_true")
    ap.add_argument(
        "--threshold-only", action="store_true", help="choose best.pt's p(hit) threshold on validation and stop"
    )
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    init = load_checkpoint(args.init)
    model = model_from_checkpoint(init)
    model.train()
    opt = torch.optim.Adam(model.parameters(), lr=args.lr)
    step, best, history = 0, math.inf, []
    if args.resume and (out / "last.pt").exists():
        st = torch.load(out / "last.pt", map_location="cpu", weights_only=False)
        model.load_state_dict(st["model_state"])
        opt.load_state_dict(st["optimizer"])
        step, best, history = st["global_step"], st["best_val"], st["history"]
        print(f"resumed at step {step} (best val {best:.5f})")
    train, val = pools(args, out)
    if args.threshold_only:
        return write_threshold(out, val, args)
    vrng = np.random.default_rng([args.seed, 999])
    val_batches = []
    for _ in range(4):
        x, y, _ = draw_batch(val, vrng, 32, args.max_window, args.p_true)
        val_batches.append((torch.from_numpy(x), torch.from_numpy(y)))
    sched = lambda s: 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(s, args.steps) / args.steps))  # noqa: E731
    if step == 0:
        v0 = val_loss(model, val_batches)
        history.append(dict(step=0, train_loss=float("nan"), val_loss=v0, seconds=0.0))
        print(f"step 0 val {v0:.5f}", flush=True)
    t_start = time.perf_counter()
    log = open(out / "log.csv", "a", newline="")
    w = csv.writer(log)
    run_loss, n_run = 0.0, 0
    while step < args.steps and time.perf_counter() - t_start < args.minutes * 60:
        rng = np.random.default_rng([args.seed, step])
        x, y, _ = draw_batch(train, rng, args.batch_size, args.max_window, args.p_true)
        for g in opt.param_groups:
            g["lr"] = args.lr * sched(step)
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=args.precision == "bf16"):
            outputs = model(torch.from_numpy(x))
        loss, parts = model.loss({k: v.float() for k, v in outputs.items()}, {"depths": torch.from_numpy(y)})
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        run_loss += float(loss.detach())
        n_run += 1
        if step % args.val_every == 0 or step == args.steps:
            v = val_loss(model, val_batches)
            el = time.perf_counter() - t_start
            rec = dict(step=step, train_loss=run_loss / n_run, val_loss=v, seconds=el)
            history.append(rec)
            w.writerow([step, f"{rec['train_loss']:.5f}", f"{v:.5f}", f"{el:.0f}"])
            log.flush()
            print(f"step {step} train {rec['train_loss']:.5f} val {v:.5f} ({el / 60:.1f} min)", flush=True)
            run_loss, n_run = 0.0, 0
            payload = {k: v_ for k, v_ in init.items() if k not in DROP}
            payload.update(
                model_state=model.state_dict(),
                global_step=step,
                history=history,
                finetune=dict(
                    init=str(init.get("path")),
                    data="fused past:k windows of simulated drive-past sequences (spotlights.learning.fused)",
                    max_window=args.max_window,
                    p_true=args.p_true,
                    boxes="true or noisy (0.10 m, 2 deg, 3%), not refined",
                    lr=args.lr,
                    steps=args.steps,
                    batch_size=args.batch_size,
                ),
            )
            if v < best:
                best = v
                save_checkpoint(out / "best.pt", payload)
            torch.save(
                dict(
                    model_state=model.state_dict(),
                    optimizer=opt.state_dict(),
                    global_step=step,
                    best_val=best,
                    history=history,
                ),
                out / "last.tmp",
            )
            (out / "last.tmp").replace(out / "last.pt")
    log.close()
    print(f"stopped at step {step}; best val {best:.5f}")
    return write_threshold(out, val, args)


def write_threshold(out: Path, val, args) -> int:
    """Choose ``best.pt``'s p(hit) threshold on validation and store it in the checkpoint."""
    ck = load_checkpoint(out / "best.pt")
    model = model_from_checkpoint(ck)
    chosen = choose_threshold(model, val, args.max_window, args.p_true, args.seed)
    print(f"p(hit) threshold {chosen['value']} (default's {ck['hit_threshold']['value']})", flush=True)
    ck["hit_threshold"] = chosen
    save_checkpoint(out / "best.pt", {k: v for k, v in ck.items() if k not in DROP})
    return 0


if __name__ == "__main__":
    sys.exit(main())
