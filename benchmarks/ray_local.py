"""Benchmark of the ray-local SA-Net (``sanet-local``): evidence gathering and the training step beside ``sanet-hit``.

* ``evidence``: per-ray evidence (near-ray candidates and free-space bins) for the default's 16,384-ray
  box rig (box-128x128-ellipsoid-s1, a 4.6 x 1.9 x 1.6 m box), batch 32, K = 256 (the network's input)
  and K = 2,048 observed points: the batched torch path the model runs
  (:func:`spotlights.learning.evidence.ray_evidence` + features) and the geometry layer's numpy path
  (one scan at a time), per scan;
* ``step``: one training step (forward, loss, backward, Adam) at batch 32 of the dense hit-aware SA-Net
  (the default model's network: hidden [256, 64], 16,384 rays) and of ``sanet-local`` (the same network
  plus the evidence and the per-ray MLP), fp32 and bf16 autocast, the calls alternating, medians.

Wall and CPU time (``time.process_time``) of every call are reported: on a shared machine the CPU time
with ``--threads 1`` is the latency on one idle core. Usage::

    nice -n 15 python benchmarks/ray_local.py --threads 1 --repeats 5 --json docs/results/ray_local.json
"""

from __future__ import annotations

import argparse
import json
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
            f"evidence K={k}: torch batch {batch}: {out[f'K{k}']['torch_per_scan_ms']}, numpy one scan: "
            f"{out[f'K{k}']['numpy_per_scan_ms']}"
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--only", nargs="*", default=["evidence", "step"])
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    res = {"threads": a.threads, "batch": a.batch, "repeats": a.repeats, "rig": RIG}
    if "evidence" in a.only:
        res["evidence"] = bench_evidence(a.batch, a.repeats)
    if "step" in a.only:
        res["step"] = bench_step(a.batch, a.repeats)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
