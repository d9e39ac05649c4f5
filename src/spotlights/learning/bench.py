"""Parameter counts and inference latency of the five models, measured the same way.

Every model is built from its packaged config (random weights, seeded) and run on
the same random input (B, 256, 3) in the unit ball, in one process with the same
torch thread count. After ``warmup`` untimed passes each, the timed passes go
round-robin (one pass of every model per repeat), so that load changes on a shared
machine hit every model alike; the median of ``repeats`` passes is reported.

Two timings per model and batch:

* ``forward_ms``  - the network alone (SA-Net: the N*M depths),
* ``complete_ms`` - forward + turning the output into point clouds (SA-Net: rig
  decoding and the 0.2 clip, the paper's "w/ clip" row; baselines: splitting the
  (B, 2048, 3) tensor per sample).
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from .. import logs
from ..geometry.rig import make_rig
from ..options import (
    DEVICE_HELP,
    MAX_BATCH,
    batch_size_number,
    check_batch_size,
    check_threads,
    non_negative_int,
    option,
    positive_int,
)
from ..outputs import atomic_output, check_writable
from .models import DISPLAY_NAMES, MODEL_NAMES, build_model, check_model_name, load_config
from .rays import timing_directions


def cpu_name() -> str:
    """The CPU model name (from /proc/cpuinfo on Linux), else the platform's processor string."""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def time_calls(calls: dict, repeats: int = 10, warmup: int = 2, sync=None) -> dict:
    """The one latency timer: median wall time in seconds of each of several calls, timed round-robin.

    Parameters
    ----------
    calls : {key: fn} zero-argument callables.
    repeats : timed runs of each call; warmup : untimed runs of each call first.
    sync : optional callable run after every call (``torch.cuda.synchronize`` on a GPU).

    Every repeat times each call once, in order, so that a change of load on a shared machine
    hits every call alike and their ratios stay meaningful. Returns {key: median seconds}.
    """
    for fn in calls.values():
        for _ in range(max(warmup, 0)):
            fn()
    if sync:
        sync()
    times: dict = {k: [] for k in calls}
    for _ in range(max(repeats, 1)):
        for key, fn in calls.items():
            t0 = time.perf_counter()
            fn()
            if sync:
                sync()
            times[key].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def median_latency(fn, repeats: int = 10, warmup: int = 2, sync=None) -> float:
    """Median wall time of ``fn()`` in seconds over ``repeats`` runs after ``warmup`` untimed runs (:func:`time_calls`)."""
    return time_calls({0: fn}, repeats, warmup, sync)[0]


def timing_inputs(batches: Sequence[int], n_input: int = 256, seed: int = 0, device=None) -> dict:
    """{batch: (batch, n_input, 3) float32 tensor on ``device``}: points uniform in [-0.57, 0.57]^3 (the unit
    frame; the cube inside the unit ball), from one generator seeded with ``seed``, drawn in batch order."""
    import torch

    gen = torch.Generator().manual_seed(seed)
    return {b: (torch.rand(b, n_input, 3, generator=gen) * 2 - 1).mul(0.57).to(device) for b in batches}


TIMING_SENSOR = (2.4, 1.2, 0.35)
"""The LiDAR (unit frame, front left and a little above the box) with which models that read free space are timed."""


def _model_calls(model, x, device) -> dict:
    """{"forward": fn, "complete": fn} for one model and input batch (box-rig SA-Nets get one box's rays)."""
    from .models.base import CLIP_DEFAULT

    dirs = timing_directions(model, x.shape[0])  # None, or the rays of one box for box-rig SA-Nets
    dirs = None if dirs is None else dirs.to(device)
    if getattr(model, "uses_evidence", False):  # the ray-local SA-Net also reads the scan along its rays
        sensor = x.new_tensor(TIMING_SENSOR).expand(x.shape[0], 3)
        return {
            "forward": (lambda: model(x, dirs, sensor)),
            "complete": (lambda: model.complete(x, CLIP_DEFAULT, dirs, sensor)),
        }
    return {
        "forward": (lambda: model(x)),
        "complete": (
            lambda: model.complete(x, CLIP_DEFAULT) if dirs is None else model.complete(x, CLIP_DEFAULT, dirs)
        ),
    }


def model_latency(
    model,
    device,
    batches: Sequence[int] = (1, 32),
    repeats: int = 10,
    warmup: int = 2,
    n_input: int = 256,
    seed: int = 0,
) -> dict:
    """Median latency of one model (the ``latency_ms`` of ``spotlights evaluate``), timed as :func:`bench_models` does.

    Returns {batch: {"forward_ms", "complete_ms"}} in milliseconds: the network alone, and
    forward + turning the output into point clouds (SA-Net: decoding and the 0.2 clip).
    """
    import torch

    sync = torch.cuda.synchronize if torch.device(device).type == "cuda" else None
    inputs = timing_inputs(batches, n_input, seed, device)
    out = {}
    with torch.inference_mode():
        for b in batches:
            med = time_calls(_model_calls(model, inputs[b], device), repeats, warmup, sync)
            out[int(b)] = {"forward_ms": med["forward"] * 1e3, "complete_ms": med["complete"] * 1e3}
    return out


def count_macs(model, n_input: int = 256) -> int:
    """Multiply-accumulates of one forward pass for one sample, as executed.

    Counted with ``torch.utils.flop_counter.FlopCounterMode`` on the matrix products
    actually run (a linear layer on R rows costs ``R * in_features * out_features``; a
    per-shape code broadcast over K points by ``MLP.forward_concat`` is counted once, not
    K times). Biases, activations, normalisation and max-pooling are not counted: they
    are a few percent. The sample is ``n_input`` distinct points (:func:`timing_inputs`): at inference the
    encoder runs on a shape's distinct points only, so a sample of repeated points would count fewer.
    """
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    sample = timing_inputs([1], n_input, device=next(model.parameters()).device)[1]
    with torch.inference_mode(), FlopCounterMode(display=False) as counter:
        model(sample)
    return int(counter.get_total_flops()) // 2


def bench_models(
    names: Sequence[str] = MODEL_NAMES,
    batches: Sequence[int] = (1, 32),
    repeats: int = 10,
    warmup: int = 2,
    threads: int | None = None,
    device=None,
    rig=None,
    seed: int = 0,
    n_input: int = 256,
    progress=None,
) -> dict:
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
    import torch

    from .device import resolve_device

    batches = [check_batch_size(b, "batch") for b in batches]
    if threads:
        torch.set_num_threads(check_threads(threads))
    dev = resolve_device(device)
    sync = torch.cuda.synchronize if dev.type == "cuda" else None
    rig = rig or make_rig(32, 64, 60.0)
    inputs = timing_inputs(batches, n_input, seed, dev)
    models = {}
    for name in names:
        check_model_name(name)
        torch.manual_seed(seed)
        models[name] = build_model(load_config(name), rig=rig).to(dev).eval()
    med = _median_times(models, names, batches, (inputs, dev), (repeats, warmup, sync), progress)
    rows = _model_rows(models, batches, med, n_input)
    return {
        "device": str(dev) if dev.type == "cpu" else f"{dev} ({torch.cuda.get_device_name(dev)})",
        "cpu": cpu_name(),
        "cpu_count": os.cpu_count(),
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "repeats": repeats,
        "warmup": warmup,
        "batches": [int(b) for b in batches],
        "rig": rig.name,
        "models": rows,
    }


def _median_times(models: dict, names, batches: list[int], inputs: tuple, timing: tuple, progress) -> dict:
    """{(model name, batch, "forward" or "complete"): median seconds} of every model (name -> module) on the inputs
    of each batch size (``inputs`` = ({batch: tensor}, device); ``timing`` = (repeats, warmup, the device's
    synchronize or None)); ``progress`` (optional callable(str)) is told each batch's times of the ``names``."""
    import torch

    tensors, dev = inputs
    repeats, warmup, sync = timing
    # Round-robin over every model and both timings (time_calls), so that a change of load on a
    # shared machine hits all models alike and the ratios stay meaningful.
    med = {}
    with torch.inference_mode():
        for b in batches:
            calls = {
                (name, kind): fn
                for name, model in models.items()
                for kind, fn in _model_calls(model, tensors[b], dev).items()
            }
            med.update({(name, b, kind): t for (name, kind), t in time_calls(calls, repeats, warmup, sync).items()})
            if progress:
                for name in names:
                    progress(
                        f"{name} batch {b}: forward {med[(name, b, 'forward')] * 1e3:.2f} ms, "
                        f"complete {med[(name, b, 'complete')] * 1e3:.2f} ms"
                    )
    return med


def _model_rows(models: dict, batches: list[int], med: dict, n_input: int) -> list[dict]:
    """:func:`bench_models`' row of each model: its parameters, multiply-accumulates per sample and latencies (ms)
    of each batch size from the median times ``med`` (:func:`_median_times`)."""
    rows = []
    for name, model in models.items():
        lat = {
            int(b): {"forward_ms": med[(name, b, "forward")] * 1e3, "complete_ms": med[(name, b, "complete")] * 1e3}
            for b in batches
        }
        rows.append(
            {
                "model": name,
                "display_name": DISPLAY_NAMES[name],
                "params": model.param_counts(),
                "macs_per_sample": count_macs(model, n_input),
                "latency_ms": lat,
            }
        )
    return rows


def bench_markdown(result: dict) -> str:
    """A Markdown table of :func:`bench_models` output (parameters in millions, latencies in ms)."""
    batches = result["batches"]
    head = ["Model", "Encoder", "Decoder", "Total", "GMAC/sample"]
    for b in batches:
        head += [f"forward b{b} (ms)", f"complete b{b} (ms)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in result["models"]:
        p = r["params"]
        cells = [
            r["display_name"],
            f"{p['encoder'] / 1e6:.3f}M",
            f"{p['decoder'] / 1e6:.3f}M",
            f"{p['total'] / 1e6:.3f}M",
            f"{r['macs_per_sample'] / 1e9:.3f}" if "macs_per_sample" in r else "n/a",
        ]
        for b in batches:
            lt = r["latency_ms"][b] if b in r["latency_ms"] else r["latency_ms"][str(b)]
            cells += [f"{lt['forward_ms']:.2f}", f"{lt['complete_ms']:.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    ratio_lines = []
    sanet = next((r for r in result["models"] if r["model"] == "sanet"), None)
    others = [r for r in result["models"] if not r["model"].startswith("sanet")]  # the baselines
    if sanet and others:
        for b in batches:
            key = b if b in sanet["latency_ms"] else str(b)
            fastest = min(others, key=lambda r: r["latency_ms"][key]["complete_ms"])
            ratio = fastest["latency_ms"][key]["complete_ms"] / sanet["latency_ms"][key]["complete_ms"]
            ratio_lines.append(
                f"batch {b}: fastest baseline {fastest['display_name']} "
                f"{fastest['latency_ms'][key]['complete_ms']:.2f} ms, SA-Net (w/ clip) "
                f"{sanet['latency_ms'][key]['complete_ms']:.2f} ms: {ratio:.1f}x faster"
            )
        if "macs_per_sample" in sanet:
            least = min(others, key=lambda r: r["macs_per_sample"])
            ratio_lines.append(
                f"compute: SA-Net {sanet['macs_per_sample'] / 1e9:.3f} GMAC/sample, the cheapest baseline "
                f"{least['display_name']} {least['macs_per_sample'] / 1e9:.3f} "
                f"({least['macs_per_sample'] / sanet['macs_per_sample']:.1f}x)"
            )
        smallest = min(others, key=lambda r: r["params"]["total"])
        ratio_lines.append(
            f"parameters: SA-Net {sanet['params']['total'] / 1e6:.3f}M = "
            f"{sanet['params']['total'] / smallest['params']['total']:.2f} x the smallest baseline "
            f"({smallest['display_name']}, {smallest['params']['total'] / 1e6:.3f}M)"
        )
    foot = (
        f"\n{result['device']} ({result.get('cpu', '?')}, {result.get('cpu_count', '?')} cores), "
        f"{result['threads']} torch threads, torch {result['torch']}, median of {result['repeats']} round-robin runs "
        f"after {result['warmup']} warm-up runs, SA-Net rig {result['rig']}.\n"
    )
    return "\n".join(lines) + "\n" + foot + "".join(f"\n- {r}" for r in ratio_lines) + ("\n" if ratio_lines else "")


@dataclass(frozen=True, kw_only=True)
class BenchSettings:
    """What ``spotlights bench models`` is asked to do: its options as one object, each field
    declaring its option (:func:`spotlights.options.option`). Latencies are milliseconds."""

    models: list = option(
        default=list(MODEL_NAMES),
        nargs="+",
        choices=MODEL_NAMES,
        metavar="MODEL",
        help=f"models to measure (default all: {', '.join(MODEL_NAMES)})",
    )
    batch: list = option(
        default=[1, 32],
        type=batch_size_number,
        nargs="+",
        metavar="B",
        help=f"batch sizes, each 1..{MAX_BATCH} (default 1 32)",
    )
    repeats: int = option(default=10, type=positive_int, help="timed runs per measurement (median reported)")
    warmup: int = option(default=2, type=non_negative_int, help="untimed warm-up runs (default 2)")
    threads: int | None = option(
        default=None, type=positive_int, help="torch threads for every model (default: torch's)"
    )
    device: str | None = option(default=None, help=DEVICE_HELP)
    json: bool = option(default=False, action="store_true", help="print JSON instead of a table")
    out: str | None = option("--out", "-o", default=None, metavar="FILE.json", help="also write the JSON result here")
    quiet: bool = option(
        "--quiet",
        "-q",
        default=False,
        action="store_true",
        help="no progress lines and no table (with --out: only the file)",
    )


def run_bench(s: BenchSettings, log: Callable[[str], None] = logs.info) -> dict:
    """``spotlights bench models``: :func:`bench_models` as ``s`` says (progress lines on stderr
    unless ``s.json`` or ``s.quiet``), the JSON result written to ``s.out`` (atomically) when
    given, then ``log`` gets the JSON (``s.json``) or the Markdown table. Returns the result."""
    import json
    import sys

    check_writable(s.out)
    res = bench_models(
        s.models,
        s.batch,
        repeats=s.repeats,
        warmup=s.warmup,
        threads=s.threads,
        device=s.device,
        progress=None if s.json or s.quiet else (lambda m: print(m, file=sys.stderr)),
    )
    text = json.dumps(res, indent=2)
    if s.out:
        with atomic_output(s.out) as tmp:
            tmp.write_text(text)
    log(text if s.json else bench_markdown(res))
    return res
