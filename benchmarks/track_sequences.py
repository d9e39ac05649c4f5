"""Fusion and box refinement on simulated drive-past sequences, against ground truth.

For ``--meshes`` (default: the first ``--n`` ApolloScape cars by name) one sequence each
(:func:`spotlights.data.synthetic.sequences.simulate_sequence`, ``--sensor`` hdl32e by default:
nuScenes-like; ``--frames`` at 10 Hz; noisy boxes N(0, 0.10 m) per horizontal axis, N(0, 2 deg), 3%
size), then:

1. **box refinement** (:func:`spotlights.data.tracks.refine_track`, windows ``all`` and ``past:5``): the
   mean horizontal centre error and the mean absolute heading error of the noisy and of the refined
   boxes against the true ones;
2. **completion against the number of fused frames**: at every frame ``t >= K_max - 1`` the causal window
   ``past:K`` (K = 1, 2, 5, 10) is fused (:func:`spotlights.data.tracks.fuse_track`, the completion's
   crop: margin 0.15 m, ground clearance 0.10 m) under true boxes, noisy boxes and refined boxes
   (``all``), completed by the model (``spotlights.learning.inference.complete_in_boxes`` on the
   256-point input, as ``real complete`` does), and scored against the mesh's surface (2,048 points) in
   the true box frame: accuracy (completion -> truth, mean, metres) and completeness (truth ->
   completion); the truth is ``--gt-points`` (20,000) points on the mesh surface (2,048 were used before: ~12 cm
   apart on a car, a floor of ~4 cm under every accuracy).

Usage::

    OMP_NUM_THREADS=1 python benchmarks/track_sequences.py --n 6 --json docs/results/real/track_sequences.json
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import Counter
from pathlib import Path

import numpy as np

from spotlights.data.lidar import sensor_preset
from spotlights.data.synthetic.sequences import SequenceSpec, simulate_sequence
from spotlights.data.tracks import TrackFrame, fuse_track, parse_window, refine_track
from spotlights.geometry.distances import accuracy, completeness
from spotlights.geometry.io import load_mesh
from spotlights.geometry.sampling import sample_surface
from spotlights.learning.fused import paper_split_meshes
from spotlights.learning.inference import complete_in_boxes, load_completer, prepare_partial

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "meshes" / "apolloscape-cars"
WINDOWS = (1, 2, 5, 10, "all")


def box_errors(frames, boxes):
    """Mean horizontal centre error (m) and mean absolute heading error (deg) of ``boxes`` against the truth."""
    t = [float(np.hypot(*(b.center - f["true_box"].center)[:2])) for f, b in zip(frames, boxes)]
    y = [abs(math.degrees(math.remainder(b.yaw - f["true_box"].yaw, 2 * math.pi))) for f, b in zip(frames, boxes)]
    return float(np.mean(t)), float(np.mean(y))


def simulated_sequence(path, index: int, seed: int, sensor: str, frames: int, hz: float, gt_points: int):
    """The mesh at ``path``, the LiDAR sequence simulated past it (seeded by ``[seed, index]``) and its dense truth:
    ``gt_points`` surface points (seeded by ``[seed, index, 1]``) in the sequence's box frame, metres. Dense:
    2,048 points on a car's ~30 m2 are ~12 cm apart, a floor of ~4 cm under any accuracy."""
    mesh = load_mesh(path)
    rng = np.random.default_rng([seed, index])
    seq = simulate_sequence(
        np.asarray(mesh.vertices), np.asarray(mesh.faces), sensor_preset(sensor), SequenceSpec(frames, hz), rng
    )
    gt = sample_surface(mesh, gt_points, seed=np.random.default_rng([seed, index, 1])) - seq["center_in_mesh"]
    return mesh, seq, gt


def truth_floor(mesh, center_in_mesh: np.ndarray, size: np.ndarray, rig, gt: np.ndarray) -> tuple[float, float]:
    """Accuracy and completeness (metres, true box frame) of the mesh's own depths on ``rig`` (a box rig spec
    or rig), decoded, against ``gt`` (G, 3): what a perfect model of this representation scores, a floor under
    every completion's numbers (rays see no interior surface; ``gt`` is a finite sample)."""
    import trimesh

    from spotlights.geometry.encode import MeshProbe, decode
    from spotlights.geometry.frames import normalization_from_box

    local = trimesh.Trimesh(
        np.asarray(mesh.vertices, np.float64) - center_in_mesh, np.asarray(mesh.faces), process=False
    )
    probe = MeshProbe(local, normalization_from_box(np.zeros(3), size))
    pts, hit = decode(probe.encode(rig), probe.rig_for(rig))
    own = probe.normalization.from_unit(pts[hit].astype(np.float64))
    return accuracy(own, gt), completeness(own, gt)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", default=str(MESHES))
    ap.add_argument("--n", type=int, default=6)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--hz", type=float, default=10.0, help="frame rate (2: nuScenes keyframes)")
    ap.add_argument("--sensor", default="hdl32e")
    ap.add_argument("--checkpoint", nargs="+", default=["default"], help="one or more (scored side by side)")
    ap.add_argument(
        "--split", default=None, choices=("train", "val", "test"), help="the paper split's cars of --meshes"
    )
    ap.add_argument("--precision", default="fp32")
    ap.add_argument("--gt-points", type=int, default=20000, help="points sampled on the mesh surface (truth)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--resample",
        default="random",
        choices=("random", "fps"),
        help="how a fused window is brought to the model's input (as `real complete --resample`)",
    )
    ap.add_argument("--input-points", type=int, default=256, help="points per model input (the models learned 256)")
    ap.add_argument(
        "--snap",
        type=float,
        default=0.0,
        help="snap the rays to each window's input within R (unit frame), as --snap R",
    )
    ap.add_argument("--snap-mirror", action="store_true", help="with --snap: the mirrored input too")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    if args.split:
        meshes = paper_split_meshes(args.meshes, args.split)[: args.n]
    else:
        meshes = sorted(Path(args.meshes).rglob("*.ply"))[: args.n]
    completers = {c: load_completer(c, precision=args.precision) for c in args.checkpoint}
    k_max = max(k for k in WINDOWS if k != "all")
    rig = next((c.rig for c in completers.values() if getattr(c, "rig", None) is not None), None)
    floor: list = []
    refine = {"all": Counter(), "past:5": Counter()}
    errs = {k: {"noisy": [], "refined": []} for k in refine}
    scores: dict = {}
    t_refine = 0.0
    for i, m in enumerate(meshes):
        mesh, seq, gt = simulated_sequence(m, i, args.seed, args.sensor, args.frames, args.hz, args.gt_points)
        frs = seq["frames"]
        # the representation's own floor: the mesh itself encoded on the model's rig in its true box, decoded
        if rig is not None:  # point-set models only: no rig, no floor
            floor.append(truth_floor(mesh, seq["center_in_mesh"], frs[0]["true_box"].size, rig, gt))
        noisy = [TrackFrame(f["points"].astype(np.float64), f["noisy_box"], np.zeros(3), f["timestamp"]) for f in frs]
        boxes = {"true": [f["true_box"] for f in frs], "noisy": [f["noisy_box"] for f in frs]}
        for pol in refine:
            t0 = time.perf_counter()
            ref = refine_track(noisy, pol, margin=0.65, ground_clearance=0.10)
            t_refine += time.perf_counter() - t0
            refine[pol].update(ref.status)
            errs[pol]["noisy"].append(box_errors(frs, boxes["noisy"]))
            errs[pol]["refined"].append(box_errors(frs, ref.boxes))
            if pol == "all":
                boxes["refined"] = ref.boxes
        for kind, bx in boxes.items():
            for k in WINDOWS:
                pol = parse_window("all" if k == "all" else f"past:{k}")
                partials, sizes, origins, used, seen = [], [], [], [], []
                for t in range(k_max - 1, len(frs)):
                    fused = fuse_track(noisy, pol.select(len(frs), t), boxes=bx, margin=0.15, ground_clearance=0.10)
                    if len(fused.points) < 10:
                        continue
                    b = bx[t]
                    partials.append(prepare_partial(fused.points / b.radius, args.input_points, method=args.resample))
                    if args.snap:  # as real complete: a fused window's rule carves from frame t's own points only
                        window = pol.select(len(frs), t)
                        own = fuse_track(noisy, [t], boxes=bx, margin=0.15, ground_clearance=0.10).points / b.radius
                        seen.append(own if len(window) > 1 else partials[-1])  # no own points: none carved
                    sizes.append(b.size)
                    origins.append(b.normalization().to_unit(np.zeros((1, 3)))[0])  # the sensor: its frame's origin
                    used.append(t)
                for name, completer in completers.items():
                    # frame t's sensor in its box's unit frame: the free space a ray-local model reads
                    outs = complete_in_boxes(
                        completer,
                        np.stack(partials),
                        np.stack(sizes),
                        sensor_origins=np.stack(origins),
                        snap=args.snap or None,
                        snap_mirror=args.snap_mirror,
                        seen=seen if args.snap else None,
                    )
                    for t, c in zip(used, outs):
                        b, tb = bx[t], frs[t]["true_box"]
                        pred = tb.to_object(b.from_object(c.astype(np.float64) * b.radius))  # into the true box frame
                        s = scores.setdefault((name, kind, k), {"accuracy": [], "completeness": []})
                        s["accuracy"].append(accuracy(pred, gt))
                        s["completeness"].append(completeness(pred, gt))
    report = dict(
        sensor=args.sensor,
        frames=args.frames,
        hz=args.hz,
        meshes=[str(m.name) for m in meshes],
        checkpoints=args.checkpoint,
        precision=args.precision,
        resample=args.resample,
        input_points=args.input_points,
        snap=args.snap,
        snap_mirror=args.snap_mirror,
        noise={"translation_m": 0.10, "yaw_deg": 2.0, "size_rel": 0.03},
        refinement={
            pol: dict(
                statuses=dict(refine[pol]),
                noisy_translation_m=float(np.mean([e[0] for e in errs[pol]["noisy"]])),
                refined_translation_m=float(np.mean([e[0] for e in errs[pol]["refined"]])),
                noisy_yaw_deg=float(np.mean([e[1] for e in errs[pol]["noisy"]])),
                refined_yaw_deg=float(np.mean([e[1] for e in errs[pol]["refined"]])),
            )
            for pol in refine
        },
        refine_seconds=t_refine,
        truth_floor=None
        if not floor
        else dict(
            rig=str(getattr(rig, "name", rig)),
            accuracy_m=float(np.mean([f[0] for f in floor])),
            completeness_m=float(np.mean([f[1] for f in floor])),
            note="the meshes' own depths on the model's rig in the true box, decoded, scored like a completion",
        ),
        completion={
            name: {
                f"{kind} past:{k}" if k != "all" else f"{kind} all": dict(
                    n=len(v["accuracy"]),
                    accuracy_m=float(np.mean(v["accuracy"])),
                    completeness_m=float(np.mean(v["completeness"])),
                )
                for (nm, kind, k), v in scores.items()
                if nm == name
            }
            for name in completers
        },
    )
    for rows in report["completion"].values():  # gain of each window over one frame under the same boxes
        for key, r in rows.items():
            one = rows[key.split()[0] + " past:1"]
            r["accuracy_gain"] = 1 - r["accuracy_m"] / one["accuracy_m"]
            r["completeness_gain"] = 1 - r["completeness_m"] / one["completeness_m"]
    for r in report["refinement"].values():
        r["translation_cut"] = 1 - r["refined_translation_m"] / r["noisy_translation_m"]
        r["yaw_cut"] = 1 - r["refined_yaw_deg"] / r["noisy_yaw_deg"]
    text = json.dumps(report, indent=2)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
