"""Same numbers out: run the same fixed-seed jobs at two commits and compare their outputs.

    python benchmarks/same_outputs.py --ref cbb37db --out same_outputs.json   # HEAD's working tree vs cbb37db

Each side runs in a detached git worktree (the current working tree for ``--new`` = ``WORKTREE``,
the default) with ``PYTHONPATH`` pointing at its ``src``; the jobs:

1. ``dataset build`` of the 79 ApolloScape cars, 3 views each, seed 0, two workers: the file's
   bytes, and a digest of every HDF5 dataset's values and attributes (build times excluded);
2. a two-epoch ``train`` of ``sanet-hit`` on it (3 steps per epoch, batch 4, one thread, fp32):
   the validation columns of ``log.csv`` and the weights of ``best.pt``;
3. ``reproduce --quick`` (Tables 1-5, tiny): ``results.json`` without wall times;
4. ``complete`` of KITTI frame 002155 from its labels: the output PLY's bytes and the summary JSON
   without times.

Writes ``{job: {"old": digest, "new": digest, "same": bool}}`` to ``--out`` and prints a table.
Timing-like keys (``seconds``, ``time``, ``minutes``, ``fps``, ``latency``, ``*_ms``, ``*_s``, ``date``,
``version``, ``commit``), timing rows of the tables, the tables' rendered text and checks (they print the
timings) and reproduce's step bookkeeping (file times) are left out of the JSON digests: they differ from
run to run by nature. A self-check (``--ref X --new X``) must say "same" everywhere.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("SPOTLIGHTS_SHARED", REPO.parent / "shared")) / "data"
KITTI = SHARED / "lidar" / "kitti-object" / "training-fov-cropped"
VOLATILE = re.compile(
    r"second|time|minute|fps|latency|runtime|_ms$|_s$|date|version|commit|host|elapsed|wall|^steps$", re.I
)


def _strip(obj):
    """The JSON value without timing-like keys (recursively): keys matching :data:`VOLATILE`, table
    rows of a timing column, and the text of tables (it prints the timings too)."""
    if isinstance(obj, dict):
        if VOLATILE.search(str(obj.get("column", ""))):
            return None
        return {k: _strip(v) for k, v in obj.items() if not VOLATILE.search(str(k)) and k not in ("markdown", "checks")}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    return obj


def _json_digest(path: Path) -> str:
    return hashlib.sha256(json.dumps(_strip(json.loads(path.read_text())), sort_keys=True).encode()).hexdigest()[:16]


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def _h5_digest(path: Path) -> str:
    import h5py
    import numpy as np

    h = hashlib.sha256()

    def visit(name, obj):
        h.update(name.encode())
        for k in sorted(obj.attrs):
            if not VOLATILE.search(k):
                h.update(k.encode() + repr(np.asarray(obj.attrs[k]).tolist()).encode())
        if isinstance(obj, h5py.Dataset):
            v = np.asarray(obj[()])
            h.update(repr(v.tolist()).encode() if v.dtype.kind == "O" else np.ascontiguousarray(v).tobytes())

    with h5py.File(path, "r") as f:
        visit("/", f)
        f.visititems(visit)
    return h.hexdigest()[:16]


def _weights_digest(path: Path) -> str:
    import torch

    ck = torch.load(path, map_location="cpu", weights_only=False)
    h = hashlib.sha256()

    def visit(prefix, obj):
        if hasattr(obj, "detach"):
            h.update(prefix.encode() + obj.detach().float().contiguous().numpy().tobytes())
        elif isinstance(obj, dict):
            for k in sorted(obj, key=str):
                if not VOLATILE.search(str(k)):
                    visit(f"{prefix}/{k}", obj[k])

    visit("", ck.get("model_state", ck.get("state_dict", ck)))
    return h.hexdigest()[:16]


def _log_digest(path: Path) -> str:
    with open(path, newline="") as f:
        rows = [{k: v for k, v in r.items() if not VOLATILE.search(k)} for r in csv.DictReader(f)]
    return hashlib.sha256(json.dumps(rows, sort_keys=True).encode()).hexdigest()[:16]


def run_side(src: Path, work: Path, quiet: bool) -> dict:
    """Run the four jobs with ``src`` first on ``PYTHONPATH``; returns ``{job: digest}``."""
    env = dict(os.environ, PYTHONPATH=str(src), OMP_NUM_THREADS="1")
    work.mkdir(parents=True, exist_ok=True)

    def cli(*args):
        cmd = [sys.executable, "-m", "spotlights", *map(str, args)]
        r = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True)
        if r.returncode != 0:
            raise SystemExit(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stderr[-2000:]}")
        if not quiet:
            print("  ok:", " ".join(map(str, args))[:120], flush=True)

    out = {}
    cli(
        "dataset",
        "build",
        "--meshes",
        SHARED / "meshes" / "apolloscape-cars",
        "--out",
        "d.h5",
        "--views",
        3,
        "--split",
        "64/8/7",
        "--seed",
        0,
        "--workers",
        2,
        "--quiet",
    )
    out["dataset build: file bytes"] = _file_digest(work / "d.h5")
    out["dataset build: HDF5 values"] = _h5_digest(work / "d.h5")
    cli(
        "train",
        "--model",
        "sanet-hit",
        "--data",
        "d.h5",
        "--out",
        "run",
        "--epochs",
        2,
        "--steps-per-epoch",
        3,
        "--batch-size",
        4,
        "--threads",
        1,
        "--precision",
        "fp32",
        "--val-max-views",
        1,
        "--seed",
        0,
        "--quiet",
    )
    out["train: log.csv (no times)"] = _log_digest(work / "run" / "log.csv")
    out["train: best.pt weights"] = _weights_digest(work / "run" / "best.pt")
    cli(
        "reproduce",
        "--quick",
        "--out",
        "rep",
        "--meshes",
        SHARED / "meshes" / "apolloscape-cars",
        "--category-meshes",
        SHARED / "meshes" / "categories",
        "--lidar",
        SHARED / "lidar",
        "--quiet",
    )
    out["reproduce --quick: results.json"] = _json_digest(work / "rep" / "results.json")
    cli(
        "complete",
        KITTI / "velodyne_reduced" / "002155.bin",
        "--boxes",
        KITTI / "label_2" / "002155.txt",
        "--calib",
        KITTI / "calib" / "002155.txt",
        "--out",
        "002155.ply",
        "--summary",
        "002155.json",
    )
    out["complete KITTI 002155: PLY bytes"] = _file_digest(work / "002155.ply")
    out["complete KITTI 002155: summary"] = _json_digest(work / "002155.json")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ref", required=True, help="the old commit")
    ap.add_argument("--new", default=None, help="the new commit (default: this working tree)")
    ap.add_argument("--out", type=Path, default=Path("same_outputs.json"))
    ap.add_argument("--keep", action="store_true", help="keep the work folders")
    ap.add_argument("--old-digests", type=Path, help="a previous report whose 'old' side was --ref: reuse it")
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="same-outputs-"))
    trees = []
    try:
        sides = {}
        if a.old_digests:
            prev = json.loads(a.old_digests.read_text())
            if prev["_refs"]["old"] != a.ref:
                raise SystemExit(f"{a.old_digests}: its old side is {prev['_refs']['old']}, not {a.ref}")
            sides["old"] = {job: r["old"] for job, r in prev.items() if not job.startswith("_")}
        for label, ref in (("old", a.ref), ("new", a.new)):
            if label in sides:
                continue
            if ref is None:
                src = REPO / "src"
            else:
                tree = tmp / f"tree-{label}"
                subprocess.run(
                    ["git", "-C", str(REPO), "worktree", "add", "--detach", str(tree), ref],
                    check=True,
                    capture_output=True,
                )
                trees.append(tree)
                src = tree / "src"
            print(f"{label}: {ref or 'working tree'}", flush=True)
            # one work folder path for both sides: outputs that name their folder stay comparable
            sides[label] = run_side(src, tmp / "work", a.quiet)
            (tmp / "work").rename(tmp / f"work-{label}")
        report = {
            job: {
                "old": sides["old"][job],
                "new": sides["new"].get(job),
                "same": sides["old"][job] == sides["new"].get(job),
            }
            for job in sides["old"]
        }
        report["_refs"] = {"old": a.ref, "new": a.new or "working tree"}
        a.out.write_text(json.dumps(report, indent=1) + "\n")
        for job, r in report.items():
            if not job.startswith("_"):
                print(f"{'same' if r['same'] else 'DIFFERENT':10s} {job}")
        return 0 if all(r["same"] for j, r in report.items() if not j.startswith("_")) else 1
    finally:
        for tree in trees:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)], capture_output=True)
        if not a.keep:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    raise SystemExit(main())
