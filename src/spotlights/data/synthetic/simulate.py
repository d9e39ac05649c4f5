"""Simulation of one work unit, arrays in and arrays out: a model's ground truth, or a block
of its partial LiDAR views.

No files, no processes: :func:`model_ground_truth` and :func:`simulate_views` take a
:class:`~spotlights.data.synthetic.catalogue.LoadedModel` and the :class:`BuildConfig` and
return numpy arrays; :func:`compute_unit` is the one entry point the runners (process pool,
Ray) call. Every random number comes from a stream named by the model, the purpose and
the view (:func:`unit_rng`), so results depend on nothing else.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np

from ...errors import InputFileError
from ...geometry.encode import MeshProbe
from ...geometry.frames import normalization_from_mesh
from ...geometry.sampling import resample, sample_surface
from ...timing import StageTimer
from ..lidar import LidarSimulator, VehiclePose
from ..store import SAMPLE_FIELDS
from .catalogue import LoadedModel, apply_augment, load_model, model_key, source_root, source_scale
from .config import SENSOR_CLEARANCE, STREAM_GT_DENSE, STREAM_GT_POINTS, STREAM_MOUNT_HEIGHT, STREAM_VIEWS, BuildConfig


def unit_rng(seed: int, name: str, *stream: int) -> np.random.Generator:
    """The random generator of one purpose of one model: ``SeedSequence(seed, spawn_key=(model_key(name),
    *stream))`` (e.g. ``stream = (STREAM_VIEWS, v)`` for view ``v``)."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(model_key(name),) + tuple(stream)))


def as_trimesh(model: LoadedModel):
    """The :class:`trimesh.Trimesh` of a loaded model (vertices (V, 3) float64 metres, faces (F, 3) int),
    unprocessed (no merging or reordering: indices stay the file's). trimesh is imported here, not at the
    top: it costs about a second (with scipy and networkx), which ``spotlights --help`` should not pay."""
    import trimesh

    return trimesh.Trimesh(model.vertices, model.faces, process=False, validate=False)


def model_ground_truth(model: LoadedModel, cfg: BuildConfig) -> dict:
    """Ground truth of one model in its unit frame (axis-aligned box, R = half diagonal).

    Returns ``gt_points`` (gt_points, 3) f32, ``gt_dense`` (gt_dense, 3) f32, ``center`` (3,) f64,
    ``radius`` f64, ``size`` (3,) f64 (metres), ``depths`` list of (N*M,) f32 in ``cfg.rigs`` order
    (``MeshProbe(mesh).encode(rig)`` of the core; a box-targeted spec is resolved for this
    model's box, ``spec.for_box(size / 2R)``).
    """
    mesh = as_trimesh(model)
    norm = normalization_from_mesh(mesh)
    name = model.entry.name
    pts = sample_surface(mesh, cfg.gt_points, unit_rng(cfg.seed, name, STREAM_GT_POINTS))
    dense = sample_surface(mesh, cfg.gt_dense, unit_rng(cfg.seed, name, STREAM_GT_DENSE))
    probe = MeshProbe(mesh, norm)
    return {
        "gt_points": norm.to_unit(pts).astype(np.float32),
        "gt_dense": norm.to_unit(dense).astype(np.float32),
        "center": norm.center,
        "radius": np.float64(norm.radius),
        "size": norm.size,
        "depths": [probe.encode(r) for r in cfg.rigs],
    }


def simulate_views(
    sim: LidarSimulator, model: LoadedModel, cfg: BuildConfig, views: range, timings: StageTimer | None = None
) -> dict:
    """Partial observations ``views`` of one model.

    Each view: draw a pose (distance uniform in ``cfg.distance`` but at least the footprint's half
    diagonal + 0.5 m; bearing and heading uniform; the sensor height uniform in
    ``cfg.mount_height_range`` when set), scan; with fewer than ``min_points`` returns,
    draw again (at most ``max_draws`` times, then an error). Resample to ``n_points`` (more:
    ``downsample``; fewer: repeat random points), map into the unit frame of the vehicle's box.

    Returns arrays over the B views: ``partial`` (B, n_points, 3) f32 unit frame and the per-sample
    fields of :data:`~spotlights.data.store.SAMPLE_FIELDS` (``sensor_to_unit`` (B, 4, 4) f64, ...).
    ``timings`` (optional StageTimer) gets the seconds of the stages ``pose_loop`` (one entry per view:
    the draws and their scans), ``resample`` and the scans' ``rays``, ``cast`` and ``returns``.
    """
    name = model.entry.name
    b = len(views)
    out = {"partial": np.empty((b, cfg.n_points, 3), dtype=np.float32)}
    for k, (dt, shp) in SAMPLE_FIELDS.items():
        out[k] = np.zeros((b,) + shp, dtype=dt)
    dmin = max(cfg.distance[0], sim.footprint_radius + SENSOR_CLEARANCE)
    dmax = cfg.distance[1]
    if dmin >= dmax:
        raise InputFileError(
            model.entry.file,
            f"the mesh is too large ({sim.size[0]:.1f} x {sim.size[1]:.1f} m "
            f"footprint) for the distance range {cfg.distance[0]:g}-{dmax:g} m; is it in metres? "
            "(see --scale)",
        )
    center, radius = sim.center, 0.5 * float(np.linalg.norm(sim.size))
    heights = cfg.mount_height_range
    for j, v in enumerate(views):
        rng = unit_rng(cfg.seed, name, STREAM_VIEWS, int(v))
        # the sensor height of a view (when ranged) comes from its own stream: the pose draws
        # and everything else stay those of a build without the range
        h = None if heights is None else float(unit_rng(cfg.seed, name, STREAM_MOUNT_HEIGHT, int(v)).uniform(*heights))
        view_timer = StageTimer()
        for draw in range(1, cfg.max_draws + 1):  # noqa: B007 (draw is read after the loop)
            pose = VehiclePose(
                distance=float(rng.uniform(dmin, dmax)),
                azimuth=float(rng.uniform(-np.pi, np.pi)),
                heading=float(rng.uniform(-np.pi, np.pi)),
                mount_height=h,
            )
            scan = sim.scan(pose, rng, timings)
            if len(scan.points) >= cfg.min_points:
                break
        else:
            raise InputFileError(
                model.entry.file,
                f"view {v}: no pose out of {cfg.max_draws} gave {cfg.min_points} LiDAR returns "
                f"(last: {len(scan.points)}); the mesh may be too small or not in metres (see --scale), or lower "
                "--min-points",
            )
        pose_s = view_timer.lap("pose_loop")
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
            timings.add("resample", view_timer.lap("resample"))
            timings.add("pose_loop", pose_s)
    return out


def compute_unit(unit: tuple, model: LoadedModel, cfg: BuildConfig, sims: dict | None = None) -> dict:
    """The arrays of one work unit (arrays in, arrays out; no files).

    unit : ``("gt", m)`` (ground truth of model row ``m``) or ``("obs", m, a, b)`` (views ``a..b-1``).
    model : the unit's mesh. cfg : the build configuration.
    sims : optional cache ``{m: LidarSimulator}`` reused across units of one model (one BVH);
        it is cleared when another model arrives (units come model by model).

    Returns the arrays a part file stores: for ``gt``: ``gt_points``, ``gt_dense``, ``center``,
    ``radius``, ``size``, ``depths_<i>`` per rig of ``cfg.rigs``; for ``obs``: ``partial`` and the
    :data:`~spotlights.data.store.SAMPLE_FIELDS` (``model`` set to ``m``).
    """
    m = unit[1]
    if unit[0] == "gt":
        gt = model_ground_truth(model, cfg)
        arrays = {k: gt[k] for k in ("gt_points", "gt_dense", "center", "radius", "size")}
        for i, d in enumerate(gt["depths"]):
            arrays[f"depths_{i}"] = d
        return arrays
    sims = {} if sims is None else sims
    if m not in sims:
        sims.clear()  # units arrive model by model: keep one BVH
        sims[m] = LidarSimulator(model.vertices, model.faces, cfg.sensor_model)
    arrays = simulate_views(sims[m], model, cfg, range(unit[2], unit[3]))
    arrays["model"][:] = m
    return arrays


def model_depths(cfg: BuildConfig, entry, stored: dict, m: int, rig) -> np.ndarray:
    """Model row ``m``'s depths (N*M,) float32 for ``rig``: its mesh loaded again (checked against
    the stored SHA-256, centre and radius; an augmented copy made again from ``stored["augment"]``)."""
    root = source_root(cfg, entry)
    model = load_model(root, entry, source_scale(cfg, entry))
    want = stored["sha256"][m]
    if want and model.entry.sha256 != want:
        raise InputFileError(
            root / entry.file,
            f"differs from the mesh the dataset was built from (SHA-256 "
            f"{model.entry.sha256[:12]}..., the dataset recorded {want[:12]}...)",
        )
    if stored["augment"][m]:
        model = apply_augment(model, replace(model.entry, augment=json.loads(stored["augment"][m])))
    mesh = as_trimesh(model)
    norm = normalization_from_mesh(mesh)
    if not (np.array_equal(norm.center, stored["center"][m]) and float(norm.radius) == float(stored["radius"][m])):
        raise InputFileError(
            root / entry.file,
            "normalises differently from the dataset's /models/center and "
            "/models/radius (other --scale/--up/--forward?)",
        )
    return MeshProbe(mesh, norm).encode(rig)
