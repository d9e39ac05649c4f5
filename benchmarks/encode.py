"""Benchmark of the encode path (issue 2).

Measured side by side in one run (the machine is shared and noisy, so compare
ratios, not absolute numbers):

* the whole ``MeshProbe.encode`` path (rig rays, Embree call, chord test,
  normalisation to depths) on one process, against a bare ``embreex`` scene call
  on the same rays and the same BVH, for 2,048 / 8,192 / 32,768 rays on a ~5k-face
  car and a ~190k-face chair (PartNet) -- BVH build excluded, reported apart;
* the same path on both cores: ``MeshProbe(mesh, workers=2)`` (one forked helper
  process sharing each query, see ``spotlights.geometry.raycast``);
* Open3D's ``RaycastingScene.cast_rays`` (Embree on TBB threads) on the same rays
  and mesh, when Open3D is installed: with its default thread pool (both cores
  here) and with ``nthreads=2``;
* the encode path on the optional Open3D engine (``MeshProbe(mesh, engine="open3d",
  workers=2)``), same rays;
* encoding all 79 ApolloScape cars at 32 x 64 / 60 degrees (loading included,
  reported apart), with 1 and 2 worker processes.

Timing: each repeat runs every engine once, in an order rotated per repeat, as a
block of ``--block`` back-to-back calls after a 5 ms pause (so helper processes
and TBB worker threads have gone idle). The first call of a block is *cold* (it
pays the wake-up of the other core), the third and later ones are *warm* (a loop
of encodes); medians over all repeats are reported. A load change hits all engines alike.

Usage: ``python benchmarks/encode.py [--repeat 20] [--block 10] [--json docs/results/bench_encode.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from spotlights.geometry import MeshProbe, load_mesh, make_rig
from spotlights.geometry.encode import encode_mesh_files

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("SPOTLIGHTS_SHARED", ROOT.parent / "shared")) / "data" / "meshes"
CAR = SHARED / "apolloscape-cars" / "sedan" / "037-CAR02.ply"
BIG = SHARED / "categories" / "chair" / "partnet_chair_40096_7f539a84.ply"
RIGS = {2048: (32, 64), 8192: (64, 128), 32768: (128, 256)}


def interleaved(fns: dict, repeat: int, block: int = 10, gap: float = 0.005) -> dict:
    """Median wall time (s) of each callable: ``{name: (warm, cold)}``.

    Each repeat runs every callable as a block of ``block`` timed calls after a ``gap``
    pause, in an order rotated per repeat; *cold* is the first call of a block, *warm*
    the third and later ones (the second may still be ramping up). One untimed warm-up
    call each first.
    """
    for fn in fns.values():
        fn()
    names = list(fns)
    warm = {n: [] for n in names}
    cold = {n: [] for n in names}
    for r in range(repeat):
        for n in names[r % len(names):] + names[: r % len(names)]:
            time.sleep(gap)
            fn = fns[n]
            for i in range(block):
                t0 = time.perf_counter()
                fn()
                dt = time.perf_counter() - t0
                if i == 0:
                    cold[n].append(dt)
                elif i >= 2:
                    warm[n].append(dt)
    return {n: (statistics.median(warm[n] or cold[n]), statistics.median(cold[n])) for n in names}


def bench_mesh(path: Path, repeat: int, block: int) -> list[dict]:
    mesh = load_mesh(path)
    t0 = time.perf_counter()
    probe = MeshProbe(mesh)
    build = time.perf_counter() - t0
    scene = probe.caster._scene
    probe2 = MeshProbe(mesh, workers=2)  # each query shared with one forked helper process
    try:
        import open3d as o3d

        o3d_scene = o3d.t.geometry.RaycastingScene()
        o3d_scene.add_triangles(
            o3d.core.Tensor(probe.normalization.to_unit(mesh.vertices).astype(np.float32)),
            o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
        )
        probe_o3d = MeshProbe(mesh, engine="open3d", workers=2)  # the optional engine, both cores
    except ImportError:
        o3d_scene = None
    rows = []
    for n_rays, (n, m) in RIGS.items():
        rig = make_rig(n, m, 60)
        o32, d32 = rig.rays32
        fns = {"path": lambda: probe.encode(rig), "bare": lambda: scene.run(o32, d32, query="DISTANCE"),
               "path2": lambda: probe2.encode(rig)}
        if o3d_scene is not None:
            rays = o3d.core.Tensor(np.concatenate([o32, d32], axis=1))
            fns["open3d"] = lambda: o3d_scene.cast_rays(rays)["t_hit"].numpy()
            fns["open3d_nt2"] = lambda: o3d_scene.cast_rays(rays, nthreads=2)["t_hit"].numpy()
            fns["path_o3d"] = lambda: probe_o3d.encode(rig)
        t = interleaved(fns, repeat, block)
        assert probe2.encode(rig).tobytes() == probe.encode(rig).tobytes()
        mr = {k: n_rays / v[0] / 1e6 for k, v in t.items()}
        mr_cold = {k: n_rays / v[1] / 1e6 for k, v in t.items()}
        row = {
            "mesh": path.name, "faces": int(len(mesh.faces)), "rays": n_rays, "bvh_build_s": build,
            "encode_path_mrays_s": mr["path"], "bare_embree_mrays_s": mr["bare"],
            "path_over_bare": mr["path"] / mr["bare"],
            "encode_path_2proc_mrays_s": mr["path2"], "path2_over_path": mr["path2"] / mr["path"],
            "cold": {k: v for k, v in mr_cold.items()},
        }
        if o3d_scene is not None:
            best = max(mr["open3d"], mr["open3d_nt2"])
            row.update({"open3d_mrays_s": mr["open3d"], "open3d_nthreads2_mrays_s": mr["open3d_nt2"],
                        "encode_path_open3d_engine_mrays_s": mr["path_o3d"],
                        "path_over_open3d": mr["path"] / best, "path2_over_open3d": mr["path2"] / best,
                        "path2_over_open3d_cold": mr_cold["path2"] / max(mr_cold["open3d"], mr_cold["open3d_nt2"])})
        rows.append(row)
    probe2.close()
    return rows


def bench_cars(workers: int) -> dict:
    files = sorted((SHARED / "apolloscape-cars").glob("*/*.ply"))
    rig = make_rig(32, 64, 60)
    t0 = time.perf_counter()
    meshes = [load_mesh(f) for f in files]
    t_load = time.perf_counter() - t0
    from spotlights.geometry import encode_meshes

    t0 = time.perf_counter()
    encode_meshes(meshes, rig)
    t_encode = time.perf_counter() - t0
    t0 = time.perf_counter()
    depths = encode_mesh_files(files, [rig], workers=workers)
    t_files = time.perf_counter() - t0
    return {"meshes": len(files), "workers": workers, "load_s": t_load, "encode_loaded_s": t_encode,
            "load_and_encode_files_s": t_files, "mean_hit_ratio": float((depths[rig.name] > 0).mean())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--block", type=int, default=10, help="back-to-back calls per engine and repeat")
    ap.add_argument("--json", default=str(ROOT / "docs" / "results" / "bench_encode.json"))
    args = ap.parse_args()
    load = os.getloadavg()  # the 1-, 5- and 15-minute load averages before the run
    if not CAR.exists():
        print(f"shared data not found under {SHARED}; set SPOTLIGHTS_SHARED", file=sys.stderr)
        return 2
    rows = bench_mesh(CAR, args.repeat, args.block)
    rows += bench_mesh(BIG, args.repeat, args.block) if BIG.exists() else []
    print("million rays/s, warm (cold: first call after 5 ms idle)")
    print(f"{'mesh':34s} {'faces':>7s} {'rays':>6s} {'path':>5s} {'bare':>5s} {'p/bare':>6s} "
          f"{'2proc':>5s} {'o3d':>5s} {'o3d nt2':>7s} {'2proc/o3d':>9s}  cold: {'path':>5s} {'2proc':>5s} {'o3d':>5s}")
    nan = float("nan")
    for r in rows:
        c = r["cold"]
        print(f"{r['mesh']:34s} {r['faces']:7d} {r['rays']:6d} {r['encode_path_mrays_s']:5.2f} "
              f"{r['bare_embree_mrays_s']:5.2f} {r['path_over_bare']:6.2f} {r['encode_path_2proc_mrays_s']:5.2f} "
              f"{r.get('open3d_mrays_s', nan):5.2f} {r.get('open3d_nthreads2_mrays_s', nan):7.2f} "
              f"{r.get('path2_over_open3d', nan):9.2f}        {c['path']:5.2f} {c['path2']:5.2f} {c.get('open3d', nan):5.2f}")
    cars = [bench_cars(w) for w in (1, 2)]
    for c in cars:
        print(f"79 cars, 32x64/60deg, workers={c['workers']}: load {c['load_s']:.2f} s, encode (loaded) "
              f"{c['encode_loaded_s']:.2f} s, load+encode from files {c['load_and_encode_files_s']:.2f} s")
    out = {"python": platform.python_version(), "cpus": os.cpu_count(), "machine": platform.machine(),
           "repeat": args.repeat, "block": args.block, "load_before": load, "rays": rows,
           "cars": cars}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2))
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
