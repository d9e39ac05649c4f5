"""Latency of several models' ONNX exports side by side: every checkpoint exported, then completions timed
round-robin (each repeat runs every model once, in order), per batch size.

For each checkpoint (a file or a short name) and batch: the median **CPU time** per call divided by the batch,
in ms per scan, at ``--threads`` onnxruntime threads (one by default: on a shared machine the CPU time of one
thread is the latency on one otherwise idle core), and each model's ratio to the first one, measured in the
same run. Inputs: seeded random clouds of 256 points, each scan a class of the model's vocabulary in turn
(class-conditioned models), on a typical car's box for box-targeted rigs. The CPU is named in the output.

    OMP_NUM_THREADS=1 python benchmarks/onnx_latency.py --checkpoint classes runs/one-model/best.pt \\
        --labels classes one-model --json onnx_latency.json
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from models import _alternate  # noqa: E402
from spotlights.geometry.boxes import unit_extents  # noqa: E402
from spotlights.learning.cpu import cpu_description  # noqa: E402
from spotlights.learning.export import export_onnx, load_onnx_completer  # noqa: E402
from spotlights.learning.rays import TIMING_BOX_SIZE  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--checkpoint", nargs="+", required=True, help="checkpoints or short names; ratios are to the first"
    )
    ap.add_argument("--labels", nargs="+", default=None, help="a name per checkpoint (default: as given)")
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 32], help="batch sizes (1..256; default 1 32)")
    ap.add_argument("--repeats", type=int, default=20, help="timed calls per model and batch (1..1000; default 20)")
    ap.add_argument("--threads", type=int, default=1, help="onnxruntime intra-op threads (default 1)")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args()
    labels = a.labels or a.checkpoint
    if len(labels) != len(a.checkpoint):
        ap.error("--labels needs one name per --checkpoint")
    if not (all(1 <= b <= 256 for b in a.batches) and 1 <= a.repeats <= 1000 and a.threads >= 1):
        ap.error("--batches 1..256, --repeats 1..1000, --threads >= 1")
    rng = np.random.default_rng(0)
    inputs = {b: (rng.normal(size=(b, 256, 3)) * 0.3).astype(np.float32) for b in a.batches}
    with tempfile.TemporaryDirectory(prefix="onnx-latency-") as tmp:
        fns = {}
        for i, (label, ckpt) in enumerate(zip(labels, a.checkpoint)):
            onx = load_onnx_completer(export_onnx(ckpt, Path(tmp) / f"model{i}.onnx"), threads=a.threads)
            ext = unit_extents(TIMING_BOX_SIZE) if getattr(onx, "needs_box", False) else None
            vocab = list(onx.classes or [])
            for b, x in inputs.items():
                names = [vocab[j % len(vocab)] for j in range(b)] if vocab else None
                fns[(b, label)] = lambda x=x, o=onx, e=ext, n=names: o.complete(x, extents=e, classes=n)
        res = _alternate(fns, a.repeats, warmup=3)
    out = {
        "cpu": cpu_description(),
        "threads": a.threads,
        "repeats": a.repeats,
        "checkpoints": dict(zip(labels, a.checkpoint)),
    }
    out["cpu_ms_per_scan"] = {
        str(b): {label: res[(b, label)]["median_cpu_s"] * 1e3 / b for label in labels} for b in a.batches
    }
    out["ratio_to_first"] = {
        str(b): {label: v / row[labels[0]] for label, v in row.items()}
        for b, row in ((b, out["cpu_ms_per_scan"][str(b)]) for b in a.batches)
    }
    for b in a.batches:
        print(
            f"batch {b:3d}: "
            + ", ".join(
                f"{label} {out['cpu_ms_per_scan'][str(b)][label]:.2f} ms/scan ({out['ratio_to_first'][str(b)][label]:.2f}x)"
                for label in labels
            )
        )
    if a.json:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
