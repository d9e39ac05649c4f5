"""Benchmark of the encode path: one thread against two, beside Open3D.

Measured side by side in one run (the machine is shared and noisy: compare the ratios
of one run, not absolute numbers across runs):

* ``path 1t``: the whole ``MeshProbe(mesh).encode(rig)`` call (cached float32 rig rays,
  Embree distance query, chord test, depths) on one thread;
* ``path 2t``: the same with ``MeshProbe(mesh, workers=2)``: queries of at least
  ``raycast.SPLIT_MIN_RAYS`` rays are cast by two threads over the one committed scene;
* ``bare 1t`` / ``bare 2t``: the engine call alone on the same rays and scene:
  ``scene.run(o, d, query="DISTANCE")`` on one thread, and on two threads each casting
  one half (one persistent helper thread): the yardstick of "the encode path keeps
  >= 95% of a bare engine call";
* ``split 2t`` at 2,048 and 4,096 rays: ``path 2t`` with the split forced below
  ``SPLIT_MIN_RAYS``, to show where splitting stops paying;
* Open3D's ``RaycastingScene.cast_rays`` on the same rays and mesh when Open3D is
  installed (``nthreads=0``: its own pool, both cores here; and ``nthreads=2``), and the
  encode path on the optional Open3D engine;
* ``encode_mesh_files`` on all 79 ApolloScape cars (load + encode, 32 x 64 rays at 60
  degrees) with ``workers=1`` and ``workers=2`` (threads over meshes), alternating.

Timing: every repeat runs each variant as a block of ``--block`` back-to-back calls, in an
order rotated per repeat; a variant's time is the median over all repeats of its calls after
the first of each block (the first pays waking the other core and is reported apart as
*cold*). Meshes: the ~5k-face ApolloScape sedan and a ~190k-face PartNet chair. BVH builds
are excluded (reported apart). The load average before and after is recorded.

Usage::

    PYTHONPATH=src python benchmarks/encode.py --repeat 30 --json docs/results/bench_encode.json
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import platform
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from spotlights.geometry import MeshProbe, load_mesh, make_rig, raycast
from spotlights.geometry.encode import encode_mesh_files

ROOT = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("SPOTLIGHTS_SHARED", ROOT.parent / "shared")) / "data" / "meshes"
CAR = SHARED / "apolloscape-cars" / "sedan" / "037-CAR02.ply"
BIG = SHARED / "categories" / "chair" / "partnet_chair_40096_7f539a84.ply"
RIGS = {2048: (32, 64), 4096: (64, 64), 8192: (64, 128), 32768: (128, 256)}
SIZES = (2048, 8192, 32768)


def interleaved(fns: dict, repeat: int, block: int) -> dict:
    """``{name: (warm median s, cold median s)}``: blocks of ``block`` calls, order rotated per repeat."""
    for fn in fns.values():
        fn()
    names = list(fns)
    warm = {n: [] for n in names}
    cold = {n: [] for n in names}
    for r in range(repeat):
        for n in names[r % len(names) :] + names[: r % len(names)]:
            fn = fns[n]
            for i in range(block):
                t0 = time.perf_counter()
                fn()
                dt = time.perf_counter() - t0
                (cold if i == 0 else warm)[n].append(dt)
    return {n: (statistics.median(warm[n] or cold[n]), statistics.median(cold[n])) for n in names}


def bench_mesh(path: Path, repeat: int, block: int, helper: ThreadPoolExecutor) -> list[dict]:
    mesh = load_mesh(path)
    t0 = time.perf_counter()
    probe1 = MeshProbe(mesh)
    build = time.perf_counter() - t0
    probe2 = MeshProbe(mesh, workers=2)
    scene = probe1.caster.engine._scene  # the committed Embree scene of the 1-thread probe
    o3d_scene = None
    try:
        import open3d as o3d

        o3d_scene = o3d.t.geometry.RaycastingScene()
        o3d_scene.add_triangles(
            o3d.core.Tensor(probe1.normalization.to_unit(mesh.vertices).astype(np.float32)),
            o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
        )
        probe_o3d = MeshProbe(mesh, engine="open3d", workers=2)
    except ImportError:
        pass
    rows = []
    for n_rays in (2048, 4096, 8192, 32768):
        rig = make_rig(*RIGS[n_rays], angle=60)
        o, d = rig.rays32
        h = n_rays // 2
        ref = probe1.encode(rig)
        assert probe2.encode(rig).tobytes() == ref.tobytes(), "two threads changed the bytes"

        def bare2(o=o, d=d, h=h):
            f = helper.submit(scene.run, o[h:], d[h:], query="DISTANCE")
            a = scene.run(o[:h], d[:h], query="DISTANCE")
            return a, f.result()

        def forced(rig=rig):
            keep = raycast.SPLIT_MIN_RAYS
            raycast.SPLIT_MIN_RAYS = 1
            try:
                return probe2.encode(rig)
            finally:
                raycast.SPLIT_MIN_RAYS = keep

        fns = {
            "path1": lambda rig=rig: probe1.encode(rig),
            "path2": lambda rig=rig: probe2.encode(rig),
            "bare1": lambda o=o, d=d: scene.run(o, d, query="DISTANCE"),
            "bare2": bare2,
        }
        if n_rays < raycast.SPLIT_MIN_RAYS:
            fns["split2"] = forced  # what splitting would give below the threshold
        if o3d_scene is not None and n_rays in SIZES:
            rays = o3d.core.Tensor(np.ascontiguousarray(np.hstack([o, d]), dtype=np.float32))
            fns["o3d"] = lambda rays=rays: o3d_scene.cast_rays(rays, nthreads=0)
            fns["o3d_nt2"] = lambda rays=rays: o3d_scene.cast_rays(rays, nthreads=2)
            fns["path_o3d"] = lambda rig=rig: probe_o3d.encode(rig)
        t = interleaved(fns, repeat, block)
        mr = {k: n_rays / v[0] / 1e6 for k, v in t.items()}
        row = {
            "mesh": path.name,
            "faces": int(len(mesh.faces)),
            "rays": n_rays,
            "bvh_build_s": build,
            "mrays_s": mr,
            "cold_mrays_s": {k: n_rays / v[1] / 1e6 for k, v in t.items()},
        }
        if "path2" in mr:
            row["path2_over_path1"] = mr["path2"] / mr["path1"]
            row["path1_over_bare1"] = mr["path1"] / mr["bare1"]
            row["path2_over_bare2"] = mr["path2"] / mr["bare2"]
            row["bare2_over_bare1"] = mr["bare2"] / mr["bare1"]
        if "split2" in mr:
            row["split2_over_path1"] = mr["split2"] / mr["path1"]
            row["split2_over_bare1"] = mr["split2"] / mr["bare1"]
        if "o3d" in mr:
            row["path2_over_best_open3d"] = mr["path2"] / max(mr["o3d"], mr["o3d_nt2"])
        rows.append(row)
        print(
            json.dumps(
                {
                    k: (round(v, 3) if isinstance(v, float) else v)
                    for k, v in row.items()
                    if k not in ("mrays_s", "cold_mrays_s")
                }
            ),
            file=sys.stderr,
            flush=True,
        )
    return rows


def bench_cars(repeat: int) -> dict:
    """``encode_mesh_files`` on the 79 cars with 1 and 2 workers, alternating; seconds per call."""
    files = sorted(glob.glob(str(SHARED / "apolloscape-cars" / "*" / "*.ply")))
    rig = make_rig(32, 64, 60)
    ref = encode_mesh_files(files, rig, workers=1)[rig.name]
    times = {1: [], 2: []}
    for r in range(repeat):
        for w in (1, 2) if r % 2 == 0 else (2, 1):
            t0 = time.perf_counter()
            out = encode_mesh_files(files, rig, workers=w)[rig.name]
            times[w].append(time.perf_counter() - t0)
            assert out.tobytes() == ref.tobytes()
    return {
        "meshes": len(files),
        "rig": rig.name,
        "seconds": {str(w): v for w, v in times.items()},
        "median_s": {str(w): statistics.median(v) for w, v in times.items()},
        "workers2_over_workers1": statistics.median(times[1]) / statistics.median(times[2]),
        "mean_hit_ratio": float((ref > 0).mean()),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=30, help="repeats (blocks per variant) per ray count")
    ap.add_argument("--block", type=int, default=10, help="back-to-back calls per block")
    ap.add_argument("--car-repeat", type=int, default=6, help="alternating runs of the 79-car encode per worker count")
    ap.add_argument("--json", default=str(ROOT / "docs" / "results" / "bench_encode.json"), help="where the numbers go")
    args = ap.parse_args()
    load_before = os.getloadavg()
    helper = ThreadPoolExecutor(1)
    rows = bench_mesh(CAR, args.repeat, args.block, helper)
    rows += bench_mesh(BIG, args.repeat, args.block, helper) if BIG.exists() else []
    cars = bench_cars(args.car_repeat)
    load_after = os.getloadavg()
    print(
        f"{'mesh':34s} {'faces':>7s} {'rays':>6s} {'path1':>6s} {'path2':>6s} {'2t/1t':>6s} {'bare1':>6s} "
        f"{'bare2':>6s} {'p1/b1':>6s} {'p2/b2':>6s} {'o3d':>6s} {'o3d nt2':>7s} {'2t/o3d':>6s}  (M rays/s)"
    )
    nan = float("nan")
    for r in rows:
        m = r["mrays_s"]
        print(
            f"{r['mesh']:34s} {r['faces']:7d} {r['rays']:6d} {m['path1']:6.2f} {m['path2']:6.2f} "
            f"{r['path2_over_path1']:6.2f} {m['bare1']:6.2f} {m['bare2']:6.2f} {r['path1_over_bare1']:6.2f} "
            f"{r['path2_over_bare2']:6.2f} {m.get('o3d', nan):6.2f} {m.get('o3d_nt2', nan):7.2f} "
            f"{r.get('path2_over_best_open3d', nan):6.2f}"
            + (f"  (split forced: {m['split2']:.2f} = {r['split2_over_path1']:.2f}x path1)" if "split2" in m else "")
        )
    print(
        f"79 cars, encode_mesh_files: workers=1 {cars['median_s']['1']:.3f} s, workers=2 {cars['median_s']['2']:.3f} s "
        f"({cars['workers2_over_workers1']:.2f}x), medians of {args.car_repeat} alternating runs each"
    )
    print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f}")
    out = {
        "command": "PYTHONPATH=src python benchmarks/encode.py " + " ".join(sys.argv[1:]),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "machine": platform.machine(),
        "split_min_rays": raycast.SPLIT_MIN_RAYS,
        "repeat": args.repeat,
        "block": args.block,
        "load_before": load_before,
        "load_after": load_after,
        "rays": rows,
        "cars": cars,
    }
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
