"""Benchmark of the scale-out backends: Ray vs the local process pool, shards, costs.

One run, side by side (the machine may be shared: every ratio compares builds of the same
round, and rounds are repeated; the load average is recorded with each build):

1. a Ray head is started once (a separate process with ``--workers`` CPUs, its workers at
   ``--nice``); this process then lowers its own priority to ``--nice`` too, so every build's
   compute runs at the same niceness;
2. each round builds the same ``--models`` cars x ``--views`` views four times, interleaved:
   local pool with 1 worker, Ray with 1 worker, local with 2, Ray with 2 (Ray builds join the
   head, ``--workers`` caps their tasks), then a sharded Ray build (2 workers) that is merged;
3. every output is hashed: all must equal the first local build (byte-identical datasets
   local vs Ray, 1 vs 2 workers, single file vs shards);
4. per-unit costs for a projection: CPU seconds per sample and per model ground truth (one
   process, this machine), bytes per sample.

Besides wall times, every build's **CPU time** is measured: a sampler (psutil, every 0.2 s)
sums the CPU seconds of this process, its pool and the Ray head's processes (scheduler,
object store, workers). On a shared machine wall-time ratios depend on what the other users
leave free; CPU time per sample does not, and gives the overhead of Ray's machinery.

Ratios (median over rounds): ``speedup_ray = t(ray, 1) / t(ray, 2)`` (target >= 1.8),
``overhead_w = t(ray, w) / t(local, w) - 1`` (target <= 10%), for the units phase (the
distributed part) and for the whole build (Ray's connection and the HDF5 writing included).

Usage: ``python benchmarks/scaleout.py [--models 20] [--views 200] [--rounds 2] [--json docs/results/bench_scaleout.json]``
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from spotlights.data.synthetic import BuildConfig, build_dataset, discover_models, load_model, model_ground_truth
from spotlights.data.synthetic.consolidate import merge_shards

ROOT = Path(__file__).resolve().parents[1]
CARS = Path(os.environ.get("SPOTLIGHTS_SHARED", ROOT.parent / "shared")) / "data" / "meshes" / "apolloscape-cars"

HEAD = """
import sys, ray
ray.init(num_cpus=int(sys.argv[1]), include_dashboard=False, log_to_driver=False, logging_level="ERROR",
         object_store_memory=512 << 20)
print(ray.get_runtime_context().gcs_address, flush=True)
sys.stdin.read()  # until the benchmark closes stdin
ray.shutdown()
"""


class CpuMeter:
    """CPU seconds (user + system) used by the process trees under ``roots`` between start and stop,
    sampled every ``period`` s (processes that end are counted up to their last sample)."""

    def __init__(self, roots: list[int], period: float = 0.2):
        import psutil

        self.psutil, self.roots, self.period = psutil, roots, period
        self.base: dict = {}
        self.last: dict = {}

    def _sample(self) -> dict:
        out = {}
        for r in self.roots:
            try:
                procs = [self.psutil.Process(r)]
                procs += procs[0].children(recursive=True)
            except self.psutil.Error:
                continue
            for p in procs:
                try:
                    t = p.cpu_times()
                    out[(p.pid, p.create_time())] = t.user + t.system
                except self.psutil.Error:
                    pass
        return out

    def __enter__(self):
        self.base = self._sample()
        self.last = dict(self.base)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self):
        while not self._stop.wait(self.period):
            self.last.update(self._sample())

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.last.update(self._sample())
        self.seconds = sum(v - self.base.get(k, 0.0) for k, v in self.last.items())


def sha(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def subset_folder(root: Path, n: int, dest: Path) -> list[str]:
    """Links to ``n`` meshes spread evenly over the sorted list (every category represented)."""
    entries, _ = discover_models(root)
    idx = np.linspace(0, len(entries) - 1, n).round().astype(int)
    files = [entries[i].file for i in idx]
    for f in files:
        (dest / f).parent.mkdir(parents=True, exist_ok=True)
        os.symlink(root / f, dest / f)
    return files


def unit_costs(root: Path, files: list[str], cfg: BuildConfig, views: int) -> dict:
    """CPU seconds (this process) per sample and per model ground truth, on a few cars."""
    from spotlights.data.lidar import LidarSimulator
    from spotlights.data.synthetic import save_npz_atomic, simulate_views

    entries = {e.file: e for e in discover_models(root)[0]}
    t0 = time.process_time()
    for f in files:
        load_model(root, entries[f])
    load_s = (time.process_time() - t0) / len(files)
    gt_s, view_s, n_views, part_bytes = [], 0.0, 0, 0
    for f in files[:3]:
        model = load_model(root, entries[f])
        t0 = time.process_time()
        model_ground_truth(model, cfg)
        gt_s.append(time.process_time() - t0)
        sim = LidarSimulator(model.vertices, model.faces, cfg.sensor_model)
        t0 = time.process_time()
        arrays = simulate_views(sim, model, cfg, range(views))
        view_s += time.process_time() - t0
        n_views += views
        with tempfile.TemporaryDirectory() as tmp:
            save_npz_atomic(Path(tmp) / "part.npz", arrays)
            part_bytes += (Path(tmp) / "part.npz").stat().st_size
    return {"cpu_s_per_sample": view_s / n_views, "cpu_s_per_model_ground_truth": statistics.mean(gt_s),
            "cpu_s_per_mesh_load": load_s, "part_bytes_per_sample": part_bytes / n_views,
            "measured_on": f"{min(3, len(files))} cars x {views} views, one process (loading: {len(files)} meshes)"}


def project(result: dict, meshes: int = 50_000, views: int = 2_000, cores_per_node: int = 32,
            nodes=(1, 10, 50), fs_gb_per_s: float = 1.0) -> dict:
    """A build of ``meshes`` x ``views`` from the measured per-unit costs: CPU-hours (views,
    ground truth, loading, HDF5 writing, Ray's CPU overhead), storage, and wall time on
    ``nodes`` nodes of ``cores_per_node`` cores (the work spreads over every core; the shards'
    writing over the cores too, limited by a shared filesystem of ``fs_gb_per_s``)."""
    c = result["unit_costs"]
    s = result["summary"]
    samples = meshes * views
    overhead = max(0.0, max(s["cpu_overhead_ray_vs_local"].values()))
    builds = [b for b in result["builds"] if b["backend"] == "local"]
    write_cpu_per_sample = statistics.median(b["write_s"] / b["samples"] for b in builds)
    cpu = {
        "views_h": samples * c["cpu_s_per_sample"] / 3600,
        "ground_truth_h": meshes * c["cpu_s_per_model_ground_truth"] / 3600,
        "loading_h": meshes * c["cpu_s_per_mesh_load"] / 3600,
        "writing_h": samples * write_cpu_per_sample / 3600,
    }
    cpu["ray_overhead_h"] = overhead * (cpu["views_h"] + cpu["ground_truth_h"])
    total_h = sum(cpu.values())
    data_bytes = samples * s["bytes_per_sample"]
    out = {"meshes": meshes, "views": views, "samples": samples, "cpu_hours": {**cpu, "total_h": total_h},
           "storage_gb": data_bytes / 1e9, "temporary_parts_gb": samples * c["part_bytes_per_sample"] / 1e9,
           "ray_cpu_overhead_used": overhead, "cores_per_node": cores_per_node, "wall_h": {}}
    for n in nodes:
        compute = total_h / (n * cores_per_node)
        io = 2 * data_bytes / (fs_gb_per_s * 1e9) / 3600  # parts written and read back once
        out["wall_h"][str(n)] = max(compute, io)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", type=Path, default=CARS)
    ap.add_argument("--models", type=int, default=20)
    ap.add_argument("--views", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--workers", type=int, default=2, help="the larger worker count (default 2)")
    ap.add_argument("--nice", type=int, default=15, help="niceness of every build's compute (default 15)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--from-json", type=Path, default=None, help="recompute the projection of an earlier run's JSON")
    args = ap.parse_args(argv)
    if args.from_json:
        result = json.loads(args.from_json.read_text())
        if "cpu_s_per_mesh_load" not in result.get("unit_costs", {}):  # a run of an older version of this script
            with tempfile.TemporaryDirectory() as tmp:
                files = subset_folder(args.meshes, result["models"], Path(tmp))
                cfg = BuildConfig(meshes=tmp, views=result["views"], split="0.8/0.1/0.1", seed=0)
                result["unit_costs"] = unit_costs(Path(tmp), files, cfg, min(result["views"], 200))
        result["projection"] = project(result)
        print(json.dumps(result["projection"], indent=1))
        (args.json or args.from_json).write_text(json.dumps(result, indent=1) + "\n")
        return 0
    if not args.meshes.exists():
        print(f"meshes not found: {args.meshes} (set SPOTLIGHTS_SHARED)", file=sys.stderr)
        return 2
    # token authentication stays on: the head generates (or reuses) ~/.ray/auth_token, and this
    # process, a driver joining an existing cluster, sends it when RAY_AUTH_MODE=token
    os.environ.setdefault("RAY_AUTH_MODE", "token")
    env = {**os.environ, "RAY_worker_niceness": str(args.nice)}
    head = subprocess.Popen([sys.executable, "-c", HEAD, str(args.workers)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env=env)
    address = head.stdout.readline().strip()
    if not address:
        print("the Ray head did not start", file=sys.stderr)
        return 2
    os.nice(args.nice)  # from here on every build (driver, pool workers) runs at --nice, like the Ray workers
    result = {"machine": {"cores": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version(),
                          "nice": args.nice},
              "models": args.models, "views": args.views, "rounds": args.rounds, "builds": []}
    try:
        import ray

        result["ray_version"] = ray.__version__
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            meshes = tmp / "meshes"
            files = subset_folder(args.meshes, args.models, meshes)
            cfg = BuildConfig(meshes=str(meshes), views=args.views, split="0.8/0.1/0.1", seed=0)
            ref = None
            w2 = args.workers
            for r in range(args.rounds):
                plan = [("local", 1), ("ray", 1), ("local", w2), ("ray", w2)]
                if r % 2:
                    plan = [plan[1], plan[0], plan[3], plan[2]]  # alternate who goes first
                for backend, w in plan + [("ray-shards", w2)]:
                    out = tmp / (f"{backend}-{w}-{r}" + (".json" if backend == "ray-shards" else ".h5"))
                    load = os.getloadavg()
                    t0 = time.perf_counter()
                    with CpuMeter([os.getpid(), head.pid]) as cpu:
                        rep = build_dataset(cfg, out, workers=w, progress=False, log=lambda m: None,
                                            backend="ray" if backend.startswith("ray") else "local",
                                            ray_address=address if backend.startswith("ray") else None,
                                            shard_size=args.views * 4 if backend == "ray-shards" else None)
                    wall = time.perf_counter() - t0
                    digest = sha(merge_shards(out, tmp / "merged.h5", progress=False, overwrite=True)["out"]) \
                        if backend == "ray-shards" else sha(out)
                    ref = ref or digest
                    row = {"round": r, "backend": backend, "workers": w, "wall_s": wall, "cpu_s": cpu.seconds,
                           "units_s": rep.seconds_units,
                           "write_s": rep.seconds_consolidate, "samples": rep.n_samples, "bytes": rep.file_size,
                           "identical_to_first": digest == ref, "load": list(load)}
                    result["builds"].append(row)
                    print(f"round {r} {backend:10s} workers {w}: units {rep.seconds_units:7.2f} s, total {wall:7.2f} s, "
                          f"CPU {cpu.seconds:7.2f} s, "
                          f"identical {digest == ref}, load {load[0]:.1f}", flush=True)
                    for p in tmp.glob(out.stem + "*"):
                        p.unlink()
            result["unit_costs"] = unit_costs(meshes, files, cfg, min(args.views, 200))
    finally:
        head.stdin.close()
        head.wait(timeout=60)

    def med(backend, w, key):
        return statistics.median(b[key] for b in result["builds"] if b["backend"] == backend and b["workers"] == w)

    summary = {}
    summary["cpu_s_per_1000_samples"] = {f"{b}-{w}": 1000 * med(b, w, "cpu_s") / (args.models * args.views)
                                         for b, w in (("local", 1), ("ray", 1), ("local", w2), ("ray", w2))}
    summary["cpu_overhead_ray_vs_local"] = {f"{w}_workers": med("ray", w, "cpu_s") / med("local", w, "cpu_s") - 1
                                           for w in (1, w2)}
    for key in ("units_s", "wall_s"):
        summary[key] = {
            "ray_speedup_2_vs_1": med("ray", 1, key) / med("ray", w2, key),
            "local_speedup_2_vs_1": med("local", 1, key) / med("local", w2, key),
            "ray_overhead_1_worker": med("ray", 1, key) / med("local", 1, key) - 1,
            f"ray_overhead_{w2}_workers": med("ray", w2, key) / med("local", w2, key) - 1,
        }
    summary["all_identical"] = all(b["identical_to_first"] for b in result["builds"])
    summary["bytes_per_sample"] = result["builds"][0]["bytes"] / result["builds"][0]["samples"]
    result["summary"] = summary
    result["machine"]["load_after"] = list(os.getloadavg())
    result["projection"] = project(result)
    print(json.dumps(summary, indent=1))
    print(json.dumps(result["unit_costs"], indent=1))
    print(json.dumps(result["projection"], indent=1))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
