"""A tiny synthetic completion dataset written to the HDF5 schema of notes/contracts.md.

Independent of ``spotlights.data``: analytic shapes (boxes, ellipsoids,
capsules) per category, ground truth by uniform surface sampling, depths by the
geometry core's ``encode_mesh``, partial scans by casting rays from a virtual
sensor and keeping the first hits (then resampled to 256 points). Everything is
seeded; the file is a few hundred kB.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

CATEGORIES = ("hatchback", "sedan", "suv")
# (category, split) per model: one train/val/test model per category plus extra train models.
DEFAULT_LAYOUT = (
    ("hatchback", "train"),
    ("sedan", "train"),
    ("suv", "train"),
    ("hatchback", "train"),
    ("sedan", "train"),
    ("suv", "train"),
    ("hatchback", "val"),
    ("sedan", "val"),
    ("suv", "val"),
    ("hatchback", "test"),
    ("sedan", "test"),
    ("suv", "test"),
)


def make_shape(category: str, rng: np.random.Generator):
    """A trimesh in the object frame (x forward, y left, z up), centred on its box."""
    import trimesh

    if category == "hatchback":
        m = trimesh.creation.box(extents=[rng.uniform(3.6, 4.2), rng.uniform(1.6, 1.8), rng.uniform(1.4, 1.6)])
    elif category == "sedan":
        m = trimesh.creation.icosphere(subdivisions=2)
        m.apply_scale([rng.uniform(2.2, 2.5), rng.uniform(0.85, 0.95), rng.uniform(0.65, 0.75)])
    else:
        m = trimesh.creation.capsule(height=rng.uniform(2.4, 2.8), radius=rng.uniform(0.85, 1.0), count=[12, 12])
        m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    lo, hi = m.bounds
    m.apply_translation(-(lo + hi) / 2)
    return m


def simulate_partial(probe, rng: np.random.Generator, n_points: int = 256, n_rays: int = 4096):
    """Visible surface points (unit frame) of a normalised mesh seen from a random sensor.

    Returns (n_points, 3) float32 unit-frame points and the (4, 4) sensor -> unit transform.
    """
    az = rng.uniform(0, 2 * np.pi)
    el = rng.uniform(0.05, 0.5)
    sensor = 3.0 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    targets = rng.uniform(-1, 1, size=(n_rays, 3))
    d = targets - sensor
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    origins = np.repeat(sensor[None], n_rays, axis=0)
    t, _ = probe.caster.first_hit(origins, d)
    hit = np.isfinite(t)
    pts = origins[hit] + t[hit, None] * d[hit]
    if len(pts) == 0:  # pragma: no cover - cannot happen with these shapes
        pts = sensor[None] * 0.0
    idx = rng.choice(len(pts), size=n_points, replace=len(pts) < n_points)
    sensor_to_unit = np.eye(4)
    sensor_to_unit[:3, 3] = sensor
    return pts[idx].astype(np.float32), sensor_to_unit


def write_tiny_dataset(
    path, rigs=None, views: int = 8, layout=DEFAULT_LAYOUT, seed: int = 0, n_gt: int = 2048, n_dense: int = 16384
) -> Path:
    """Write a valid ``spotlights-completion`` HDF5 file and return its path.

    Parameters
    ----------
    rigs : list of Rig (default: one small cap rig 8 x 16 at 60 degrees, 128 rays, the default rig).
    views : observations per model. layout : (category, split) per model.
    """
    import h5py

    from spotlights.geometry.encode import MeshProbe
    from spotlights.geometry.rig import make_rig
    from spotlights.geometry.sampling import sample_surface

    rigs = rigs or [make_rig(8, 16, 60.0)]
    rng = np.random.default_rng(seed)
    n = len(layout)
    gt = np.zeros((n, n_gt, 3), np.float32)
    dense = np.zeros((n, n_dense, 3), np.float32)
    center = np.zeros((n, 3))
    radius = np.zeros(n)
    depths = {r.name: np.zeros((n, r.n_rays), np.float32) for r in rigs}
    partial = np.zeros((n * views, 256, 3), np.float32)
    s_model = np.repeat(np.arange(n, dtype=np.int32), views)
    s_view = np.tile(np.arange(views, dtype=np.int32), n)
    s2u = np.zeros((n * views, 4, 4))
    names = []
    for j, (cat, _split) in enumerate(layout):
        mesh = make_shape(cat, rng)
        probe = MeshProbe(mesh)
        norm = probe.normalization
        center[j], radius[j] = norm.center, norm.radius
        unit_mesh = mesh.copy()
        unit_mesh.vertices = norm.to_unit(mesh.vertices)
        gt[j] = sample_surface(unit_mesh, n_gt, seed=int(rng.integers(2**31)))
        dense[j] = sample_surface(unit_mesh, n_dense, seed=int(rng.integers(2**31)))
        for r in rigs:
            depths[r.name][j] = probe.encode(r)
        for v in range(views):
            partial[j * views + v], s2u[j * views + v] = simulate_partial(probe, rng)
        names.append(f"{cat}/{cat}_{j:02d}")
    str_dt = h5py.string_dtype("utf-8")
    path = Path(path)
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "spotlights-completion"
        f.attrs["format_version"] = 1
        f.attrs["spotlights_version"] = "test"
        f.attrs["config_json"] = json.dumps({"fixture": "tests/learning_fixtures.py", "views": views})
        f.attrs["seed"] = seed
        f.attrs["sensor_json"] = json.dumps({"kind": "synthetic-test"})
        f.attrs["default_rig"] = rigs[0].name
        g = f.create_group("models")
        g.create_dataset("name", data=np.array(names, dtype=object), dtype=str_dt)
        g.create_dataset("category", data=np.array([c for c, _ in layout], dtype=object), dtype=str_dt)
        g.create_dataset("split", data=np.array([s for _, s in layout], dtype=object), dtype=str_dt)
        g.create_dataset("gt_points", data=gt)
        g.create_dataset("gt_dense", data=dense)
        g.create_dataset("center", data=center)
        g.create_dataset("radius", data=radius)
        for r in rigs:
            rg = f.create_group(f"rigs/{r.name}")
            rg.create_dataset("depths", data=depths[r.name])
            rg.attrs["rig_json"] = json.dumps(r.to_dict())
        s = f.create_group("samples")
        s.create_dataset("partial", data=partial, chunks=(1, 256, 3))
        s.create_dataset("model", data=s_model)
        s.create_dataset("view", data=s_view)
        s.create_dataset("sensor_to_unit", data=s2u)
        # the remaining per-sample fields of the format (data/store.py SAMPLE_FIELDS); the simulated
        # sensor of simulate_partial is not a LiDAR pose, so these carry neutral values
        unit_to_sensor = np.linalg.inv(s2u)
        s.create_dataset("distance", data=np.linalg.norm(unit_to_sensor[:, :2, 3], axis=1).astype(np.float32))
        s.create_dataset("azimuth", data=np.zeros(n * views, np.float32))
        s.create_dataset("heading", data=np.zeros(n * views, np.float32))
        s.create_dataset("n_raw", data=np.full(n * views, 256, np.int32))
        s.create_dataset("n_draws", data=np.ones(n * views, np.int16))
        s.create_dataset("n_rays", data=np.full(n * views, 4096, np.int32))
    return path


# Small model arguments for fast tests (same architectures, narrower / fewer points).
TINY_MODEL_ARGS = {
    "sanet": {"code_size": 64, "encoder_widths": [16, 32, 64], "hidden": [32]},
    "sanet-hit": {"code_size": 64, "encoder_widths": [16, 32, 64], "hidden": [32]},
    "pcn": {
        "code_size": 64,
        "encoder_widths": [16, 32, 64],
        "num_coarse": 32,
        "grid_size": 2,
        "coarse_hidden": [64],
        "folding_hidden": [32],
    },
    "foldingnet": {"code_size": 64, "encoder_widths": [16, 32, 64], "grid": [8, 16], "hidden": [32]},
    "topnet": {
        "code_size": 64,
        "encoder_widths": [16, 32, 64],
        "degrees": [2, 4, 4, 4],
        "node_features": 4,
        "root_hidden": [32],
    },
    "atlasnet": {"code_size": 64, "encoder_widths": [16, 32, 64], "n_patches": 2, "patch_grid": [8, 8]},
    "snowflakenet": {
        "code_size": 64,
        "encoder_widths": [16, 32, 64],
        "n_seeds": 12,
        "seed_code": 16,
        "n_start": 16,
        "up_factors": [2, 4],
        "dim": 8,
        "k": 4,
    },
}


def tiny_overrides(name: str, epochs: int = 2, batch_size: int = 8, **train) -> dict:
    """Config overrides for a fast test run of model ``name``."""
    return {
        "model": {"args": dict(TINY_MODEL_ARGS[name])},
        "data": {"val_max_views": 2, "num_workers": 0},
        "train": {"epochs": epochs, "batch_size": batch_size, "lr": 1e-3, **train},
    }


def make_checkpoint(path, name: str, rig=None, tiny: bool = True, seed: int = 0) -> Path:
    """Save an untrained (seeded) checkpoint of model ``name`` (a valid file for inference tests)."""
    import torch

    from spotlights.geometry.rig import make_rig
    from spotlights.learning.checkpoint import save_checkpoint
    from spotlights.learning.models import build_model, load_config

    cfg = load_config(name, overrides={"model": {"args": dict(TINY_MODEL_ARGS[name])}} if tiny else None)
    rig = rig or make_rig(8, 16, 60.0)
    torch.manual_seed(seed)
    model = build_model(cfg, rig=rig)
    payload = {
        "model_name": name,
        "config": cfg,
        "rig": rig.to_dict() if model.target == "depths" else None,
        "model_state": model.state_dict(),
        "param_counts": model.param_counts(),
        "epoch": 0,
        "global_step": 0,
    }
    return save_checkpoint(path, payload)


_CACHE: dict = {}


def tiny_dataset_path(base_dir, **kw) -> Path:
    """The tiny dataset, written once per test process into ``base_dir`` (cached by its arguments)."""
    key = tuple(sorted(kw.items()))
    if key not in _CACHE or not Path(_CACHE[key]).exists():
        base = Path(base_dir)
        base.mkdir(parents=True, exist_ok=True)
        _CACHE[key] = write_tiny_dataset(base / f"tiny_{len(_CACHE)}.h5", **kw)
    return _CACHE[key]


def cli(capsys, *args):
    """Run the CLI in this process (no interpreter start-up); returns an object like CompletedProcess."""
    import subprocess

    from spotlights.cli import main

    capsys.readouterr()
    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return subprocess.CompletedProcess(args, code, captured.out, captured.err)


def one_torch_thread():
    """Generator for an autouse fixture: tiny models run faster on one thread, above all on a shared CPU."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def write_category_shapes(root: Path) -> Path:
    """Three category folders (hatchback, sedan, suv) of three :func:`make_shape` meshes each under ``root``."""
    rng = np.random.default_rng(0)
    for cat in ("hatchback", "sedan", "suv"):
        (root / cat).mkdir()
        for j in range(3):
            make_shape(cat, rng).export(root / cat / f"{cat}{j}.ply")
    return root


def run_gpu_script(tmp_path: Path, *args, env: dict | None = None) -> subprocess.CompletedProcess:
    """scripts/gpu_train.sh with ``args``, with this test's interpreter as its Python (PYTHON; the script's default
    is ``python3`` on the PATH, which under ``make test`` is not the project environment's: it would miss the
    packages), no wheel bundle, one OpenMP thread and ``env`` on top."""
    full = dict(os.environ, GPU_BUNDLE=str(tmp_path / "no-wheels"), OMP_NUM_THREADS="1", PYTHON=sys.executable)
    full.update(env or {})
    full.pop("OUT", None)
    script = Path(__file__).resolve().parents[1] / "scripts" / "gpu_train.sh"
    return subprocess.run(["bash", str(script), *map(str, args)], capture_output=True, text=True, env=full, timeout=550)
