"""Training samples from fused track windows: simulated drive-past sequences -> (partial, target depths).

A model trained on single scans takes 256 points and has learned what one view of a car looks like;
fused windows (:func:`spotlights.data.tracks.fuse_track`) cover more of the car. This module turns
simulated sequences (:func:`spotlights.data.synthetic.sequences.simulate_sequence`) into training
samples of the dense hit-aware SA-Net:

* :func:`simulate_pool` simulates ``sequences`` sequences per mesh (rates and sensors alternating over
  ``rates`` x ``sensors``) and stores, per frame, up to ``max_points`` of its scan (a seeded random
  subset, sensor frame, float32), its true and noisy boxes, and the box rig's ground-truth depths of the
  mesh **in the noisy box's frame** (the frame a completion under that box is scored in): float16
  (N*M,); the true box's depths once per sequence (the mesh is rigid, so they do not change per frame).
* :func:`draw_sample` draws one sample: a sequence, a frame ``t``, a window size ``k`` uniform in 1..K,
  boxes true (probability ``p_true``) or noisy (not refined); the causal window ``past:k`` ending at ``t``
  is fused in the box frame of ``t`` (crop margin 0.15 m, ground clearance 0.10 m, as ``real complete``),
  divided by R (half the box diagonal) and resampled to 256 points
  (:func:`spotlights.learning.inference.prepare_partial`); the target is frame ``t``'s depths under the
  same box.

Everything is seeded: one seed gives the same pool and the same samples.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..data.lidar import sensor_preset
from ..data.synthetic.catalogue import assign_splits, discover_models
from ..data.synthetic.sequences import SequenceSpec, simulate_sequence
from ..data.tracks import TrackFrame, fuse_track, parse_window
from ..errors import ParameterError
from ..geometry.encode import MeshProbe
from ..geometry.frames import normalization_from_box
from ..geometry.io import load_mesh
from ..geometry.rig import parse_rig
from .inference import prepare_partial

CROP_MARGIN = 0.15
GROUND_CLEARANCE = 0.10


@dataclass
class SequencePool:
    """Simulated sequences ready to draw fused samples from (see the module docstring).

    frames : per sequence, a list of per-frame dicts {"points": (K, 3) float32 sensor frame,
        "true_box", "noisy_box": Box, "depths_noisy": (N*M,) float16, "timestamp": s}.
    depths_true : per sequence, (N*M,) float16 depths in the true box frame.
    mesh : per sequence, the mesh index (into ``meshes``).
    """

    meshes: list
    rig: str
    frames: list = field(default_factory=list)
    depths_true: list = field(default_factory=list)
    mesh: list = field(default_factory=list)


def _mesh_in_box(mesh, center_in_mesh: np.ndarray, true_box):
    import trimesh

    v = true_box.from_object(np.asarray(mesh.vertices, dtype=np.float64) - center_in_mesh)
    return trimesh.Trimesh(v, np.asarray(mesh.faces), process=False)


def _depths(mesh_sensor, box, rig) -> np.ndarray:
    probe = MeshProbe(mesh_sensor, normalization_from_box(box.center, box.size, rotation=box.rotation))
    return probe.encode(rig).astype(np.float16)


def simulate_pool(
    meshes: list,
    sequences: int = 4,
    frames: int = 20,
    rates: tuple = (2.0, 10.0),
    sensors: tuple = ("hdl64e", "hdl32e"),
    rig: str = "box-128x128-ellipsoid-s1",
    max_points: int = 1024,
    seed: int = 0,
) -> SequencePool:
    """Simulate ``sequences`` drive-past sequences of ``frames`` frames per mesh file (see the module docstring).

    Sequence ``j`` of mesh ``i`` draws from ``numpy.random.default_rng([seed, i, j])`` at rate
    ``rates[j % len(rates)]`` Hz with sensor ``sensors[(j // len(rates)) % len(sensors)]``.
    """
    if sequences < 1 or frames < 1 or max_points < 1:
        raise ParameterError("sequences, frames and max_points must be >= 1")
    spec_rig = parse_rig(rig)
    pool = SequencePool(meshes=[str(m) for m in meshes], rig=rig)
    for i, path in enumerate(meshes):
        mesh = load_mesh(path)
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        for j in range(sequences):
            rng = np.random.default_rng([seed, i, j])
            hz = rates[j % len(rates)]
            sensor = sensor_preset(sensors[(j // len(rates)) % len(sensors)])
            seq = simulate_sequence(v, f, sensor, SequenceSpec(frames, hz), rng)
            rows = []
            for fr in seq["frames"]:
                pts = fr["points"]
                if len(pts) > max_points:
                    pts = pts[np.sort(rng.choice(len(pts), max_points, replace=False))]
                ms = _mesh_in_box(mesh, seq["center_in_mesh"], fr["true_box"])
                rows.append(
                    dict(
                        points=np.ascontiguousarray(pts, dtype=np.float32),
                        true_box=fr["true_box"],
                        noisy_box=fr["noisy_box"],
                        depths_noisy=_depths(ms, fr["noisy_box"], spec_rig),
                        timestamp=fr["timestamp"],
                    )
                )
            first = seq["frames"][0]["true_box"]
            pool.depths_true.append(_depths(_mesh_in_box(mesh, seq["center_in_mesh"], first), first, spec_rig))
            pool.frames.append(rows)
            pool.mesh.append(i)
    return pool


def draw_sample(
    pool: SequencePool, rng: np.random.Generator, max_window: int = 10, p_true: float = 0.3, tries: int = 20
) -> dict | None:
    """One fused-window sample (see the module docstring), or None after ``tries`` windows of < 10 points.

    Returns {"partial": (256, 3) float32 unit frame, "depths": (N*M,) float32 target, "size": (3,) box size
    (m), "k": window size asked, "n_frames": frames fused, "true_boxes": bool}.
    """
    for _ in range(tries):
        s = int(rng.integers(len(pool.frames)))
        rows = pool.frames[s]
        t = int(rng.integers(len(rows)))
        k = int(rng.integers(1, max_window + 1))
        true = bool(rng.random() < p_true)
        key = "true_box" if true else "noisy_box"
        sel = parse_window(f"past:{k}").select(len(rows), t)
        tf = [TrackFrame(rows[i]["points"], rows[i][key], np.zeros(3), rows[i]["timestamp"]) for i in sel]
        fused = fuse_track(tf, margin=CROP_MARGIN, ground_clearance=GROUND_CLEARANCE)
        if len(fused.points) < 10:
            continue
        b = rows[t][key]
        target = pool.depths_true[s] if true else rows[t]["depths_noisy"]
        return dict(
            partial=prepare_partial(fused.points / b.radius, seed=int(rng.integers(2**31))),
            depths=target.astype(np.float32),
            size=np.asarray(b.size, dtype=np.float64),
            k=k,
            n_frames=len(sel),
            true_boxes=true,
        )
    return None


def draw_batch(pool: SequencePool, rng: np.random.Generator, batch: int, max_window: int = 10, p_true: float = 0.3):
    """``batch`` samples of :func:`draw_sample` stacked: partial (B, 256, 3) float32, depths (B, N*M) float32."""
    out = []
    while len(out) < batch:
        smp = draw_sample(pool, rng, max_window, p_true)
        if smp is not None:
            out.append(smp)
    return (
        np.stack([o["partial"] for o in out]),
        np.stack([o["depths"] for o in out]),
        np.stack([o["size"] for o in out]),
    )


def paper_split_meshes(root, split: str, spec: str = "64/8/7", seed: int = 0) -> list[Path]:
    """The mesh files of ``split`` ("train", "val", "test") of a mesh folder under ``dataset build``'s
    split (``spec``, ``seed``, stratified by category): the paper split of the ApolloScape cars by default."""

    root = Path(root)
    entries, _ = discover_models(root)
    splits = assign_splits([e.category for e in entries], spec, seed)
    return [root / e.file for e, s in zip(entries, splits) if s == split]


__all__ = ["SequencePool", "draw_batch", "draw_sample", "paper_split_meshes", "simulate_pool"]
