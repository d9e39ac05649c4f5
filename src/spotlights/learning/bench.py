"""Parameter counts and inference latency of the five models, measured the same way.

For every model and batch size: build the model from its packaged config (random
weights, seeded), run ``warmup`` untimed forward passes, then ``repeats`` timed
ones, and report the median wall time. All models run in one process with the same
torch thread count, on the same random input (B, 256, 3) in the unit ball.

Two timings per model and batch:

* ``forward_ms``  - the network alone (SA-Net: the N*M depths),
* ``complete_ms`` - forward + turning the output into point clouds (SA-Net: rig
  decoding and the 0.2 clip, the paper's "w/ clip" row; baselines: splitting the
  (B, 2048, 3) tensor per sample).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Sequence

from .models import DISPLAY_NAMES, MODEL_NAMES, build_model, check_model_name, load_config


def median_latency(fn, repeats: int = 10, warmup: int = 2, sync=None) -> float:
    """Median wall time of ``fn()`` in seconds over ``repeats`` runs after ``warmup`` untimed runs."""
    for _ in range(max(warmup, 0)):
        fn()
    if sync:
        sync()
    times = []
    for _ in range(max(repeats, 1)):
        t0 = time.perf_counter()
        fn()
        if sync:
            sync()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_models(names: Sequence[str] = MODEL_NAMES, batches: Sequence[int] = (1, 32), repeats: int = 10,
                 warmup: int = 2, threads: int | None = None, device=None, rig=None, seed: int = 0,
                 n_input: int = 256, progress=None) -> dict:
    """Measure parameters and median inference latency of several models.

    Parameters
    ----------
    names : registry keys. batches : batch sizes. repeats, warmup : timed / untimed runs.
    threads : torch intra-op threads (default: leave torch's setting); reported.
    device : torch device (default CUDA when available, else CPU).
    rig : SA-Net's rig (default: the paper's 32 x 64 cap at 60 degrees).
    progress : optional callable(str) told about each measurement.

    Returns
    -------
    dict with ``device``, ``threads``, ``torch``, ``repeats``, ``warmup`` and ``models``: a
    list of {"model", "display_name", "params": {encoder, decoder, total},
    "latency_ms": {batch: {"forward_ms", "complete_ms"}}}.
    """
    import platform

    import torch

    from ..geometry.rig import make_rig
    from .models.base import CLIP_DEFAULT

    if threads:
        torch.set_num_threads(int(threads))
    dev = torch.device(device) if device is not None else torch.device("cuda" if torch.cuda.is_available() else "cpu")
    sync = torch.cuda.synchronize if dev.type == "cuda" else None
    rig = rig or make_rig(32, 64, 60.0)
    gen = torch.Generator().manual_seed(seed)
    inputs = {b: (torch.rand(b, n_input, 3, generator=gen) * 2 - 1).mul(0.57).to(dev) for b in batches}
    rows = []
    for name in names:
        check_model_name(name)
        torch.manual_seed(seed)
        model = build_model(load_config(name), rig=rig).to(dev).eval()
        lat = {}
        for b in batches:
            x = inputs[b]
            with torch.inference_mode():
                f = median_latency(lambda: model(x), repeats, warmup, sync)
                c = median_latency(lambda: model.complete(x, CLIP_DEFAULT), repeats, warmup, sync)
            lat[int(b)] = {"forward_ms": f * 1e3, "complete_ms": c * 1e3}
            if progress:
                progress(f"{name} batch {b}: forward {f * 1e3:.2f} ms, complete {c * 1e3:.2f} ms")
        rows.append({"model": name, "display_name": DISPLAY_NAMES[name], "params": model.param_counts(), "latency_ms": lat})
        del model
    return {
        "device": str(dev) if dev.type == "cpu" else f"{dev} ({torch.cuda.get_device_name(dev)})",
        "cpu": platform.processor() or platform.machine(),
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "repeats": repeats,
        "warmup": warmup,
        "batches": [int(b) for b in batches],
        "rig": rig.name,
        "models": rows,
    }


def bench_markdown(result: dict) -> str:
    """A Markdown table of :func:`bench_models` output (parameters in millions, latencies in ms)."""
    batches = result["batches"]
    head = ["Model", "Encoder", "Decoder", "Total"]
    for b in batches:
        head += [f"forward b{b} (ms)", f"complete b{b} (ms)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in result["models"]:
        p = r["params"]
        cells = [r["display_name"], f"{p['encoder'] / 1e6:.3f}M", f"{p['decoder'] / 1e6:.3f}M", f"{p['total'] / 1e6:.3f}M"]
        for b in batches:
            lt = r["latency_ms"][b] if b in r["latency_ms"] else r["latency_ms"][str(b)]
            cells += [f"{lt['forward_ms']:.2f}", f"{lt['complete_ms']:.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    ratio_lines = []
    sanet = next((r for r in result["models"] if r["model"] == "sanet"), None)
    others = [r for r in result["models"] if r["model"] != "sanet"]
    if sanet and others:
        for b in batches:
            key = b if b in sanet["latency_ms"] else str(b)
            fastest = min(others, key=lambda r: r["latency_ms"][key]["complete_ms"])
            ratio = fastest["latency_ms"][key]["complete_ms"] / sanet["latency_ms"][key]["complete_ms"]
            ratio_lines.append(f"batch {b}: fastest baseline {fastest['display_name']} "
                               f"{fastest['latency_ms'][key]['complete_ms']:.2f} ms, SA-Net (w/ clip) "
                               f"{sanet['latency_ms'][key]['complete_ms']:.2f} ms: {ratio:.1f}x faster")
        smallest = min(others, key=lambda r: r["params"]["total"])
        ratio_lines.append(f"parameters: SA-Net {sanet['params']['total'] / 1e6:.3f}M = "
                           f"{sanet['params']['total'] / smallest['params']['total']:.2f} x the smallest baseline "
                           f"({smallest['display_name']}, {smallest['params']['total'] / 1e6:.3f}M)")
    foot = (f"\n{result['device']}, {result['threads']} torch threads, torch {result['torch']}, median of "
            f"{result['repeats']} runs after {result['warmup']} warm-up runs, SA-Net rig {result['rig']}.\n")
    return "\n".join(lines) + "\n" + foot + "".join(f"\n- {r}" for r in ratio_lines) + ("\n" if ratio_lines else "")
