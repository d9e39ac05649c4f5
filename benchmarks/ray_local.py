"""Benchmark of the ray-local SA-Net (``sanet-local``): evidence gathering and the training step beside ``sanet-hit``.

* ``evidence``: per-ray evidence (near-ray candidates and free-space bins) for the default's 16,384-ray
  box rig (box-128x128-ellipsoid-s1, a 4.6 x 1.9 x 1.6 m box), batch 32, K = 256 (the network's input)
  and K = 2,048 observed points: the batched torch path the model runs
  (:func:`spotlights.learning.evidence.ray_evidence` + features) and the geometry layer's numpy path
  (one scan at a time), per scan;
* ``step``: one training step (forward, loss, backward, Adam) at batch 32 of the dense hit-aware SA-Net
  (the default model's network: hidden [256, 64], 16,384 rays) and of ``sanet-local`` (the same network
  plus the evidence and the per-ray MLP), fp32 and bf16 autocast, the calls alternating, medians;
* ``compile``: ``torch.compile`` against eager, bf16, batch 32, every call on another of ``--batches`` random
  batches (boxes, sensors): the ``sanet-local`` training step, and completion latency per scan
  (``Completer.complete``: forward, evidence, decoding, split into clouds) of the default checkpoint (eager) and
  of ``sanet-local`` carrying the default's weights (eager and compiled); the first compiled call's time and the
  number of graphs dynamo traced (``unique_graphs``: constant after the first calls = no recompilation per batch).

Wall and CPU time (``time.process_time``) of every call are reported: on a shared machine the CPU time
with ``--threads 1`` is the latency on one idle core. Usage::

    nice -n 15 python benchmarks/ray_local.py --threads 1 --repeats 5 --json docs/results/ray_local.json
    nice -n 15 python benchmarks/ray_local.py --threads 1 --only compile --repeats 5 --json docs/results/ray_local.json

``--json`` keeps the sections of an existing file that this run does not measure.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np
import torch

from spotlights.geometry.boxes import unit_extents
from spotlights.geometry.evidence import EvidenceParams, carved_depths, near_ray_evidence
from spotlights.geometry.rig import RigSpec
from spotlights.learning.evidence import evidence_features, ray_evidence
from spotlights.learning.models import build_model, load_config
from spotlights.learning.rays import directions_for_extents

RIG = "box-128x128-ellipsoid-s1"
BOX = (4.6, 1.9, 1.6)
SENSOR = (2.4, 1.2, 0.35)


def scans(batch: int, k: int, seed: int = 0) -> np.ndarray:
    """(batch, k, 3) float32 points on the two faces of the box that face the sensor (unit frame)."""
    rng = np.random.default_rng(seed)
    e = unit_extents(BOX)
    p = rng.uniform(-1, 1, (batch, k, 3)) * e
    half = k // 2
    p[:, :half, 0] = e[0]
    p[:, half:, 1] = e[1]
    return p.astype(np.float32)


def timed(calls: dict, repeats: int, warmup: int = 1) -> dict:
    """{key: {"wall_s", "cpu_s"}} medians of alternating calls."""
    for fn in calls.values():
        for _ in range(warmup):
            fn()
    wall = {k: [] for k in calls}
    cpu = {k: [] for k in calls}
    for _ in range(repeats):
        for k, fn in calls.items():
            w, c = time.perf_counter(), time.process_time()
            fn()
            wall[k].append(time.perf_counter() - w)
            cpu[k].append(time.process_time() - c)
    return {k: {"wall_s": statistics.median(wall[k]), "cpu_s": statistics.median(cpu[k])} for k in calls}


def bench_evidence(batch: int, repeats: int) -> dict:
    spec = RigSpec.from_name(RIG)
    params = EvidenceParams()
    e = np.tile(unit_extents(BOX), (batch, 1))
    dirs = torch.from_numpy(directions_for_extents(spec, e))
    origins = torch.from_numpy(np.array(spec.origins, dtype=np.float32))
    sensor = torch.tensor([SENSOR] * batch)
    out = {}
    for k in (256, 2048):
        pts = torch.from_numpy(scans(batch, k))

        def torch_path(pts=pts):
            evidence_features(ray_evidence(pts, origins, dirs, sensor, spec.n_secondary, params), params)

        p0, d0, o0 = pts[0].double().numpy(), dirs[0].double().numpy(), origins.double().numpy()

        def numpy_path(p0=p0, d0=d0, o0=o0):
            near_ray_evidence(p0, o0, d0, spec.n_secondary, params)
            carved_depths(p0, o0, d0, np.array(SENSOR), params)

        res = timed({"torch_batch": torch_path, "numpy_one": numpy_path}, repeats)
        out[f"K{k}"] = {
            "torch_per_scan": {m.replace("_s", "_ms"): 1e3 * v / batch for m, v in res["torch_batch"].items()},
            "numpy_per_scan": {m.replace("_s", "_ms"): 1e3 * v for m, v in res["numpy_one"].items()},
        }
        print(
            f"evidence K={k}: torch batch {batch}: {out[f'K{k}']['torch_per_scan']}, numpy one scan: "
            f"{out[f'K{k}']['numpy_per_scan']}"
        )
    return out


def bench_step(batch: int, repeats: int) -> dict:
    spec = RigSpec.from_name(RIG)
    e = np.tile(unit_extents(BOX), (batch, 1))
    dirs = torch.from_numpy(directions_for_extents(spec, e))
    x = torch.from_numpy(scans(batch, 256))
    sensor = torch.tensor([SENSOR] * batch)
    gen = torch.Generator().manual_seed(0)
    target = torch.rand(batch, spec.n_rays, generator=gen) * (torch.rand(batch, spec.n_rays, generator=gen) < 0.35)
    batch_d = {"depths": target}
    calls = {}
    for name in ("sanet-hit", "sanet-local"):
        cfg = load_config(name, overrides={"model": {"args": {"hidden": [256, 64], "float32_head": True}}})
        torch.manual_seed(0)
        model = build_model(cfg, rig=spec).train()
        opt = torch.optim.Adam(model.parameters(), lr=1e-4)
        args = (x, dirs, sensor) if name == "sanet-local" else (x,)
        for prec in ("fp32", "bf16"):

            def step(model=model, opt=opt, args=args, prec=prec):
                with torch.autocast("cpu", dtype=torch.bfloat16, enabled=prec == "bf16"):
                    out = model(*args)
                out = {k: (v.float() if v.is_floating_point() else v) for k, v in out.items()}
                loss, _ = model.loss(out, batch_d)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()

            calls[(name, prec)] = step
    res = timed(calls, repeats)
    out = {f"{n} {p}": v for (n, p), v in res.items()}
    for prec in ("fp32", "bf16"):
        a, b = res[("sanet-hit", prec)], res[("sanet-local", prec)]
        out[f"ratio {prec}"] = {m: b[m] / a[m] for m in a}
    for k, v in out.items():
        print(f"step {k}: {v}")
    return out


def random_batches(spec: RigSpec, batch: int, count: int, k: int = 256) -> list[tuple]:
    """``count`` batches (partial (B, k, 3), extents (B, 3), directions (B, N*M, 3), sensors (B, 3)) of random car
    boxes (3.5-5.2 x 1.6-2.1 x 1.3-2.0 m) and sensors (2-4 unit radii away, one unknown per batch), float32."""
    rng = np.random.default_rng(1)
    out = []
    for i in range(count):
        e = unit_extents(rng.uniform([3.5, 1.6, 1.3], [5.2, 2.1, 2.0], (batch, 3)))
        p = scans(batch, k, seed=100 + i) / unit_extents(BOX) * e[:, None]
        az = rng.uniform(0, 2 * np.pi, batch)
        s = rng.uniform(2, 4, (batch, 1)) * np.stack([np.cos(az), np.sin(az), rng.uniform(0.05, 0.3, batch)], 1)
        s[i % batch] = np.nan
        dirs = directions_for_extents(spec, e)
        out.append(tuple(torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)) for a in (p, e, dirs, s)))
    return out


def timed_cycle(calls: dict, repeats: int, count: int, probe=None, seen: dict | None = None) -> dict:
    """As :func:`timed` for calls ``fn(i)`` that take the index of a batch: call j of every function gets batch
    ``j % count`` (the first call, j = 0, is the warm-up and is timed apart: ``first_wall_s``, ``first_cpu_s``).
    ``seen["after_first"]``: what ``probe()`` returns after the first calls."""
    first = {}
    for key, fn in calls.items():
        w, c = time.perf_counter(), time.process_time()
        fn(0)
        first[key] = {"first_wall_s": time.perf_counter() - w, "first_cpu_s": time.process_time() - c}
        print(f"compile {key}: first call {first[key]}", flush=True)
    if probe is not None and seen is not None:
        seen["after_first"] = probe()
    wall = {k: [] for k in calls}
    cpu = {k: [] for k in calls}
    for j in range(1, repeats + 1):
        for key, fn in calls.items():
            w, c = time.perf_counter(), time.process_time()
            fn(j % count)
            wall[key].append(time.perf_counter() - w)
            cpu[key].append(time.process_time() - c)
    return {k: {"wall_s": statistics.median(wall[k]), "cpu_s": statistics.median(cpu[k]), **first[k]} for k in calls}


def bench_compile(batch: int, repeats: int, count: int, backend: str = "inductor") -> dict:
    """torch.compile vs eager, bf16: the sanet-local training step and the completion latency (see the docstring)."""
    from torch._dynamo.utils import counters

    from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint
    from spotlights.learning.inference import Completer

    cpu = torch.device("cpu")
    ckpt = load_checkpoint("default")
    default = model_from_checkpoint(ckpt, cpu).eval()
    spec = default.rig  # the default's RigSpec: box-128x128-ellipsoid-s1
    data = random_batches(spec, batch, count)
    gen = torch.Generator().manual_seed(0)
    targets = [
        {
            "depths": torch.rand(batch, spec.n_rays, generator=gen)
            * (torch.rand(batch, spec.n_rays, generator=gen) < 0.35)
        }
        for _ in range(count)
    ]
    args = dict(ckpt["config"]["model"]["args"])

    def local_model():
        """sanet-local with the default's network and weights (its correction starts at zero)."""
        cfg = load_config("sanet-local", overrides={"model": {"args": args}})
        torch.manual_seed(0)
        m = build_model(cfg, rig=default.rig)
        missing, unexpected = m.load_state_dict(default.state_dict(), strict=False)
        assert not unexpected and all(n.startswith(("candidate.", "local.")) for n in missing), (missing, unexpected)
        m.threshold = default.threshold
        return m

    calls = {}
    for mode in ("eager", "compiled"):
        model = local_model().train()
        net = torch.compile(model, backend=backend) if mode == "compiled" else model
        opt = torch.optim.Adam(model.parameters(), lr=1e-6)

        def step(i, model=model, net=net, opt=opt):
            p, _, dirs, s = data[i]
            with torch.autocast("cpu", dtype=torch.bfloat16):
                out = net(p, dirs, s)
            out = {k: (v.float() if v.is_floating_point() else v) for k, v in out.items()}
            loss, _ = model.loss(out, targets[i])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()

        calls[f"step sanet-local {mode}"] = step
    local_ckpt = {**ckpt, "model_name": "sanet-local"}
    completers = {"complete default eager": Completer(default, ckpt, cpu, precision="bf16")}
    for mode in ("eager", "compiled"):
        model = local_model().eval()
        if mode == "compiled":
            model.forward = torch.compile(model.forward, backend=backend)
        completers[f"complete sanet-local {mode}"] = Completer(model, local_ckpt, cpu, precision="bf16")
    points = {}
    for key, comp in completers.items():

        def complete(i, key=key, comp=comp):
            p, e, _, s = data[i]
            points.setdefault(key, []).append(
                sum(len(c) for c in comp.complete(p.numpy(), extents=e.numpy(), sensor_origins=s.numpy()))
            )

        calls[key] = complete
    counters.clear()
    seen = {}
    res = timed_cycle(calls, repeats, count, probe=lambda: int(counters["stats"]["unique_graphs"]), seen=seen)
    out = {
        "precision": "bf16",
        "backend": backend,
        "batches": count,
        "graphs_traced_after_first_calls": seen["after_first"],
        "graphs_traced": int(counters["stats"]["unique_graphs"]),
        "dynamo_stats": {k: int(v) for k, v in counters["stats"].items()},
    }
    for key, v in res.items():
        row = dict(v)
        if key.startswith("complete"):
            row.update({f"{m}_ms_per_scan": 1e3 * v[f"{m}_s"] / batch for m in ("wall", "cpu")})
            row["points_per_scan"] = statistics.mean(points[key]) / batch
        out[key] = row
    for key, v in out.items():
        print(f"compile {key}: {v}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--only", nargs="*", default=["evidence", "step", "compile"])
    ap.add_argument("--backend", default="inductor", help="torch.compile backend (eager: a quick check of the code)")
    ap.add_argument("--batches", type=int, default=20, help="distinct random batches of the compile section")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    res = {}
    if a.json and os.path.exists(a.json):
        with open(a.json) as f:
            res = json.load(f)
    res.update({"threads": a.threads, "batch": a.batch, "repeats": a.repeats, "rig": RIG})
    if "evidence" in a.only:
        res["evidence"] = bench_evidence(a.batch, a.repeats)
    if "step" in a.only:
        res["step"] = bench_step(a.batch, a.repeats)
    if "compile" in a.only:
        res["compile"] = bench_compile(a.batch, a.repeats, a.batches, a.backend)
    if a.json:
        with open(a.json + ".tmp", "w") as f:
            json.dump(res, f, indent=1)
        os.replace(a.json + ".tmp", a.json)


if __name__ == "__main__":
    main()
