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

Or in one HDF5 file (:func:`write_sequences_h5`, ``dataset sequences --out FILE.h5 [--workers N]``; read with
:func:`read_sequences_h5`), format ``spotlights-sequences`` version 1, written like the completion dataset
(gzip, no time stamps, HDF5 1.10 layout: the same seed gives the same bytes whatever the number of workers):

* root attributes: ``format``, ``format_version``, ``seed``, ``sensor``, ``noise`` (JSON: the sigmas of
  :class:`BoxNoise`), ``spec`` (JSON: frames, rate, ranges), ``n_sequences``, ``n_frames``;
* ``/sequences`` (S rows): ``mesh`` (str), ``track_id`` (str), ``trajectory`` (JSON str), ``first_frame``
  (int64, its first row of ``/frames``), ``n_frames`` (int32), ``gt`` (S, 2048, 3) float32 (the mesh surface,
  box frame, metres);
* ``/frames`` (F rows, sequence after sequence): ``sequence``, ``frame`` (int32), ``timestamp`` (float64, s),
  ``track_id`` (str), ``point_start`` (int64), ``n_points`` (int32), ``true_box`` and ``noisy_box`` ((F, 7)
  float64: centre x, y, z, length, width, height, yaw, sensor frame), ``sensor_origin`` ((F, 3) float64, sensor
  frame: zeros), ``sensor_in_true_unit`` and ``sensor_in_noisy_unit`` ((F, 3) float64: the sensor in each
  box's unit frame, object frame / half the box diagonal);
* ``/points`` (P, 3) float32, sensor frame, metres: frame ``f``'s scan is rows
  ``point_start[f] : point_start[f] + n_points[f]``.
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ...errors import InputFileError, ParameterError
from ...geometry.boxes import Box
from ...geometry.io import load_mesh
from ...geometry.sampling import sample_surface
from ...outputs import atomic_output, hdf5_output, output_folder
from ...processes import process_map
from ..lidar import LidarSimulator, SensorModel, VehiclePose, sensor_preset
from ..store_writer import COMPRESSION

MAX_SIZE_SIGMA = 0.25
"""The largest relative size noise (a detector's size error is a few percent; 5 at the command line wrote boxes of
negative size)."""

MIN_SIZE_FACTOR = 0.1
"""A noisy box keeps at least this share of each true dimension (reached only by draws beyond ~3.6 sigma at the
largest size noise; the default's 0.03 never reaches it)."""


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
        if self.size_rel > MAX_SIZE_SIGMA:
            raise ParameterError(
                f"box noise size_rel (`size_sigma`) must be at most {MAX_SIZE_SIGMA:g} (relative), got {self.size_rel:g}",
                "size_sigma",
            )

    def apply(self, box: Box, rng: np.random.Generator) -> Box:
        """A noisy copy of ``box`` (draws 6 normals from ``rng``: dx, dy, dyaw, dl, dw, dh)."""
        d = rng.normal(size=6)
        center = box.center + np.array([d[0], d[1], 0.0]) * self.translation_m
        size = box.size * np.maximum(1.0 + d[3:] * self.size_rel, MIN_SIZE_FACTOR)  # never a flat or negative box
        return Box.from_yaw(center, size, box.yaw + math.radians(self.yaw_deg) * d[2], box.label, box.cls, box.track_id)


MAX_FRAMES = 10_000
"""Frames per sequence (``dataset sequences --frames``): 1000 s of driving past at 10 Hz, 10 times a KITTI tracking
sequence; 10^8 ran for ever."""
MAX_SEQUENCES = 100_000
"""Sequences in one call (``dataset sequences --sequences``): 100 times nuScenes' 850 scenes' worth of vehicles is
not one call's job (without a bound any count was accepted, to run for ever)."""
HZ_RANGE = (0.1, 1000.0)
"""Frame rates (``--hz``), Hz: spinning LiDARs turn at 5-20 Hz; far outside, the vehicle's positions (speed / rate
per frame) overflowed (1e-300 Hz put it 1e301 m away, with NumPy overflow warnings)."""


@dataclass(frozen=True)
class SequenceSpec:
    """How sequences are drawn: frames, rate, trajectory ranges, noise."""

    n_frames: int = 20
    hz: float = 10.0
    lateral_m: tuple = (4.0, 12.0)
    speed_mps: tuple = (3.0, 12.0)
    noise: BoxNoise = BoxNoise()

    def __post_init__(self):
        if not 1 <= self.n_frames <= MAX_FRAMES:
            raise ParameterError(f"`frames`: a sequence has 1..{MAX_FRAMES} frames, got {self.n_frames}", "frames")
        lo, hi = HZ_RANGE
        if not (math.isfinite(self.hz) and lo <= self.hz <= hi):
            raise ParameterError(f"`hz`: the frame rate must be in [{lo:g}, {hi:g}] Hz, got {self.hz:g}", "hz")


VEHICLE_LENGTH_M = (0.5, 50.0)
"""The longest side a mesh may have to drive past the sensor, metres: a toy car is longer than 0.5 m, a road train
shorter than 50 m. Outside, the mesh is not in metres (a 1e-30 m mesh gave scans of no points, exit 0)."""


def load_vehicle_mesh(path):
    """The mesh of ``path`` (:func:`~spotlights.geometry.io.load_mesh`), refused with an
    :class:`~spotlights.errors.InputFileError` naming the file when its longest side is outside
    :data:`VEHICLE_LENGTH_M`."""
    mesh = load_mesh(path)
    longest = float(np.ptp(np.asarray(mesh.vertices), axis=0).max())
    lo, hi = VEHICLE_LENGTH_M
    if not lo <= longest <= hi:
        raise InputFileError(
            path, f"the mesh is {longest:.3g} m long: a vehicle to drive past is {lo:g}-{hi:g} m (is it in metres?)"
        )
    return mesh


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


def _check_sequence_count(n_sequences: int) -> None:
    """``--sequences``: 1..:data:`MAX_SEQUENCES` (checked before any output)."""
    if not 1 <= n_sequences <= MAX_SEQUENCES:
        raise ParameterError(f"`sequences`: 1..{MAX_SEQUENCES} sequences, got {n_sequences}", "sequences")


def write_sequences(
    meshes: list, out, n_sequences: int, spec: SequenceSpec, seed: int = 0, sensor: str = "hdl64e"
) -> list[Path]:
    """Simulate ``n_sequences`` sequences (mesh ``i % len(meshes)`` for sequence ``i``) into ``out``.

    meshes : mesh files (z up, x forward, metres). Returns the ``sequence.json`` paths written. Every file
    is written atomically; a sequence is complete when its ``sequence.json`` exists (written last). When a write
    fails (a full disk), the sequence folders this call made are removed before the error goes on.
    """
    _check_sequence_count(n_sequences)
    if not meshes:
        raise ParameterError("no mesh to simulate")
    sens = sensor_preset(sensor)
    out = Path(out)
    loaded: dict[int, tuple] = {}
    written = []
    made_here: list[Path] = []  # the sequence folders this call creates
    try:
        for i in range(n_sequences):
            j = i % len(meshes)
            if j not in loaded:
                mesh = load_vehicle_mesh(meshes[j])
                loaded[j] = (mesh, np.asarray(mesh.vertices), np.asarray(mesh.faces))
            mesh, v, f = loaded[j]
            rng = np.random.default_rng([seed, i])
            seq = simulate_sequence(v, f, sens, spec, rng)
            name = f"seq{i:04d}"
            folder = out / name
            if not folder.exists():
                made_here.append(folder)
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
    except BaseException:
        # a full disk (or Ctrl-C) midway: the run is incomplete; the sequence folders this call made go with what
        # they hold (an empty or half folder was left, and a run is written whole or not at all)
        for made in made_here:
            shutil.rmtree(made, ignore_errors=True)
        raise
    return written


H5_FORMAT = "spotlights-sequences"
H5_FORMAT_VERSION = 1
_MESHES: dict = {}


def _box_row(b: Box) -> list[float]:
    return [*map(float, b.center), *map(float, b.size), float(b.yaw)]


def _sequence_arrays(job: tuple) -> dict:
    """Sequence ``i`` of a build (a :func:`process_map` unit): its frames as arrays (see the module docstring)."""
    mesh_path, i, seed, spec, sensor = job
    if mesh_path not in _MESHES:
        _MESHES.clear()
        mesh = load_vehicle_mesh(mesh_path)
        _MESHES[mesh_path] = (mesh, np.asarray(mesh.vertices), np.asarray(mesh.faces))
    mesh, v, f = _MESHES[mesh_path]
    rng = np.random.default_rng([seed, i])
    seq = simulate_sequence(v, f, sensor_preset(sensor), spec, rng)
    gt = (sample_surface(mesh, 2048, seed=rng) - seq["center_in_mesh"]).astype(np.float32)
    frs = seq["frames"]
    return dict(
        gt=gt,
        trajectory=json.dumps(seq["trajectory"], sort_keys=True),
        timestamp=np.array([fr["timestamp"] for fr in frs], np.float64),
        n_points=np.array([len(fr["points"]) for fr in frs], np.int32),
        points=np.concatenate([fr["points"] for fr in frs]).astype(np.float32).reshape(-1, 3),
        true_box=np.array([_box_row(fr["true_box"]) for fr in frs], np.float64),
        noisy_box=np.array([_box_row(fr["noisy_box"]) for fr in frs], np.float64),
        sensor_in_true_unit=np.stack([fr["true_box"].to_unit(np.zeros(3)) for fr in frs]),
        sensor_in_noisy_unit=np.stack([fr["noisy_box"].to_unit(np.zeros(3)) for fr in frs]),
    )


def write_sequences_h5(
    meshes: list, out, n_sequences: int, spec: SequenceSpec, seed: int = 0, sensor: str = "hdl64e", workers: int = 1
) -> Path:
    """Simulate ``n_sequences`` sequences (mesh ``i % len(meshes)`` for sequence ``i``) into one HDF5 file ``out``
    (the module docstring's layout; written atomically). ``workers`` processes simulate; the bytes do not
    depend on their number. Returns ``out``."""
    _check_sequence_count(n_sequences)
    if not meshes:
        raise ParameterError("no mesh to simulate")
    sensor_preset(sensor)  # an unknown sensor fails before any work
    import h5py

    jobs = [(str(meshes[i % len(meshes)]), i, seed, spec, sensor) for i in range(n_sequences)]
    seqs = list(process_map(_sequence_arrays, jobs, workers, what="sequence"))
    counts = np.array([len(s["timestamp"]) for s in seqs], np.int64)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    n_pts = np.concatenate([s["n_points"] for s in seqs])
    strt = h5py.string_dtype("utf-8")
    out = Path(out)
    with atomic_output(out) as tmp, hdf5_output(tmp, "w", libver=("earliest", "v110")) as (f, _check):
        f.attrs["format"] = H5_FORMAT
        f.attrs["format_version"] = H5_FORMAT_VERSION
        f.attrs["seed"] = int(seed)
        f.attrs["sensor"] = sensor
        f.attrs["noise"] = json.dumps(asdict(spec.noise), sort_keys=True)
        f.attrs["spec"] = json.dumps(
            dict(n_frames=spec.n_frames, hz=spec.hz, lateral_m=list(spec.lateral_m), speed_mps=list(spec.speed_mps)),
            sort_keys=True,
        )
        f.attrs["n_sequences"] = int(n_sequences)
        f.attrs["n_frames"] = int(counts.sum())

        def put(g, name, data, dtype=None):
            a = np.asarray(data, dtype=dtype) if dtype is not strt else np.array(data, dtype=object)
            kw = {} if dtype is strt or a.ndim == 0 else COMPRESSION
            g.create_dataset(name, data=a, dtype=dtype or a.dtype, track_times=False, **kw)

        g = f.create_group("sequences")
        put(g, "mesh", [j[0] for j in jobs], strt)
        put(g, "track_id", [str(i) for i in range(n_sequences)], strt)
        put(g, "trajectory", [s["trajectory"] for s in seqs], strt)
        put(g, "first_frame", first, np.int64)
        put(g, "n_frames", counts, np.int32)
        put(g, "gt", np.stack([s["gt"] for s in seqs]), np.float32)
        g = f.create_group("frames")
        put(g, "sequence", np.repeat(np.arange(n_sequences), counts), np.int32)
        put(g, "frame", np.concatenate([np.arange(c) for c in counts]), np.int32)
        put(g, "timestamp", np.concatenate([s["timestamp"] for s in seqs]), np.float64)
        put(g, "track_id", [str(i) for i, c in enumerate(counts) for _ in range(c)], strt)
        put(g, "point_start", np.concatenate([[0], np.cumsum(n_pts)[:-1]]), np.int64)
        put(g, "n_points", n_pts, np.int32)
        for k in ("true_box", "noisy_box", "sensor_in_true_unit", "sensor_in_noisy_unit"):
            put(g, k, np.concatenate([s[k] for s in seqs]), np.float64)
        put(g, "sensor_origin", np.zeros((int(counts.sum()), 3)), np.float64)
        put(f, "points", np.concatenate([s["points"] for s in seqs]), np.float32)
    return out


def read_sequences_h5(path) -> list[dict]:
    """The sequences of a :func:`write_sequences_h5` file: per sequence {"mesh", "track_id", "gt" (2048, 3),
    "frames": [{"points" (K, 3) float32 sensor frame, "true_box", "noisy_box": Box, "timestamp": s,
    "sensor_origin" (3,)}]}. One-line :class:`InputFileError` for a file of another format."""
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputFileError(path, f"is not an HDF5 file ({exc})") from None
    with f:
        if f.attrs.get("format") != H5_FORMAT:
            raise InputFileError(path, f"is not a {H5_FORMAT} file (format {f.attrs.get('format')!r})")
        s, fr = f["sequences"], f["frames"]
        pts = f["points"][:]
        start, npt = fr["point_start"][:], fr["n_points"][:]
        rows = {k: fr[k][:] for k in ("true_box", "noisy_box", "timestamp", "sensor_origin")}
        out = []
        for q in range(len(s["n_frames"])):
            a, n = int(s["first_frame"][q]), int(s["n_frames"][q])
            tid = s["track_id"][q].decode()
            frames = []
            for r in range(a, a + n):
                boxes = [
                    Box.from_yaw(rows[k][r, :3], rows[k][r, 3:6], float(rows[k][r, 6]), "car", "car", tid)
                    for k in ("true_box", "noisy_box")
                ]
                frames.append(
                    dict(
                        points=pts[start[r] : start[r] + npt[r]],
                        true_box=boxes[0],
                        noisy_box=boxes[1],
                        timestamp=float(rows["timestamp"][r]),
                        sensor_origin=rows["sensor_origin"][r],
                    )
                )
            out.append(dict(mesh=s["mesh"][q].decode(), track_id=tid, gt=s["gt"][q], frames=frames))
    return out


__all__ = [
    "BoxNoise",
    "SequenceSpec",
    "simulate_sequence",
    "write_sequences",
    "write_sequences_h5",
    "read_sequences_h5",
]


def simulate_sequences(
    meshes: str | Path,
    out: str | Path,
    n_sequences: int,
    spec: SequenceSpec,
    seed: int = 0,
    sensor: str = "hdl64e",
    workers: int = 1,
) -> Path:
    """What ``spotlights dataset sequences`` does: the meshes of ``meshes`` (a file or a folder,
    :func:`mesh_files`) driven past the sensor into ``out``, one HDF5 file when it ends in ``.h5``/``.hdf5``
    (:func:`write_sequences_h5`, ``workers`` processes, the same bytes for any number), else a folder with one
    ``seqNNNN/`` per sequence (:func:`write_sequences`; removed again if nothing could be written).
    Returns ``out``."""
    _check_sequence_count(n_sequences)  # before any mesh is read
    files = mesh_files(meshes)
    for f in files[:n_sequences]:  # every mesh a sequence drives, checked before anything is written
        load_vehicle_mesh(f)
    if Path(out).suffix.lower() in (".h5", ".hdf5"):
        return write_sequences_h5(files, out, n_sequences, spec, seed, sensor, workers)
    with output_folder(out) as folder:
        write_sequences(files, folder, n_sequences, spec, seed=seed, sensor=sensor)
    return Path(out)
