"""What ``--snap R`` costs per box: ``spotlights.geometry.evidence.snap_to_observed`` on the default's rig, side by side.

One box (a 4.6 x 1.9 x 1.6 m car) on the default model's 128 x 128 box rig (16,384 rays), 256 observed points on
its left side (a LiDAR's view of it), random predicted depths and hits; the snap at R = 0.05 with and without the
sensor origin (the occlusion rule; trees that predate it time only the first). Each tree runs in a fresh process
with one thread; the rounds alternate ``--against OTHER_SRC`` (e.g. a checkout before a change) and this
checkout's ``src``; per round the CPU time of ``--calls`` calls (``time.process_time``: on a shared machine the
work, not the wait for a core). Report: medians per tree and their ratio.

Usage::

    python benchmarks/snap_speed.py --against before/src --rounds 5 --json docs/results/fair/snap/occlusion_rule/snap_speed.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from spotlights.outputs import atomic_output

HERE = Path(__file__).resolve().parents[1]

TIMER = r"""
import inspect, json, sys, time
import numpy as np
from spotlights.geometry.boxes import unit_extents
from spotlights.geometry.evidence import snap_to_observed
from spotlights.geometry.rig import RigSpec

spec = RigSpec.from_name("box-128x128-ellipsoid-s1")
e = unit_extents([4.6, 1.9, 1.6])
rig = spec.for_box(e)
o, d = np.array(rig.origins, dtype=np.float64), np.array(rig.directions, dtype=np.float64)
rng = np.random.default_rng(0)
p = rng.uniform(-1, 1, (256, 3)) * e * [0.9, 1.0, 0.9]
p[:, 1] = 0.8 * e[1]
depth, keep = rng.uniform(0.1, 0.6, len(d)), rng.random(len(d)) < 0.9
calls = int(sys.argv[1])
out = {}
kinds = {"no sensor": {}}
if "sensor" in inspect.signature(snap_to_observed).parameters:
    kinds["sensor (occlusion rule)"] = {"sensor": np.array([0.0, 3.0, 0.5])}
for name, kw in kinds.items():
    snap_to_observed(p, o, d, spec.n_secondary, depth, keep, 0.05, **kw)  # imports, caches
    t = time.process_time()
    for _ in range(calls):
        snap_to_observed(p, o, d, spec.n_secondary, depth, keep, 0.05, **kw)
    out[name] = (time.process_time() - t) / calls * 1e3
print(json.dumps(out))
"""


def one_round(src: Path, calls: int) -> dict:
    """Milliseconds of CPU per snapped box with ``src`` first on the path, in a fresh one-thread process."""
    env = dict(os.environ, PYTHONPATH=str(src), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-c", TIMER, str(calls)], env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{src}: the timing failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", default=None, help="another tree's src folder, timed in turn with this one")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--calls", type=int, default=20, help="snapped boxes timed per round and tree")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    trees = {"this": HERE / "src"} | ({"other": Path(args.against)} if args.against else {})
    rounds: dict = {k: [] for k in trees}
    for _ in range(args.rounds):
        for name, src in trees.items():
            rounds[name].append(one_round(src, args.calls))
    medians = {
        name: {kind: statistics.median(r[kind] for r in runs) for kind in runs[0]} for name, runs in rounds.items()
    }
    report = {
        "trees": {k: str(v) for k, v in trees.items()},
        "calls": args.calls,
        "rounds": rounds,
        "median_ms_per_box": medians,
        "load": float(Path("/proc/loadavg").read_text().split()[0]) if Path("/proc/loadavg").exists() else None,
    }
    if args.against:
        report["speedup_no_sensor"] = medians["other"]["no sensor"] / medians["this"]["no sensor"]
    for name, m in medians.items():
        print(name, ", ".join(f"{k}: {v:.1f} ms a box" for k, v in m.items()))
    if args.against:
        print(f"no sensor: {report['speedup_no_sensor']:.2f}x faster than {args.against}")
    if args.json:
        with atomic_output(Path(args.json)) as tmp:
            tmp.write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
