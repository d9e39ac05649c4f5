"""Synthetic completion dataset: simulated LiDAR partial scans + per-model ground truth.

The paper's recipe (Section 5.1) for any folder of meshes: every model gets
``views`` partial observations from a simulated spinning LiDAR (see
:mod:`spotlights.data.lidar`), each resampled to 256 points, and one ground
truth shared by its observations: 2048 and 16384 uniform surface points and the
Spotlights depth arrays of one or more rigs. Everything of a sample lives in the
unit frame of the vehicle's box (the paper's normalisation), and the transform
from the sensor frame is stored with each sample.

Work and determinism
--------------------
Work units are (model, ground truth) and (model, block of views). Every random
number of view ``v`` of model ``m`` comes from
``SeedSequence(seed, spawn_key=(model_key(name_m), 1, v))`` (ground truth: stream
2 and 3), where ``model_key`` is a hash of the model's name: results depend on
neither the number of workers, nor the order of completion, nor the block size,
nor which other meshes are in the folder.

Resumability
------------
Workers write each finished unit to ``OUT.parts/`` atomically (temporary name,
then rename); a unit whose shard exists is never recomputed. ``OUT.parts/plan.json``
records the configuration and the model list: a later run resumes only the
same plan. When all units exist, the HDF5 file is written (streaming, one shard
at a time) under a temporary name and renamed onto ``OUT``; the parts are then
deleted.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import re
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .._version import __version__
from ..errors import InputFileError, ParameterError, SpotlightsError
from ..geometry.io import MESH_SUFFIXES, load_mesh
from ..geometry.rig import Rig, RigSpec, make_rig
from ..utils import atomic_output, exclusive_lock
from .lidar import LidarSimulator, SensorModel, VehiclePose, hdl64e
from .store import FORMAT, FORMAT_VERSION, SAMPLE_FIELDS, SPLITS, write_dataset

PLAN_VERSION = 1
# Seed streams (the second spawn-key word).
STREAM_VIEWS, STREAM_GT_POINTS, STREAM_GT_DENSE, STREAM_SPLIT = 1, 2, 3, 4
# Clearance between the sensor and the vehicle's footprint (metres), on top of its half diagonal.
SENSOR_CLEARANCE = 0.5


# ----------------------------------------------------------------------------------------------
# configuration
# ----------------------------------------------------------------------------------------------
def parse_rig(spec: "str | Rig | RigSpec") -> "Rig | RigSpec":
    """A rig from ``"NxM"``, ``"NxM@DEG"`` (e.g. ``"64x32@60"``) or a rig name.

    Cap rigs (``"64x32@60"``, ``"cap-32x64-60"``) give the :class:`Rig` itself (its rays do
    not depend on the object). Box-targeted rig names (``"box-32x64-ellipsoid-s1"``, any
    :attr:`RigSpec.name`) give a :class:`RigSpec`: each model's depths use the rig of its own
    box (``spec.for_box(size / 2R)``, see docs/box-rig.md).
    """
    if isinstance(spec, Rig):
        return spec
    if isinstance(spec, RigSpec):
        return spec if spec.needs_box else spec.for_box(None)
    s = str(spec).strip().lower()
    if s.startswith("box-"):
        return RigSpec.from_name(s)
    m = re.fullmatch(r"(\d+)x(\d+)(?:@(\d+(?:\.\d*)?|\.\d+))?", s) or re.fullmatch(r"cap-(\d+)x(\d+)-(\d+(?:\.\d*)?)", s)
    if not m:
        raise ParameterError(f"rig {spec!r} not understood; write NxM or NxM@DEG, e.g. 64x32@60 (N viewpoints, "
                             "M rays each, cap half-angle in degrees, default 60), or a rig name such as "
                             "cap-32x64-60 or box-32x64-ellipsoid-s1 (box-targeted, docs/box-rig.md)")
    return make_rig(int(m.group(1)), int(m.group(2)), angle=float(m.group(3)) if m.group(3) else 60.0)


def parse_split(spec: str) -> tuple[str, list[float]]:
    """Parse ``"64/8/7"`` (model counts: integers) or ``"0.8/0.1/0.1"`` (fractions summing to 1).

    Returns ``("counts" | "fractions", [train, val, test])``.
    """
    parts = [p.strip() for p in str(spec).replace(",", "/").split("/")]
    if len(parts) != 3 or not all(parts):
        raise ParameterError(f"split {spec!r}: give three parts train/val/test, e.g. 64/8/7 or 0.8/0.1/0.1")
    try:
        if all(re.fullmatch(r"\d+", p) for p in parts):
            vals = [int(p) for p in parts]
            return "counts", vals
        vals = [float(p) for p in parts]
    except ValueError:
        raise ParameterError(f"split {spec!r}: parts must be numbers") from None
    if any(not math.isfinite(v) or v < 0 for v in vals):
        raise ParameterError(f"split {spec!r}: parts must be >= 0")
    if abs(sum(vals) - 1.0) > 1e-6:
        raise ParameterError(f"split {spec!r}: fractions add up to {sum(vals):g}, not 1")
    return "fractions", vals


@dataclass
class BuildConfig:
    """Everything that determines a dataset's content (stored as ``config_json``).

    meshes : folder of meshes (sub-folders = categories) or with a manifest.
    manifest : CSV with columns ``file`` and ``category`` (optional ``up``, ``forward``, ``split``);
        default: ``MESHES/manifest.csv`` when it exists.
    views : partial observations per model.
    split : ``"64/8/7"`` model counts or ``"0.81/0.1/0.09"`` fractions (train/val/test).
    seed : root seed (>= 0).
    n_points : points per partial observation.
    gt_points, gt_dense : uniform surface samples per model (paper: 2048 and 16384).
    default_rig : the rig of the SA-Net ground truth (paper: 32 x 64, 60 deg).
    extra_rigs : more rigs whose ground truth is stored too (ablations: 64x32@60, 256x64@60;
        box-targeted rigs by name, e.g. box-32x64-ellipsoid-s1: each model uses its own box).
    sensor : the LiDAR model (dict of :class:`SensorModel`).
    distance : (min, max) horizontal distance of the box centre from the sensor, metres.
    min_points : fewest returns an observation may have; fewer and the pose is redrawn.
    max_draws : poses tried per observation before giving up on the model (an error).
    downsample : ``"random"`` (subset without replacement) or ``"fps"`` (farthest-point).
    up, forward : the mesh files' up and forward axes (object frame: x forward, y left, z up).
    scale : factor applied to the mesh coordinates (meshes must be in metres for the sensor).
    stratify : assign the split per category (keeps category proportions) or over all models.
    """

    meshes: str = ""
    manifest: str | None = None
    views: int = 2000
    split: str = "0.81/0.1/0.09"
    seed: int = 0
    n_points: int = 256
    gt_points: int = 2048
    gt_dense: int = 16384
    default_rig: str = "32x64@60"
    extra_rigs: list = field(default_factory=list)
    sensor: dict = field(default_factory=lambda: hdl64e().to_dict())
    distance: tuple = (4.0, 40.0)
    min_points: int = 50
    max_draws: int = 100
    downsample: str = "random"
    up: str = "z"
    forward: str = "x"
    scale: float = 1.0
    stratify: bool = True

    def validate(self) -> "BuildConfig":
        """Check every field (raises ParameterError); normalises rig specs and tuples."""
        for name in ("views", "n_points", "gt_points", "gt_dense", "max_draws"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and v >= 1):
                raise ParameterError(f"{name.replace('_', ' ')} must be an integer >= 1, got {v!r}")
        if not (isinstance(self.seed, (int, np.integer)) and self.seed >= 0):
            raise ParameterError(f"seed must be an integer >= 0, got {self.seed!r}")
        if not (isinstance(self.min_points, (int, np.integer)) and self.min_points >= 1):
            raise ParameterError(f"min points must be an integer >= 1, got {self.min_points!r}")
        d = tuple(float(x) for x in self.distance)
        if len(d) != 2 or not (0.0 < d[0] < d[1]) or not all(math.isfinite(x) for x in d):
            raise ParameterError(f"distance range must be MIN:MAX metres with 0 < MIN < MAX, got {self.distance!r}")
        self.distance = d
        if self.downsample not in ("random", "fps"):
            raise ParameterError(f"downsample must be 'random' or 'fps', got {self.downsample!r}")
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ParameterError(f"scale must be > 0, got {self.scale!r}")
        parse_split(self.split)
        self.default_rig = parse_rig(self.default_rig).name
        extra = []
        for r in self.extra_rigs:
            name = parse_rig(r).name
            if name != self.default_rig and name not in extra:
                extra.append(name)
        self.extra_rigs = extra
        sensor = SensorModel.from_dict(self.sensor)
        self.sensor = sensor.to_dict()
        if sensor.max_range <= d[0]:
            raise ParameterError(f"the sensor's range ({sensor.max_range} m) does not reach {d[0]} m")
        return self

    @property
    def rigs(self) -> "list[Rig | RigSpec]":
        """[default rig, extra rigs...]: cap :class:`Rig` objects, box-targeted :class:`RigSpec` objects."""
        return [parse_rig(self.default_rig)] + [parse_rig(r) for r in self.extra_rigs]

    @property
    def sensor_model(self) -> SensorModel:
        """The :class:`SensorModel` of ``sensor``."""
        return SensorModel.from_dict(self.sensor)

    def to_dict(self) -> dict:
        """JSON-serialisable dict (what ``config_json`` stores)."""
        d = asdict(self)
        d["distance"] = list(self.distance)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "BuildConfig":
        """Rebuild and validate a config from :meth:`to_dict` output (unknown keys ignored)."""
        cfg = cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})
        return cfg.validate()


# ----------------------------------------------------------------------------------------------
# models: discovery, loading, split
# ----------------------------------------------------------------------------------------------
@dataclass
class ModelEntry:
    """One mesh of the dataset: ``name`` (relative path without suffix), ``file`` (relative path),
    ``category``, its axes, an optional split from the manifest, and its file's SHA-256."""

    name: str
    file: str
    category: str
    up: str
    forward: str
    split: str | None = None
    sha256: str = ""


def model_key(name: str) -> int:
    """A stable 63-bit integer for a model name (seeds its random streams)."""
    return int.from_bytes(hashlib.sha256(name.encode("utf-8")).digest()[:8], "little") >> 1


def discover_models(folder: str | os.PathLike, manifest: str | os.PathLike | None = None, up: str = "z",
                    forward: str = "x") -> tuple[list[ModelEntry], list[dict]]:
    """Find the meshes of a dataset and their categories.

    With a manifest (``manifest`` or ``FOLDER/manifest.csv``): its rows, columns ``file``
    (relative to the folder) and ``category`` (optional ``up``, ``forward``, ``split``).
    Without: every mesh file under ``folder`` (sorted); the category is the first sub-folder
    (files directly in ``folder`` take the folder's name).

    Returns ``(entries sorted by name, problems)`` where problems are ``{"file", "problem"}``
    for manifest rows whose file is missing.
    """
    root = Path(folder)
    if not root.exists():
        raise InputFileError(root, "no such folder")
    if not root.is_dir():
        raise InputFileError(root, "is not a folder of meshes")
    man = Path(manifest) if manifest else (root / "manifest.csv" if (root / "manifest.csv").exists() else None)
    entries: list[ModelEntry] = []
    problems: list[dict] = []
    if man is not None:
        if not man.exists():
            raise InputFileError(man, "no such manifest")
        try:
            with open(man, newline="") as fh:
                rows = list(csv.DictReader(fh))
        except (OSError, UnicodeDecodeError, csv.Error) as exc:
            raise InputFileError(man, f"cannot read the manifest CSV ({exc})") from None
        if not rows or "file" not in rows[0]:
            raise InputFileError(man, "manifest needs a header with a 'file' column (and 'category')")
        for row in rows:
            rel = (row.get("file") or "").strip()
            if not rel:
                continue
            p = root / rel
            cat = (row.get("category") or "").strip() or (Path(rel).parts[0] if len(Path(rel).parts) > 1 else root.name)
            split = (row.get("split") or "").strip().lower() or None
            if split is not None and split not in SPLITS:
                raise InputFileError(man, f"row {rel}: split {split!r} is not one of {', '.join(SPLITS)}")
            if not p.is_file():
                problems.append({"file": rel, "problem": "listed in the manifest but missing"})
                continue
            entries.append(ModelEntry(name=str(Path(rel).with_suffix("").as_posix()), file=Path(rel).as_posix(),
                                      category=cat, up=(row.get("up") or "").strip() or up,
                                      forward=(row.get("forward") or "").strip() or forward, split=split))
    else:
        files = sorted(p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in MESH_SUFFIXES
                       and not any(part.startswith(".") for part in p.relative_to(root).parts))
        for p in files:
            rel = p.relative_to(root)
            cat = rel.parts[0] if len(rel.parts) > 1 else root.name
            entries.append(ModelEntry(name=rel.with_suffix("").as_posix(), file=rel.as_posix(), category=cat,
                                      up=up, forward=forward))
    if not entries and not problems:
        raise InputFileError(root, f"no mesh files ({' '.join(MESH_SUFFIXES)}) found" +
                             (f" from manifest {man}" if man else ""))
    names = [e.name for e in entries]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputFileError(root, f"several mesh files share the name {dup[0]!r} (differing only by suffix)")
    entries.sort(key=lambda e: e.name)
    return entries, problems


@dataclass
class LoadedModel:
    """A mesh ready for simulation: object-frame (x forward, y left, z up, metres) float64
    ``vertices`` (V, 3) without unreferenced vertices, int64 ``faces`` (F, 3)."""

    entry: ModelEntry
    vertices: np.ndarray
    faces: np.ndarray


def load_model(root: Path, entry: ModelEntry, scale: float = 1.0) -> LoadedModel:
    """Load one mesh (validated by :func:`~spotlights.geometry.io.load_mesh`), drop unreferenced
    vertices (they would enlarge the box), scale it and hash its file. Raises InputFileError."""
    path = root / entry.file
    mesh = load_mesh(path, up=entry.up, forward=entry.forward)
    used = np.unique(mesh.faces)
    remap = np.full(len(mesh.vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    v = np.asarray(mesh.vertices, dtype=np.float64)[used] * float(scale)
    f = remap[np.asarray(mesh.faces, dtype=np.int64)]
    entry.sha256 = hashlib.sha256(path.read_bytes()).hexdigest()
    return LoadedModel(entry=entry, vertices=v, faces=f)


def assign_splits(categories: list[str], spec: str, seed: int, stratify: bool = True,
                  fixed: list[str | None] | None = None) -> list[str]:
    """Assign every model to train/val/test.

    Parameters
    ----------
    categories : category of each model (in model order).
    spec : ``"64/8/7"`` counts (must add up to the number of models) or fractions
        (counts by the largest-remainder rule).
    seed : root seed; the assignment is a seeded permutation.
    stratify : when True, models are shuffled within each category and the categories laid
        end to end; splits are dealt along that list by an evenly spread label sequence, so every
        split gets each category in proportion (up to rounding) with the exact total counts.
    fixed : optional split per model from a manifest; when every model has one it is used as is.

    Returns
    -------
    list of split names, one per model.
    """
    n = len(categories)
    if fixed is not None and all(s is not None for s in fixed):
        return list(fixed)
    if fixed is not None and any(s is not None for s in fixed):
        raise ParameterError("the manifest gives a split for some models but not all")
    kind, vals = parse_split(spec)
    if kind == "counts":
        counts = [int(v) for v in vals]
        if sum(counts) != n:
            raise ParameterError(f"split {spec} adds up to {sum(counts)} models but there are {n} usable meshes")
    else:
        raw = [v * n for v in vals]
        counts = [int(math.floor(r)) for r in raw]
        order = sorted(range(3), key=lambda i: (-(raw[i] - counts[i]), i))
        for i in order[: n - sum(counts)]:
            counts[i] += 1
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(0, STREAM_SPLIT)))
    if stratify:
        cats = sorted(set(categories))
        order = []
        for c in cats:
            members = [i for i in range(n) if categories[i] == c]
            order.extend(members[j] for j in rng.permutation(len(members)))
    else:
        order = [int(i) for i in rng.permutation(n)]
    # Evenly spread label sequence with exact counts (largest deficit first, ties by split order).
    labels = []
    assigned = [0, 0, 0]
    for j in range(n):
        deficit = [counts[s] * (j + 1) / max(n, 1) - assigned[s] for s in range(3)]
        s = max((s for s in range(3) if assigned[s] < counts[s]), key=lambda s: (deficit[s], -s))
        assigned[s] += 1
        labels.append(SPLITS[s])
    out = [""] * n
    for pos, i in enumerate(order):
        out[i] = labels[pos]
    return out


# ----------------------------------------------------------------------------------------------
# per-model computations
# ----------------------------------------------------------------------------------------------
def _rng(seed: int, name: str, *stream: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(model_key(name),) + tuple(stream)))


def model_ground_truth(model: LoadedModel, cfg: BuildConfig) -> dict:
    """Ground truth of one model in its unit frame (axis-aligned box, R = half diagonal).

    Returns ``gt_points`` (gt_points, 3) f32, ``gt_dense`` (gt_dense, 3) f32, ``center`` (3,) f64,
    ``radius`` f64, ``size`` (3,) f64 (metres), ``depths`` list of (N*M,) f32 in ``cfg.rigs`` order
    (``MeshProbe(mesh).encode(rig)`` of the core; a box-targeted spec is resolved for this
    model's box, ``spec.for_box(size / 2R)``).
    """
    import trimesh

    from ..geometry.encode import MeshProbe
    from ..geometry.frames import normalization_from_mesh
    from ..geometry.sampling import sample_surface

    mesh = trimesh.Trimesh(model.vertices, model.faces, process=False, validate=False)
    norm = normalization_from_mesh(mesh)
    name = model.entry.name
    pts = sample_surface(mesh, cfg.gt_points, _rng(cfg.seed, name, STREAM_GT_POINTS))
    dense = sample_surface(mesh, cfg.gt_dense, _rng(cfg.seed, name, STREAM_GT_DENSE))
    probe = MeshProbe(mesh, norm)
    return {
        "gt_points": norm.to_unit(pts).astype(np.float32),
        "gt_dense": norm.to_unit(dense).astype(np.float32),
        "center": norm.center, "radius": np.float64(norm.radius), "size": norm.size,
        "depths": [probe.encode(r) for r in cfg.rigs],
    }


def simulate_views(sim: LidarSimulator, model: LoadedModel, cfg: BuildConfig, views: range,
                   timings: dict | None = None) -> dict:
    """Partial observations ``views`` of one model.

    Each view: draw a pose (distance uniform in ``cfg.distance`` but at least the footprint's half
    diagonal + 0.5 m; bearing and heading uniform), scan; with fewer than ``min_points`` returns,
    draw again (at most ``max_draws`` times, then an error). Resample to ``n_points`` (more:
    ``downsample``; fewer: repeat random points), map into the unit frame of the vehicle's box.

    Returns arrays over the B views: ``partial`` (B, n_points, 3) f32 unit frame and the per-sample
    fields of :data:`~spotlights.data.store.SAMPLE_FIELDS` (``sensor_to_unit`` (B, 4, 4) f64, ...).
    """
    from ..geometry.sampling import resample

    name = model.entry.name
    b = len(views)
    out = {"partial": np.empty((b, cfg.n_points, 3), dtype=np.float32)}
    for k, (dt, shp) in SAMPLE_FIELDS.items():
        out[k] = np.zeros((b,) + shp, dtype=dt)
    dmin = max(cfg.distance[0], sim.footprint_radius + SENSOR_CLEARANCE)
    dmax = cfg.distance[1]
    if dmin >= dmax:
        raise SpotlightsError(f"{model.entry.file}: the mesh is too large ({sim.size[0]:.1f} x {sim.size[1]:.1f} m "
                              f"footprint) for the distance range {cfg.distance[0]:g}-{dmax:g} m; is it in metres? "
                              "(see --scale)")
    center, radius = sim.center, 0.5 * float(np.linalg.norm(sim.size))
    for j, v in enumerate(views):
        rng = _rng(cfg.seed, name, STREAM_VIEWS, int(v))
        t0 = time.perf_counter()
        for draw in range(1, cfg.max_draws + 1):
            pose = VehiclePose(distance=float(rng.uniform(dmin, dmax)), azimuth=float(rng.uniform(-np.pi, np.pi)),
                               heading=float(rng.uniform(-np.pi, np.pi)))
            scan = sim.scan(pose, rng, timings)
            if len(scan.points) >= cfg.min_points:
                break
        else:
            raise SpotlightsError(
                f"{model.entry.file}: view {v}: no pose out of {cfg.max_draws} gave {cfg.min_points} LiDAR returns "
                f"(last: {len(scan.points)}); the mesh may be too small or not in metres (see --scale), or lower "
                "--min-points")
        t1 = time.perf_counter()
        pts = resample(scan.points, cfg.n_points, rng, method=cfg.downsample)
        out["partial"][j] = (pts - center) / radius
        out["sensor_to_unit"][j] = sim.box_normalization(pose).matrix
        out["model"][j] = -1  # filled in by the caller (model row)
        out["view"][j] = v
        out["distance"][j] = pose.distance
        out["azimuth"][j] = pose.azimuth
        out["heading"][j] = pose.heading
        out["n_raw"][j] = len(scan.points)
        out["n_draws"][j] = draw
        out["n_rays"][j] = scan.n_rays
        if timings is not None:
            timings["resample"] = timings.get("resample", 0.0) + (time.perf_counter() - t1)
            timings["views"] = timings.get("views", 0) + 1
            timings["draws"] = timings.get("draws", 0) + draw
            timings["pose_loop"] = timings.get("pose_loop", 0.0) + (t1 - t0)
    return out


# ----------------------------------------------------------------------------------------------
# the build: plan, parallel units, shards, consolidation
# ----------------------------------------------------------------------------------------------
@dataclass
class BuildReport:
    """What a build did: counts, timings (seconds) and the output size (bytes)."""

    out: str
    n_models: int
    n_samples: int
    units_total: int
    units_done_before: int
    units_computed: int
    skipped: list
    seconds_units: float = 0.0
    seconds_consolidate: float = 0.0
    seconds_total: float = 0.0
    file_size: int = 0
    already_complete: bool = False


_WORKER: dict = {}


def _init_worker(state: dict, quiet_sigint: bool) -> None:
    """Pool initializer: keep the shared state (config, meshes, parts folder); ignore Ctrl-C
    (the parent handles it and terminates the pool)."""
    import signal

    if quiet_sigint:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # pool.terminate() must end a worker at once
    _WORKER.clear()
    _WORKER.update(state)
    _WORKER["sims"] = {}
    # the process that started this worker (the fork server of process_pool_context, which exits
    # with the build): when it is gone, the build was killed
    _WORKER["parent"] = os.getppid() if quiet_sigint else None


def _shard_name(unit: tuple) -> str:
    if unit[0] == "gt":
        return f"gt-{unit[1]:05d}.npz"
    return f"obs-{unit[1]:05d}-{unit[2]:07d}-{unit[3]:07d}.npz"


def _save_npz_atomic(path: Path, arrays: dict) -> None:
    with atomic_output(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())


def _run_unit(unit: tuple) -> tuple:
    """Compute one unit in a worker and write its shard; returns ``(unit, seconds)``."""
    t0 = time.perf_counter()
    cfg: BuildConfig = _WORKER["cfg"]
    models: list[LoadedModel] = _WORKER["models"]
    parts: Path = _WORKER["parts"]
    m = unit[1]
    model = models[m]
    if unit[0] == "gt":
        gt = model_ground_truth(model, cfg)
        arrays = {k: gt[k] for k in ("gt_points", "gt_dense", "center", "radius", "size")}
        for i, d in enumerate(gt["depths"]):
            arrays[f"depths_{i}"] = d
    else:
        sims = _WORKER["sims"]
        if m not in sims:
            sims.clear()  # units arrive model by model: keep one BVH
            sims[m] = LidarSimulator(model.vertices, model.faces, cfg.sensor_model)
        arrays = simulate_views(sims[m], model, cfg, range(unit[2], unit[3]))
        arrays["model"][:] = m
    _save_npz_atomic(parts / _shard_name(unit), arrays)
    if _WORKER.get("parent") is not None and os.getppid() != _WORKER["parent"]:
        os._exit(0)  # the build was killed: the shard is saved, leave quietly instead of a broken pipe
    return unit, time.perf_counter() - t0


def _plan_units(n_models: int, views: int, block: int) -> list[tuple]:
    units = [("gt", m) for m in range(n_models)]
    for m in range(n_models):
        for a in range(0, views, block):
            units.append(("obs", m, a, min(views, a + block)))
    return units


def _default_log(msg: str) -> None:
    from tqdm import tqdm

    tqdm.write(msg, file=sys.stderr)


def build_dataset(cfg: BuildConfig, out: str | os.PathLike, workers: int | None = None, overwrite: bool = False,
                  resume: bool = False, block: int | None = None, keep_parts: bool = False, progress: bool = True,
                  log: Callable[[str], None] | None = None) -> BuildReport:
    """Build (or finish) a completion dataset file.

    Parameters
    ----------
    cfg : the build configuration (validated here).
    out : the HDF5 file to write; its work folder is ``OUT.parts``.
    workers : processes (default: all cores). Results do not depend on it.
    overwrite : replace an existing ``out`` and discard unfinished parts.
    resume : accept an existing complete ``out`` (nothing to do). Unfinished parts of the same
        plan are always resumed.
    block : views per work unit (default: ~views/8, at most 250); only affects scheduling.
    keep_parts : keep ``OUT.parts`` after the file is written.
    progress : show progress bars.
    log : where warnings go (default: stderr).

    Returns
    -------
    :class:`BuildReport`.
    """
    t_start = time.perf_counter()
    log = log or _default_log
    cfg = cfg.validate()
    out = Path(out)
    parts = out.with_name(out.name + ".parts")
    if out.is_dir():
        raise InputFileError(out, "is a folder; give the dataset file to write (e.g. cars.h5)")
    if out.exists() and not overwrite:
        if not resume:
            raise InputFileError(out, "already exists; pass --overwrite to rebuild it (or --resume to accept it)")
        from .store import open_dataset

        with open_dataset(out) as ds:
            if BuildConfig.from_dict(ds.config).to_dict() != cfg.to_dict():
                raise InputFileError(out, "exists and was built with a different configuration; pass --overwrite")
            return BuildReport(str(out), ds.n_models, ds.n_samples, 0, 0, 0, [], already_complete=True,
                               file_size=out.stat().st_size)
    workers = max(1, int(workers or os.cpu_count() or 1))

    root = Path(cfg.meshes)
    entries, skipped = discover_models(root, cfg.manifest, cfg.up, cfg.forward)
    models: list[LoadedModel] = []
    from tqdm import tqdm

    for e in tqdm(entries, desc="load meshes", unit="mesh", disable=not progress or len(entries) < 20, leave=False):
        try:
            models.append(load_model(root, e, cfg.scale))
        except InputFileError as exc:
            skipped.append({"file": e.file, "problem": exc.problem})
    for s in skipped:
        log(f"warning: skipping {root / s['file']}: {s['problem']}")
    if not models:
        raise InputFileError(root, f"none of the {len(entries) + len(skipped)} meshes could be read")
    splits = assign_splits([m.entry.category for m in models], cfg.split, cfg.seed, cfg.stratify,
                           [m.entry.split for m in models])
    for m, s in zip(models, splits):
        m.entry.split = s
    n_models, views = len(models), cfg.views
    block = int(block or max(1, min(250, math.ceil(views / 8))))
    plan = {
        "plan_version": PLAN_VERSION, "config": cfg.to_dict(),
        "models": [asdict(m.entry) for m in models], "skipped": skipped,
    }

    # --- the parts folder: new, resumed, or refused --------------------------------------
    if overwrite and parts.exists():
        shutil.rmtree(parts)
    parts.mkdir(parents=True, exist_ok=True)
    # two builds never write the same shards
    with exclusive_lock(parts / ".lock", f"{parts}: another build is writing this dataset right now"):
        plan_path = parts / "plan.json"
        if plan_path.exists():
            try:
                old = json.loads(plan_path.read_text())
            except (OSError, json.JSONDecodeError):
                raise InputFileError(plan_path, "unreadable build plan; pass --overwrite to start again") from None
            old_block = old.pop("block", block)
            if old != plan:
                diff = sorted(k for k in set(old.get("config", {})) | set(plan["config"])
                              if old.get("config", {}).get(k) != plan["config"].get(k))
                what = f"options differ: {', '.join(diff)}" if diff else "the meshes differ"
                raise InputFileError(parts, f"holds an unfinished build with another plan ({what}); pass --overwrite "
                                            "to discard it, or rerun with the original options")
            block = int(old_block)
        else:
            with atomic_output(plan_path, suffix=".json") as tmp:
                tmp.write_text(json.dumps({**plan, "block": block}, indent=1, sort_keys=True))
        for stale in parts.glob(".*.part*"):  # temporaries of a killed run
            stale.unlink(missing_ok=True)

        units = _plan_units(n_models, views, block)
        pending = [u for u in units if not (parts / _shard_name(u)).exists()]
        done_before = len(units) - len(pending)
        if done_before:
            log(f"resuming {parts}: {done_before} of {len(units)} work units already done")
        state = {"cfg": cfg, "models": models, "parts": parts}
        t_units = time.perf_counter()
        _run_units(pending, state, workers, progress, n_models, views)
        t_cons = time.perf_counter()
        _consolidate(out, parts, cfg, models, skipped, units, state, progress)
        t_end = time.perf_counter()
    if not keep_parts:
        shutil.rmtree(parts, ignore_errors=True)
    return BuildReport(
        out=str(out), n_models=n_models, n_samples=n_models * views, units_total=len(units),
        units_done_before=done_before, units_computed=len(pending), skipped=skipped,
        seconds_units=t_cons - t_units, seconds_consolidate=t_end - t_cons, seconds_total=t_end - t_start,
        file_size=out.stat().st_size)


def _run_units(pending: list, state: dict, workers: int, progress: bool, n_models: int, views: int) -> None:
    """Compute the pending units (in-process for one worker, else a process pool)."""
    from tqdm import tqdm

    n_obs = sum(u[3] - u[2] for u in pending if u[0] == "obs")
    n_gt = sum(1 for u in pending if u[0] == "gt")
    bar = tqdm(total=n_obs, desc="build", unit="sample", disable=not progress, smoothing=0.05, dynamic_ncols=True)
    done_gt = 0

    def advance(unit):
        nonlocal done_gt
        if unit[0] == "gt":
            done_gt += 1
            bar.set_postfix_str(f"ground truth {done_gt}/{n_gt}", refresh=False)
        else:
            bar.update(unit[3] - unit[2])

    try:
        for unit, _ in _map_units(_run_unit, pending, state, workers):
            advance(unit)
    finally:
        bar.close()


def _map_units(fn, items: list, state: dict, workers: int):
    """Yield ``fn(item)`` for every item: in this process when ``workers == 1`` (or one item),
    else unordered on a pool of ``min(workers, len(items))`` processes started from a fork
    server (``spotlights.utils.process_pool_context``), each initialised with ``state``; the
    pool is terminated on any error or when the caller stops early."""
    if workers == 1 or len(items) <= 1:
        _init_worker(state, quiet_sigint=False)
        for item in items:
            yield fn(item)
        return
    from ..utils import process_pool_context

    pool = process_pool_context().Pool(min(workers, len(items)), initializer=_init_worker, initargs=(state, True))
    try:
        yield from pool.imap_unordered(fn, items, chunksize=1)
        pool.close()
    except BaseException:
        pool.terminate()
        raise
    finally:
        pool.join()


def _load_shard(path: Path, unit: tuple, state: dict) -> dict:
    """Read a shard; a shard that cannot be read (e.g. a damaged disk) is recomputed in-process."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except Exception:
        path.unlink(missing_ok=True)
        if not _WORKER or _WORKER.get("parts") != state["parts"]:
            _init_worker(state, quiet_sigint=False)
        _run_unit(unit)
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}


def _consolidate(out: Path, parts: Path, cfg: BuildConfig, models: list, skipped: list, units: list,
                 state: dict, progress: bool) -> None:
    """Stream the shards, in sample order, into ``out`` (written under a temporary name, then renamed)."""
    from tqdm import tqdm

    n = len(models)
    rigs = cfg.rigs
    gts = [_load_shard(parts / _shard_name(("gt", m)), ("gt", m), state) for m in range(n)]
    model_arrays = {
        "name": [m.entry.name for m in models], "file": [m.entry.file for m in models],
        "sha256": [m.entry.sha256 for m in models], "category": [m.entry.category for m in models],
        "split": [m.entry.split for m in models],
        "gt_points": np.stack([g["gt_points"] for g in gts]), "gt_dense": np.stack([g["gt_dense"] for g in gts]),
        "center": np.stack([g["center"] for g in gts]), "radius": np.array([float(g["radius"]) for g in gts]),
        "size": np.stack([g["size"] for g in gts]),
    }
    rig_arrays = [(r, np.stack([g[f"depths_{i}"] for g in gts])) for i, r in enumerate(rigs)]
    del gts
    obs_units = [u for u in units if u[0] == "obs"]
    attrs = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "spotlights_version": __version__,
        "config_json": json.dumps(cfg.to_dict(), sort_keys=True), "seed": int(cfg.seed),
        "sensor_json": json.dumps(cfg.sensor, sort_keys=True), "default_rig": rigs[0].name,
        "views_per_model": int(cfg.views), "skipped_json": json.dumps(skipped, sort_keys=True),
    }

    def blocks():
        bar = tqdm(total=n * cfg.views, desc="write " + out.name, unit="sample", disable=not progress,
                   dynamic_ncols=True)
        try:
            for u in obs_units:
                a = _load_shard(parts / _shard_name(u), u, state)
                if a["partial"].shape != (u[3] - u[2], cfg.n_points, 3) or np.any(a["model"] != u[1]):
                    raise SpotlightsError(f"{parts / _shard_name(u)}: shard does not match the plan; delete it and rerun")
                a["start"] = u[1] * cfg.views + u[2]
                yield a
                bar.update(u[3] - u[2])
        finally:
            bar.close()

    with atomic_output(out, suffix=".h5") as tmp:
        write_dataset(tmp, attrs=attrs, models=model_arrays, rigs=rig_arrays, n_points=cfg.n_points,
                      views_per_model=cfg.views, sample_blocks=blocks())


# ----------------------------------------------------------------------------------------------
# adding a rig to an existing dataset file
# ----------------------------------------------------------------------------------------------
@dataclass
class AddRigReport:
    """What :func:`add_rig` did: the rig added, counts, seconds, the file size (bytes)."""

    out: str
    rig: str
    n_models: int
    n_rays: int
    hit_ratio: float
    seconds_depths: float = 0.0
    seconds_write: float = 0.0
    file_size: int = 0
    already_present: bool = False


def _add_rig_unit(m: int) -> tuple[int, np.ndarray]:
    """Worker: one model's depths for the rig being added (``_WORKER`` holds the job)."""
    import trimesh

    from ..geometry.encode import MeshProbe
    from ..geometry.frames import normalization_from_mesh

    job = _WORKER
    entry, stored = job["entries"][m], job["stored"]
    model = load_model(job["root"], entry, job["scale"])
    want = stored["sha256"][m]
    if want and model.entry.sha256 != want:
        raise InputFileError(job["root"] / entry.file, f"differs from the mesh the dataset was built from (SHA-256 "
                                                      f"{model.entry.sha256[:12]}..., the dataset recorded {want[:12]}...)")
    mesh = trimesh.Trimesh(model.vertices, model.faces, process=False, validate=False)
    norm = normalization_from_mesh(mesh)
    if not (np.array_equal(norm.center, stored["center"][m]) and float(norm.radius) == float(stored["radius"][m])):
        raise InputFileError(job["root"] / entry.file, "normalises differently from the dataset's /models/center and "
                                                      "/models/radius (other --scale/--up/--forward?)")
    return m, MeshProbe(mesh, norm).encode(job["rig"])


def add_rig(path: str | os.PathLike, rig: "str | Rig | RigSpec", meshes: str | os.PathLike | None = None,
            workers: int | None = None, progress: bool = True, log: Callable[[str], None] | None = None) -> AddRigReport:
    """Add the ground-truth depths of one more rig to an existing dataset file, without rebuilding it.

    The depths are exactly those a build with ``--rig RIG`` would have stored: every model's
    mesh is loaded again (``config_json`` records the meshes folder, manifest, axes and scale;
    each file must still have the SHA-256 in ``/models/sha256``), normalised by its box
    (checked against ``/models/center`` and ``/models/radius``) and encoded with
    ``MeshProbe(mesh, norm).encode(rig)``; box-targeted specs use each model's own box. The
    group ``/rigs/<rig.name>`` is written with ``rig_json`` and ``config_json``'s
    ``extra_rigs`` gains the rig's name (so the file's config rebuilds it identically).

    Atomic: the file is copied beside itself, the group added to the copy, and the copy renamed
    onto ``path``; an interrupted run leaves ``path`` untouched (rerun it). The bytes do not
    depend on ``workers``.

    Parameters
    ----------
    path : dataset file (``spotlights-completion``).
    rig : rig name or shorthand (see :func:`parse_rig`), a Rig or a RigSpec.
    meshes : the meshes folder (default: the one ``config_json`` records).
    workers : processes (default: all cores).

    Returns
    -------
    :class:`AddRigReport` (``already_present`` when the file holds the identical rig already).

    A second ``add_rig`` on the same file while one runs raises SpotlightsError (a lock file
    ``.NAME.lock`` beside it), instead of silently losing one of the two rigs.
    """
    from .store import open_dataset

    path = Path(path)
    rig = parse_rig(rig)
    open_dataset(path).close()  # a missing or foreign file fails before a lock file is made beside it
    # Two add-rig runs on one file would each copy it and rename their copy onto it: the last
    # rename would drop the other's rig. A lock beside the file makes the second one fail.
    with exclusive_lock(path.with_name(f".{path.name}.lock"), f"{path}: another 'dataset add-rig' is rewriting this file right now"):
        return _add_rig_locked(path, rig, meshes, workers, progress, log or _default_log)


def _add_rig_locked(path: Path, rig, meshes, workers, progress, log) -> AddRigReport:
    """:func:`add_rig` once the file's lock is held."""
    import h5py
    from tqdm import tqdm

    from .store import open_dataset, write_rig_group

    t0 = time.perf_counter()
    with open_dataset(path) as ds:
        cfg_dict = dict(ds.config)
        if rig.name in ds.rig_names:
            have = json.loads(ds._h5()[f"rigs/{rig.name}"].attrs["rig_json"])
            if have != json.loads(json.dumps(rig.to_dict())):
                raise InputFileError(path, f"holds a different rig under the name {rig.name}")
            return AddRigReport(str(path), rig.name, ds.n_models, rig.n_rays, float("nan"), already_present=True,
                                file_size=path.stat().st_size)
        f = ds._h5()
        stored = {
            "names": [str(x) for x in ds.names],
            "sha256": [x.decode() if isinstance(x, bytes) else str(x) for x in f["models/sha256"][()]]
            if "models/sha256" in f else [""] * ds.n_models,
            "center": np.asarray(ds.center, dtype=np.float64), "radius": np.asarray(ds.radius, dtype=np.float64),
        }
    if not cfg_dict.get("meshes") and meshes is None:
        raise InputFileError(path, "config_json records no meshes folder; pass --meshes DIR")
    cfg = BuildConfig.from_dict(cfg_dict)
    root = Path(meshes) if meshes is not None else Path(cfg.meshes)
    manifest = cfg.manifest if cfg.manifest and Path(cfg.manifest).exists() else None
    entries, _ = discover_models(root, manifest, cfg.up, cfg.forward)
    by_name = {e.name: e for e in entries}
    missing = [n for n in stored["names"] if n not in by_name]
    if missing:
        raise InputFileError(root, f"has no mesh for {len(missing)} of the dataset's models (first: {missing[0]}); "
                                   "pass the meshes folder the dataset was built from (--meshes)")
    state = {"entries": [by_name[n] for n in stored["names"]], "stored": stored, "root": root, "scale": cfg.scale,
             "rig": rig}
    n = len(stored["names"])
    depths = np.zeros((n, rig.n_rays), dtype=np.float32)
    workers = max(1, min(int(workers or os.cpu_count() or 1), n))
    bar = tqdm(total=n, desc=f"depths {rig.name}", unit="model", disable=not progress, dynamic_ncols=True)
    try:
        for m, d in _map_units(_add_rig_unit, list(range(n)), state, workers):
            depths[m] = d
            bar.update(1)
    finally:
        bar.close()
    t1 = time.perf_counter()
    cfg_dict["extra_rigs"] = list(cfg_dict.get("extra_rigs") or []) + [rig.name]
    with atomic_output(path, suffix=".h5") as tmp:
        shutil.copyfile(path, tmp)
        with h5py.File(tmp, "r+") as f:
            write_rig_group(f.require_group("rigs"), rig, depths)
            f.attrs["config_json"] = json.dumps(cfg_dict, sort_keys=True)
    hit = float(np.mean(depths > 0))
    return AddRigReport(str(path), rig.name, n, rig.n_rays, hit, seconds_depths=t1 - t0,
                        seconds_write=time.perf_counter() - t1, file_size=path.stat().st_size)
