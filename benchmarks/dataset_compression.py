"""HDF5 compression of a completion dataset's per-sample arrays: write and read CPU seconds, file size, bytes read back.

Takes the per-sample arrays of an existing dataset (``--data``: ``/samples/partial`` (S, 256, 3) float32 and the
scalar and matrix fields of ``spotlights.data.store_writer.SAMPLE_FIELDS``) and writes them again, as the dataset
writer does (same chunks: one sample per chunk of ``partial``, blocks of ``--block`` samples), with each
compression of ``CANDIDATES``, the candidates interleaved over ``--rounds`` rounds (medians of CPU seconds, one
thread); then reads every file back whole and ``--reads`` single samples at random (as training reads them) and
checks that every array reads back equal to the source, bit for bit. Writes ``--json`` (default
``docs/results/speed/compression.json``).

Usage: ``python benchmarks/dataset_compression.py --data cars.h5``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

REPO = Path(__file__).resolve().parents[1]
CANDIDATES = {
    "gzip 4 + shuffle": dict(compression="gzip", compression_opts=4, shuffle=True),
    "lzf + shuffle": dict(compression="lzf", shuffle=True),
    "lzf": dict(compression="lzf"),
    "none": {},
}


def write(path: Path, arrays: dict, comp: dict, block: int) -> None:
    with h5py.File(path, "w", libver=("earliest", "v110")) as f:
        ds = {}
        for k, a in arrays.items():
            chunks = (
                (1,) + a.shape[1:]
                if k == "partial"
                else (max(1, min(len(a), 4096 if a.ndim == 1 else 256)),) + a.shape[1:]
            )
            ds[k] = f.create_dataset(k, shape=a.shape, dtype=a.dtype, chunks=chunks, track_times=False, **comp)
        for s in range(0, len(arrays["partial"]), block):
            for k, d in ds.items():
                d[s : s + block] = arrays[k][s : s + block]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="a completion dataset (.h5) whose sample arrays are written again")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--block", type=int, default=512, help="samples written at a time (the build's blocks)")
    ap.add_argument("--reads", type=int, default=2000, help="single samples read at random per file")
    ap.add_argument("--json", default=str(REPO / "docs" / "results" / "speed" / "compression.json"))
    args = ap.parse_args()
    sys.path.insert(0, str(REPO / "src"))
    from spotlights.data.store_writer import SAMPLE_FIELDS
    from spotlights.learning.cpu import cpu_description

    with h5py.File(args.data, "r") as f:
        arrays = {"partial": f["samples/partial"][()]}
        arrays.update({k: f[f"samples/{k}"][()] for k in SAMPLE_FIELDS})
    raw_mb = sum(a.nbytes for a in arrays.values()) / 1e6
    write_cpu: dict = {k: [] for k in CANDIDATES}
    sizes, read_all, read_one, equal = {}, {}, {}, {}
    rng = np.random.default_rng(0)
    picks = np.sort(rng.choice(len(arrays["partial"]), args.reads, replace=False))
    with tempfile.TemporaryDirectory(prefix="bench-compression-") as tmp:
        for _ in range(args.rounds):
            for name, comp in CANDIDATES.items():
                path = Path(tmp) / f"{name.replace(' ', '_')}.h5"
                c0 = time.process_time()
                write(path, arrays, comp, args.block)
                write_cpu[name].append(time.process_time() - c0)
                sizes[name] = path.stat().st_size / 1e6
        for name in CANDIDATES:
            path = Path(tmp) / f"{name.replace(' ', '_')}.h5"
            with h5py.File(path, "r") as f:
                c0 = time.process_time()
                back = {k: f[k][()] for k in arrays}
                read_all[name] = time.process_time() - c0
                equal[name] = all(np.array_equal(back[k], a) and back[k].dtype == a.dtype for k, a in arrays.items())
                d = f["partial"]
                c0 = time.process_time()
                for i in picks:
                    d[int(i)]
                read_one[name] = (time.process_time() - c0) / len(picks) * 1e6
    res = {
        "command": "python benchmarks/dataset_compression.py "
        + " ".join(Path(a).name if a == args.data else a for a in sys.argv[1:]),
        "cpu": cpu_description(),
        "load_average": list(os.getloadavg()),
        "data": {"file": Path(args.data).name, "samples": int(len(arrays["partial"])), "raw_mb": raw_mb},
        "h5py": h5py.__version__,
        "candidates": {
            name: {
                "write_cpu_s": statistics.median(write_cpu[name]),
                "file_mb": sizes[name],
                "read_all_cpu_s": read_all[name],
                "read_one_sample_cpu_us": read_one[name],
                "arrays_read_back_equal": equal[name],
            }
            for name in CANDIDATES
        },
    }
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps(res["candidates"], indent=1))
    print(f"-> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
