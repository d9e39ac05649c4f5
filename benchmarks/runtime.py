"""What one frame and one scan cost, runtime by runtime, and what bf16 changes: the speed study's numbers.

Sections (``--only``; default all), every one measured side by side in this run, named with the CPU it ran on
(model name, AVX-512, avx512_bf16 and AMX flags, usable cores) and the load average:

* ``import``: ``python -c "import spotlights"`` as a process against ``python -c pass`` (wall and CPU seconds of
  the child, ``RUSAGE_CHILDREN``; medians of ``--process-repeats``);
* ``cli``: ``spotlights complete`` on KITTI 002155 (its label_2 boxes and calibration) as a process, default
  options, against ``--runtime torch --precision fp32`` (the defaults before ``auto``) and ``--runtime torch``
  (torch at ``--precision auto``): wall and CPU seconds of the child, runs interleaved, medians; whether the child
  imported torch is not measured here (``tests/test_runtime_auto.py`` checks it);
* ``model``: the default model completing seeded random partial scans (a 4.6 x 1.9 x 1.6 m car box; forward,
  decoding, split into clouds) with torch fp32, torch bf16 autocast and onnxruntime (the shipped export): CPU
  seconds per scan at one thread (batch 1 and 32) and wall / CPU ms per scan at batch 32 on 2 threads, paths
  interleaved, medians of ``--repeats``; the model's forward FLOPs (``torch.utils.flop_counter``) and the
  measured one-thread matmul peak (2048 x 2048 ``torch.mm``, fp32 and bf16) give the fraction of the peak
  each path reaches;
* ``bf16``: what bf16 autocast changes against fp32 (torch, the default model): on test cars (``--data``: the
  test split of a completion dataset, ``--cars`` scans spread over it; skipped without it), the largest
  depth and p(hit) differences, the share of rays kept by one and not the other and the points per completion;
  on KITTI 002155 (the default model and its class-model fallback, as ``spotlights complete`` runs them), per
  completed object the points of both and the mean distance from each bf16 point to the fp32 completion
  (centimetres).

* ``parity``: the shipped ONNX exports against their torch checkpoints (float32): the largest difference of every
  graph output on 32 seeded scans (the class model: every class row and no class in turn) and the rays kept by
  one and not the other (:func:`spotlights.learning.export.parity`);
* ``pictures``: the frame picture of the first ``--picture-frames`` frames of the shared nuScenes scene (the default
  model and its fallback): CPU seconds (of the drawing thread) per frame of the bird's-eye raster (``result_png``, the default) and of
  matplotlib's figure with close-ups (``--closeups``), drawn in this process; then ``real complete --frames 0:N``
  as a process, pictures on (the default), ``--no-pictures`` and ``--closeups``, interleaved: the frame loop's
  wall seconds (``summary.json``'s ``wall_seconds``, after the model loads) and the child's CPU seconds.

The CPU figures are the ones to compare across machines and loads (CPU seconds at one thread do not depend on
what else runs); wall figures are reported beside them for the runs' ratios, never as absolute claims. Writes
``--json`` (default ``docs/results/speed/runtime.json``).

Usage: ``python benchmarks/runtime.py [--only cli model] [--data cars.h5] [--repeats 10]``
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
SHARED = Path(os.environ.get("SPOTLIGHTS_SHARED", REPO.parent / "shared")) / "data"
KITTI = SHARED / "lidar" / "kitti-object" / "training-fov-cropped"
NUSCENES = SHARED / "lidar" / "nuscenes"
SECTIONS = ("import", "cli", "model", "bf16", "pictures", "parity")
BOX = (4.6, 1.9, 1.6)  # metres: the car box the rays of the default (box-targeted) model are aimed at


def child_env() -> dict:
    """The environment of the timed processes: this checkout's package, bytecode caches written and used (as an
    installed package has them), the libraries' own thread counts (no ``OMP_NUM_THREADS``), no GPU."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "OMP_NUM_THREADS")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO / "src"), os.environ.get("PYTHONPATH", "")) if p)
    env["CUDA_VISIBLE_DEVICES"] = ""
    return env


def run_process(cmd: list[str], env: dict) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of one child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def processes(variants: dict[str, list[str]], repeats: int) -> dict:
    """Medians (and ranges) of wall and CPU seconds of each variant's process, the variants interleaved after one
    warm-up run each."""
    env = child_env()
    for cmd in variants.values():
        run_process(cmd, env)
    got: dict = {k: {"wall": [], "cpu": []} for k in variants}
    for _ in range(repeats):
        for k, cmd in variants.items():
            w, c = run_process(cmd, env)
            got[k]["wall"].append(w)
            got[k]["cpu"].append(c)
    return {
        k: {
            "wall_s": statistics.median(v["wall"]),
            "cpu_s": statistics.median(v["cpu"]),
            "wall_range_s": [min(v["wall"]), max(v["wall"])],
            "cpu_range_s": [min(v["cpu"]), max(v["cpu"])],
        }
        for k, v in got.items()
    }


def section_import(repeats: int) -> dict:
    py = [sys.executable, "-c"]
    res = processes({"python": py + ["pass"], "import spotlights": py + ["import spotlights"]}, repeats)
    res["import_spotlights_over_python"] = {
        "wall_s": res["import spotlights"]["wall_s"] - res["python"]["wall_s"],
        "cpu_s": res["import spotlights"]["cpu_s"] - res["python"]["cpu_s"],
    }
    return res


def section_cli(repeats: int) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-runtime-") as tmp:
        base = [sys.executable, "-m", "spotlights", "complete", str(KITTI / "velodyne_reduced" / "002155.bin")]
        base += ["--boxes", str(KITTI / "label_2" / "002155.txt"), "--calib", str(KITTI / "calib" / "002155.txt")]
        base += ["--out", str(Path(tmp) / "o.ply"), "-q"]
        variants = {
            "default (auto: onnxruntime fp32)": base,
            "--runtime torch --precision fp32 (the defaults before auto)": base
            + ["--runtime", "torch", "--precision", "fp32"],
            "--runtime torch (precision auto)": base + ["--runtime", "torch"],
        }
        res = processes(variants, repeats)
    return {"frame": "KITTI object 002155 (velodyne_reduced, label_2 + calib)", "runs": res}


def _alternate(fns: dict, repeats: int) -> dict:
    """Median wall and CPU seconds of each function, the functions interleaved after two warm-up calls each."""
    for f in fns.values():
        f()
        f()
    wall: dict = {k: [] for k in fns}
    cpu: dict = {k: [] for k in fns}
    for _ in range(repeats):
        for k, f in fns.items():
            t0, c0 = time.perf_counter(), time.process_time()
            f()
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    return {k: (statistics.median(wall[k]), statistics.median(cpu[k])) for k in fns}


def matmul_peak(repeats: int = 5) -> dict:
    """One-thread GFLOP/s (CPU time) of a 2048 x 2048 matrix product: ``torch.mm`` at fp32 and bf16, and
    onnxruntime's ``MatMul`` at fp32 (its own kernels: on some CPUs faster than torch's fp32 library); ``fp32`` is
    the better of the two fp32 figures, the peak a float32 path is measured against."""
    import onnxruntime as ort
    import torch
    from onnx import TensorProto, helper

    torch.set_num_threads(1)
    n = 2048
    out = {}
    for name, dt in (("torch_fp32", torch.float32), ("torch_bf16", torch.bfloat16)):
        a, b = torch.randn(n, n).to(dt), torch.randn(n, n).to(dt)
        (t,) = _alternate({name: lambda a=a, b=b: torch.mm(a, b)}, repeats).values()
        out[name] = 2 * n**3 / t[1] / 1e9
    x, y = (helper.make_tensor_value_info(k, TensorProto.FLOAT, [n, n]) for k in ("a", "b"))
    z = helper.make_tensor_value_info("c", TensorProto.FLOAT, [n, n])
    graph = helper.make_graph([helper.make_node("MatMul", ["a", "b"], ["c"])], "mm", [x, y], [z])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
    feed = {k: np.random.default_rng(0).normal(size=(n, n)).astype(np.float32) for k in ("a", "b")}
    (t,) = _alternate({"ort": lambda: sess.run(None, feed)}, repeats).values()
    out["onnxruntime_fp32"] = 2 * n**3 / t[1] / 1e9
    out["fp32"] = max(out["torch_fp32"], out["onnxruntime_fp32"])
    out["bf16"] = out["torch_bf16"]
    return out


def section_model(repeats: int) -> dict:
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    from spotlights.geometry.boxes import unit_extents
    from spotlights.learning.device import autocast
    from spotlights.learning.export import load_onnx_completer
    from spotlights.learning.inference import load_completer
    from spotlights.learning.runtime import shipped_onnx

    ref = load_completer("default", device="cpu")
    onnx_path = shipped_onnx("default")
    g = np.random.default_rng(0)
    scans = {b: (g.normal(size=(b, 256, 3)) * [0.35, 0.2, 0.15]).astype(np.float32) for b in (1, 32)}
    ext = {b: np.tile(unit_extents(np.array(BOX)), (b, 1)) for b in scans}
    cpu = torch.device("cpu")
    with torch.inference_mode(), FlopCounterMode(display=False) as fc:
        ref.model(torch.from_numpy(scans[1]))
    flops = int(fc.get_total_flops())

    def torch_path(b, prec):
        def f():
            with autocast(prec, cpu):
                ref.complete(scans[b], extents=ext[b])

        return f

    out: dict = {"model": ref.model_name, "box_m": list(BOX), "forward_flops_per_scan": flops}
    for threads in (1, 2):
        torch.set_num_threads(threads)
        onx = load_onnx_completer(onnx_path, threads=threads)
        batches = (1, 32) if threads == 1 else (32,)
        fns = {}
        for b in batches:
            fns[(b, "torch fp32")] = torch_path(b, "fp32")
            fns[(b, "torch bf16")] = torch_path(b, "bf16")
            fns[(b, "onnxruntime fp32")] = lambda b=b, onx=onx: onx.complete(scans[b], extents=ext[b])
        for (b, path), (w, c) in _alternate(fns, repeats).items():
            row = out.setdefault(f"{threads}_thread{'s' if threads > 1 else ''}", {}).setdefault(f"batch_{b}", {})
            row[path] = {"wall_ms_per_scan": w * 1e3 / b, "cpu_ms_per_scan": c * 1e3 / b}
    peak = matmul_peak()
    out["matmul_peak_gflops_1_thread"] = peak
    one = out["1_thread"]["batch_32"]
    out["fraction_of_peak_1_thread_batch_32"] = {
        path: flops / (v["cpu_ms_per_scan"] / 1e3) / 1e9 / peak["bf16" if "bf16" in path else "fp32"]
        for path, v in one.items()
    }
    return out


def _test_cars(data: str, n: int):
    """(n, 256, 3) float32 unit-frame partial scans spread over the test split of ``data``, their (n, 3) box
    half-extents in the unit frame (what the box rig is aimed at) and the number of test models."""
    from spotlights.data.store import open_dataset

    store = open_dataset(data)
    try:
        models = np.flatnonzero(store.splits == "test")
        rows = store.split_indices("test")
        pick = rows[np.linspace(0, len(rows) - 1, n).astype(int)]
        x = store.partials(pick).astype(np.float32)
        return x, store.extents[store.sample_model[pick]], len(models)
    finally:
        store.close()


def section_bf16(data: str | None, cars: int) -> dict:
    import torch
    from scipy.spatial import cKDTree

    from spotlights.completion.frame import complete_scene
    from spotlights.completion.scan import CompletionOptions
    from spotlights.data.real import open_reader
    from spotlights.learning.device import autocast
    from spotlights.learning.inference import load_completer

    torch.set_num_threads(2)
    out: dict = {}
    if data:
        ref = load_completer("default", device="cpu")
        x, e, n_models = _test_cars(data, cars)
        raw = {}
        for prec in ("fp32", "bf16"):
            with torch.inference_mode(), autocast(prec, torch.device("cpu")):
                o = ref.model(torch.from_numpy(x))
            raw[prec] = {"depths": o["depths"].float().numpy(), "p": torch.sigmoid(o["hit_logits"].float()).numpy()}
        keep = {p: r["p"] >= ref.threshold for p, r in raw.items()}
        counts = {
            p: [len(c) for c in load_completer("default", device="cpu", precision=p).complete(x, extents=e)]
            for p in ("fp32", "bf16")
        }
        out["test_cars"] = {
            "data": Path(data).name,
            "scans": int(len(x)),
            "test_models": int(n_models),
            "max_depth_difference": float(np.abs(raw["bf16"]["depths"] - raw["fp32"]["depths"]).max()),
            "max_p_hit_difference": float(np.abs(raw["bf16"]["p"] - raw["fp32"]["p"]).max()),
            "rays_kept_by_one_only_share": float((keep["bf16"] != keep["fp32"]).mean()),
            "points_per_completion": {p: float(np.mean(c)) for p, c in counts.items()},
        }
    frame = open_reader(KITTI, "kitti").load(("", "002155"))
    results = {}
    for prec in ("fp32", "bf16"):
        opts = CompletionOptions(runtime="torch", precision=prec)
        results[prec] = complete_scene(
            frame.points,
            frame.boxes,
            opts.load_completer(),
            opts.scene_config(),
            fallback=opts.load_fallback(),
            fallback_name=opts.fallback_model,
        )
    objs = []
    for a, b in zip(results["fp32"].objects, results["bf16"].objects):
        if a.status != "completed" or b.status != "completed":
            continue
        d = cKDTree(a.completion).query(b.completion)[0]
        objs.append(
            {
                "object": a.index,
                "class": a.box.cls,
                "model": a.completed_by or "default",
                "points_fp32": int(len(a.completion)),
                "points_bf16": int(len(b.completion)),
                "mean_distance_bf16_to_fp32_cm": float(d.mean() * 100),
                "p99_distance_bf16_to_fp32_cm": float(np.percentile(d, 99) * 100),
            }
        )
    out["kitti_002155"] = {
        "statuses_equal": [o.status for o in results["fp32"].objects] == [o.status for o in results["bf16"].objects],
        "objects": objs,
    }
    return out


def section_parity() -> dict:
    from spotlights.geometry.boxes import unit_extents
    from spotlights.learning.export import load_onnx_completer, parity
    from spotlights.learning.runtime import shipped_onnx

    x = (np.random.default_rng(1).normal(size=(32, 256, 3)) * [0.35, 0.2, 0.15]).astype(np.float32)
    e = unit_extents(np.array(BOX))
    out = {}
    for name in ("default", "classes"):
        onx = load_onnx_completer(shipped_onnx(name), threads=1)
        rows = np.arange(len(x)) % (len(onx.classes) + 1) - 1 if onx.classes else None
        out[name] = parity(name, onx, x, extents=e, classes=rows)
    return out


def section_pictures(frames: int, rounds: int) -> dict:
    import pickle

    from spotlights.completion.frame import complete_scene
    from spotlights.completion.pictures import bev_scene, result_png
    from spotlights.completion.scan import CompletionOptions
    from spotlights.data.real import open_reader

    reader = open_reader(NUSCENES, "nuscenes")
    keys = reader.frame_keys()[:frames]
    opts = CompletionOptions()
    main_model, fallback = opts.load_completer(), opts.load_fallback()
    cpu: dict = {"raster": [], "closeups": []}
    sizes: dict = {"result_pickle_bytes": [], "payload_pickle_bytes": [], "png_bytes": []}
    for key in keys:
        f = reader.load(key)
        r = complete_scene(
            f.points, f.boxes, main_model, opts.scene_config(), fallback=fallback, fallback_name=opts.fallback_model
        )
        scan_xy, objects = bev_scene(r)  # what a picture process is sent, against the whole result
        sizes["result_pickle_bytes"].append(len(pickle.dumps(r)))
        sizes["payload_pickle_bytes"].append(len(pickle.dumps((scan_xy, objects))))
        for name, closeups in (("raster", False), ("closeups", True)):
            c0 = time.thread_time()  # this thread's CPU: not the model's threads, which may spin after a forward
            png = result_png(r, "title", closeups)
            cpu[name].append(time.thread_time() - c0)
            if not closeups:
                sizes["png_bytes"].append(len(png))
    out: dict = {
        "source": "nuScenes scene-0523 (the shared mini extract)",
        "frames": len(keys),
        "cpu_s_per_picture": {k: statistics.median(v[1:] or v) for k, v in cpu.items()},
        "cpu_clock": "time.thread_time of the drawing thread (not the model's threads, which may spin after a forward)",
        "medians": {k: statistics.median(v) for k, v in sizes.items()},
    }
    env = child_env()
    runs: dict = {"pictures (default)": [], "--no-pictures": [], "--closeups": []}
    extra = {"pictures (default)": [], "--no-pictures": ["--no-pictures"], "--closeups": ["--closeups"]}
    for _ in range(rounds):
        for name in runs:
            with tempfile.TemporaryDirectory(prefix="bench-pictures-") as tmp:
                cmd = [sys.executable, "-m", "spotlights", "real", "complete", str(NUSCENES), "--format", "nuscenes"]
                cmd += ["--frames", f"0:{frames}", "--out", str(Path(tmp) / "o"), "-q", *extra[name]]
                wall, child_cpu = run_process(cmd, env)
                summ = json.loads((Path(tmp) / "o" / "summary.json").read_text())
                runs[name].append((summ["wall_seconds"], child_cpu, wall))
    out["real_complete"] = {
        name: {
            "frame_loop_wall_s": statistics.median(v[0] for v in vals),
            "frames_per_s": frames / statistics.median(v[0] for v in vals),
            "process_cpu_s": statistics.median(v[1] for v in vals),
            "process_wall_s": statistics.median(v[2] for v in vals),
        }
        for name, vals in runs.items()
    }
    rc = out["real_complete"]
    out["frame_loop_pictures_over_none"] = (
        rc["pictures (default)"]["frame_loop_wall_s"] / rc["--no-pictures"]["frame_loop_wall_s"]
    )
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", choices=SECTIONS, default=list(SECTIONS))
    ap.add_argument("--repeats", type=int, default=10, help="timed calls per path (model section)")
    ap.add_argument("--process-repeats", type=int, default=5, help="timed processes per variant (import, cli)")
    ap.add_argument("--data", default=None, help="bf16 section: a completion dataset whose test split holds the cars")
    ap.add_argument("--cars", type=int, default=64, help="bf16 section: test scans (default 64)")
    ap.add_argument("--picture-frames", type=int, default=8, help="pictures section: nuScenes frames (default 8)")
    ap.add_argument("--picture-rounds", type=int, default=2, help="pictures section: runs of each variant")
    ap.add_argument("--json", default=str(REPO / "docs" / "results" / "speed" / "runtime.json"))
    args = ap.parse_args()
    sys.path.insert(0, str(REPO / "src"))
    from spotlights.learning.cpu import cpu_description

    res: dict = {
        "command": "python benchmarks/runtime.py "
        + " ".join(Path(a).name if a == args.data else a for a in sys.argv[1:]),
        "cpu": cpu_description(),
        "load_average_at_start": list(os.getloadavg()),
        "python": sys.version.split()[0],
    }
    try:
        import onnxruntime
        import torch

        res["versions"] = {"torch": torch.__version__, "onnxruntime": onnxruntime.__version__}
    except ImportError:
        pass
    t0 = time.perf_counter()
    if "import" in args.only:
        res["import"] = section_import(args.process_repeats)
        print("import:", json.dumps(res["import"]["import_spotlights_over_python"]), flush=True)
    if "cli" in args.only:
        res["cli"] = section_cli(args.process_repeats)
        print("cli:", json.dumps(res["cli"]["runs"], indent=1), flush=True)
    if "model" in args.only:
        res["model"] = section_model(args.repeats)
        print("model:", json.dumps(res["model"], indent=1), flush=True)
    if "bf16" in args.only:
        res["bf16"] = section_bf16(args.data, args.cars)
        print("bf16:", json.dumps(res["bf16"], indent=1), flush=True)
    if "parity" in args.only:
        res["parity"] = section_parity()
        print("parity:", json.dumps(res["parity"]), flush=True)
    if "pictures" in args.only:
        res["pictures"] = section_pictures(args.picture_frames, args.picture_rounds)
        print("pictures:", json.dumps(res["pictures"], indent=1), flush=True)
    res["load_average_at_end"] = list(os.getloadavg())
    res["seconds"] = time.perf_counter() - t0
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"-> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
