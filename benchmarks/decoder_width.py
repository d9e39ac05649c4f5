"""Latency of the per-viewpoint decoder against today's default decoder, side by side in one run.

Four hit-aware SA-Nets on the dense box rig (16,384 rays), untrained (latency does not depend on the
weights): today's default architecture (``sanet-hit`` + ``variants/sanet-hit-dense.yaml``, decoder
1024 -> 256 -> 64 -> 2 x 16,384), the wide one (``variants/sanet-hit-wide.yaml``: 128 codes of 64 per
viewpoint), and both class-conditioned with class templates (the ``classes.pt`` layout and
``variants/sanet-hit-wide-classes.yaml``). For each: the whole network (encoder + decoder) and the decoder
alone, at batch 32 (and 1), fp32 and bf16 autocast, calls alternating model by model every repeat; the
median **CPU time** (``time.process_time``) per call, divided by the batch: ms per scan at one thread
(on a shared machine a niced benchmark's wall time mostly measures its waiting). Inputs: 256 points per
scan (the datasets' partial size), seeded.

Usage::

    OMP_NUM_THREADS=1 nice -n 10 python benchmarks/decoder_width.py --json docs/results/models/decoder_width.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch
import yaml

from spotlights.geometry.rig import RigSpec
from spotlights.learning.cpu import cpu_description
from spotlights.learning.models import build_model, load_config

VARIANTS = Path(__file__).resolve().parents[1] / "src/spotlights/learning/configs/variants"
CLASSES = ["car", "caravan", "truck", "bus", "trailer"]


def models() -> dict:
    """{label: model} of the four architectures (eval mode, seeded)."""
    dense = yaml.safe_load((VARIANTS / "sanet-hit-dense.yaml").read_text())
    wide = yaml.safe_load((VARIANTS / "sanet-hit-wide.yaml").read_text())
    cls = {"classes": CLASSES, "class_templates": True}
    rig = RigSpec.from_name(dense["data"]["rig"])
    out = {}
    for label, over, extra in (
        ("default", dense, {}),
        ("wide", wide, {}),
        ("default-classes", dense, cls),
        ("wide-classes", wide, cls),
    ):
        cfg = load_config("sanet-hit", overrides={"model": {"args": {**over["model"]["args"], **extra}}})
        torch.manual_seed(0)
        out[label] = build_model(cfg, rig=rig).eval()
    return out


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--repeats", type=int, default=41, help="timed calls per model and setting (median kept)")
    p.add_argument("--batches", type=int, nargs="+", default=[32, 1])
    p.add_argument("--json", type=Path, default=None)
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    nets = models()
    g = torch.Generator().manual_seed(0)
    result = {
        "cpu": cpu_description(),
        "threads": a.threads,
        "torch": torch.__version__,
        "points_per_scan": 256,
        "repeats": a.repeats,
        "timer": "process_time (CPU time), median per call / batch",
        "parameters": {k: m.param_counts() for k, m in nets.items()},
        "ms_per_scan": {},
    }
    for b in a.batches:
        x = (torch.rand(b, 256, 3, generator=g) * 2 - 1) * 0.57
        cls = torch.arange(b) % len(CLASSES)
        for precision in ("fp32", "bf16"):
            times = {(k, part): [] for k in nets for part in ("network", "decoder")}
            codes = {}
            with torch.inference_mode(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision == "bf16"):
                for k, m in nets.items():  # warm-up, and each model's code for the decoder-alone timing
                    c = cls if m.classes else None
                    m(x, c)
                    codes[k] = m.encode(x, c)
                    m.decoder(codes[k])
                for _ in range(a.repeats):
                    for k, m in nets.items():
                        c = cls if m.classes else None
                        t = time.process_time()
                        m(x, c)
                        times[(k, "network")].append(time.process_time() - t)
                        t = time.process_time()
                        m.decoder(codes[k])
                        times[(k, "decoder")].append(time.process_time() - t)
            for (k, part), v in times.items():
                ms = 1000.0 * statistics.median(v) / b
                result["ms_per_scan"].setdefault(f"batch{b}", {}).setdefault(precision, {}).setdefault(k, {})[part] = (
                    round(ms, 4)
                )
            row = result["ms_per_scan"][f"batch{b}"][precision]
            for k in ("wide", "wide-classes"):
                base = "default" if k == "wide" else "default-classes"
                row[k]["network_ratio_to_default"] = round(row[k]["network"] / row[base]["network"], 3)
            print(f"batch {b} {precision}: " + ", ".join(f"{k} {v['network']:.3f} ms/scan" for k, v in row.items()))
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
