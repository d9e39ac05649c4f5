"""Simulated sequences with ground truth: a vehicle driving past the sensor, scanned at 10 Hz.

Real sets have tracks but no complete shapes; the simulator has both. Each sequence is one mesh
driving along a straight line past a static sensor (:class:`spotlights.data.lidar.LidarSimulator`,
the dataset's LiDAR model: HDL-64E by default, ``hdl32e`` for nuScenes-like scans), one scan per frame.
Per frame it records the vehicle's **true box** and a **detector-like noisy box** drawn from
:class:`BoxNoise` (independent per frame):

* centre: + N(0, ``translation_m``^2) on each horizontal axis of the sensor frame (default 0.10 m);
* heading: + N(0, ``yaw_deg``^2) degrees (default 2);
* size: each of length, width, height x (1 + N(0, ``size_rel``^2)) (default 3%); the centre's height
  and the box's up axis are kept.

Trajectory: heading 0 or pi (drawn), lateral offset ``lateral_m`` (drawn uniformly, on either side),
speed ``speed_mps`` (drawn uniformly), the middle frame within 3 m of abeam the sensor; the vehicle
keeps its heading. Scans hold only the vehicle's returns (the simulator's ground occludes, but
returns no points), in the sensor frame (x forward, y left, z up; the sensor at the origin).

Written in the generic multi-frame format (``real complete --format generic`` reads it; see
docs/real-data.md) - per sequence ``DIR/seqNNNN/``: ``FFFF.npy`` scans ((K, 3) float32, metres),
``sequence.json`` (frames with the *noisy* box, track id ``"0"``, timestamp in seconds),
``truth.json`` (mesh, sensor, noise model, and per frame the true and noisy boxes) and ``gt.npy``
(2,048 points sampled uniformly on the mesh surface, float32, in the box frame: x forward, y left,
z up, box centre, metres). One seed gives the same bytes (sequence ``i`` draws from
``numpy.random.default_rng([seed, i])``).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ...errors import ParameterError
from ...geometry.boxes import Box
from ...geometry.io import load_mesh
from ...geometry.sampling import sample_surface
from ...utils import atomic_output
from ..lidar import LidarSimulator, SensorModel, VehiclePose, sensor_preset


@dataclass(frozen=True)
class BoxNoise:
    """The detector-like box noise of :mod:`spotlights.data.synthetic.sequences` (sigmas, independent per frame):
    ``translation_m`` metres per horizontal axis, ``yaw_deg`` degrees, ``size_rel`` relative per dimension."""

    translation_m: float = 0.10
    yaw_deg: float = 2.0
    size_rel: float = 0.03

    def __post_init__(self):
        for k, v in asdict(self).items():
            if not (math.isfinite(v) and v >= 0):
                raise ParameterError(f"box noise {k} must be >= 0, got {v}")

    def apply(self, box: Box, rng: np.random.Generator) -> Box:
        """A noisy copy of ``box`` (draws 6 normals from ``rng``: dx, dy, dyaw, dl, dw, dh)."""
        d = rng.normal(size=6)
        center = box.center + np.array([d[0], d[1], 0.0]) * self.translation_m
        size = box.size * (1.0 + d[3:] * self.size_rel)
        return Box.from_yaw(center, size, box.yaw + math.radians(self.yaw_deg) * d[2], box.label, box.cls, box.track_id)


@dataclass(frozen=True)
class SequenceSpec:
    """How sequences are drawn: frames, rate, trajectory ranges, noise."""

    n_frames: int = 20
    hz: float = 10.0
    lateral_m: tuple = (4.0, 12.0)
    speed_mps: tuple = (3.0, 12.0)
    noise: BoxNoise = BoxNoise()

    def __post_init__(self):
        if self.n_frames < 1:
            raise ParameterError(f"a sequence needs at least 1 frame, got {self.n_frames}")
        if not (math.isfinite(self.hz) and self.hz > 0):
            raise ParameterError(f"the frame rate must be > 0 Hz, got {self.hz}")


def simulate_sequence(vertices: np.ndarray, faces: np.ndarray, sensor: SensorModel, spec: SequenceSpec, rng) -> dict:
    """One vehicle driving past the sensor (see the module docstring).

    vertices (V, 3) float, faces (F, 3) int: the mesh in its object frame (x forward, y left, z up, metres).
    Returns {"frames": [{"points": (K, 3) float32 sensor frame, "true_box": Box, "noisy_box": Box,
    "timestamp": seconds}], "trajectory": {...}}.
    """
    sim = LidarSimulator(vertices, faces, sensor)
    side = 1.0 if rng.random() < 0.5 else -1.0
    direction = 1.0 if rng.random() < 0.5 else -1.0
    lateral = side * rng.uniform(*spec.lateral_m)
    speed = rng.uniform(*spec.speed_mps)
    x_mid = rng.uniform(-3.0, 3.0)
    heading = 0.0 if direction > 0 else math.pi
    if abs(lateral) <= sim.footprint_radius:
        raise ParameterError(f"lateral offset {abs(lateral):.2f} m would put the vehicle over the sensor")
    frames = []
    for k in range(spec.n_frames):
        t = k / spec.hz
        x = x_mid + direction * speed * (k - (spec.n_frames - 1) / 2.0) / spec.hz
        pose = VehiclePose(distance=math.hypot(x, lateral), azimuth=math.atan2(lateral, x), heading=heading)
        scan = sim.scan(pose, rng)
        m = sim.object_to_sensor(pose)
        pts = (scan.points @ m[:3, :3].T + m[:3, 3]).astype(np.float32)
        true = Box.from_yaw(sim.box_center_in_sensor(pose), sim.size, heading, "car", "car", "0")
        frames.append(dict(points=pts, true_box=true, noisy_box=spec.noise.apply(true, rng), timestamp=t))
    traj = dict(lateral_m=lateral, speed_mps=speed, heading_rad=heading, x_mid_m=x_mid, hz=spec.hz)
    return {"frames": frames, "trajectory": traj, "center_in_mesh": sim.center}


def _box_json(b: Box) -> dict:
    return {
        "center": [float(v) for v in b.center],
        "size": [float(v) for v in b.size],
        "yaw": float(b.yaw),
        "label": "car",
        "track_id": b.track_id,
    }


SEQUENCE_MESH_SUFFIXES = (".ply", ".obj", ".off", ".stl", ".glb", ".gltf")
"""Files ``dataset sequences --meshes FOLDER`` takes (the order its error message lists them in)."""


def mesh_files(path: str | Path) -> list[Path]:
    """The mesh file ``path``, or the mesh files anywhere under the folder ``path`` (sorted);
    ParameterError when there is none."""
    src = Path(path)
    if src.is_dir():
        meshes = sorted(p for p in src.rglob("*") if p.suffix.lower() in SEQUENCE_MESH_SUFFIXES)
        if not meshes:
            raise ParameterError(f"{src}: no mesh file ({', '.join(SEQUENCE_MESH_SUFFIXES)}) in the folder")
        return meshes
    if src.is_file():
        return [src]
    raise ParameterError(f"{src}: no such mesh file or folder")


def write_sequences(
    meshes: list, out, n_sequences: int, spec: SequenceSpec, seed: int = 0, sensor: str = "hdl64e"
) -> list[Path]:
    """Simulate ``n_sequences`` sequences (mesh ``i % len(meshes)`` for sequence ``i``) into ``out``.

    meshes : mesh files (z up, x forward, metres). Returns the ``sequence.json`` paths written. Every file
    is written atomically; a sequence is complete when its ``sequence.json`` exists (written last).
    """
    if n_sequences < 1:
        raise ParameterError(f"--sequences must be >= 1, got {n_sequences}")
    if not meshes:
        raise ParameterError("no mesh to simulate")
    sens = sensor_preset(sensor)
    out = Path(out)
    loaded: dict[int, tuple] = {}
    written = []
    for i in range(n_sequences):
        j = i % len(meshes)
        if j not in loaded:
            mesh = load_mesh(meshes[j])
            loaded[j] = (mesh, np.asarray(mesh.vertices), np.asarray(mesh.faces))
        mesh, v, f = loaded[j]
        rng = np.random.default_rng([seed, i])
        seq = simulate_sequence(v, f, sens, spec, rng)
        name = f"seq{i:04d}"
        folder = out / name
        folder.mkdir(parents=True, exist_ok=True)
        gt = (sample_surface(mesh, 2048, seed=rng) - seq["center_in_mesh"]).astype(np.float32)
        with atomic_output(folder / "gt.npy") as tmp:
            with open(tmp, "wb") as fh:
                np.save(fh, gt)
        rows = []
        for k, fr in enumerate(seq["frames"]):
            with atomic_output(folder / f"{k:04d}.npy") as tmp:
                with open(tmp, "wb") as fh:
                    np.save(fh, fr["points"])
            rows.append(
                dict(
                    scan=f"{k:04d}.npy",
                    frame_id=f"{k:04d}",
                    timestamp=fr["timestamp"],
                    boxes=[_box_json(fr["noisy_box"])],
                    true_box=_box_json(fr["true_box"]),
                    n_points=len(fr["points"]),
                )
            )
        truth = dict(
            mesh=str(meshes[j]),
            sensor=sensor,
            noise=asdict(spec.noise),
            trajectory=seq["trajectory"],
            seed=seed,
            index=i,
            gt="gt.npy (2048 points on the mesh surface, box frame)",
            frames=rows,
        )
        with atomic_output(folder / "truth.json") as tmp:
            tmp.write_text(json.dumps(truth, indent=1) + "\n", encoding="utf-8")
        frames = [{k: r[k] for k in ("scan", "frame_id", "timestamp", "boxes")} for r in rows]
        with atomic_output(folder / "sequence.json") as tmp:
            tmp.write_text(json.dumps({"sequence": name, "frames": frames}, indent=1) + "\n", encoding="utf-8")
        written.append(folder / "sequence.json")
    return written


__all__ = ["BoxNoise", "SequenceSpec", "simulate_sequence", "write_sequences"]
