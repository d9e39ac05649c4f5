"""Completion of whole LiDAR frames: a scan plus its boxes -> every vehicle completed, in the scan's frame.

:func:`complete_scene` is the library behind ``spotlights complete SCAN --boxes BOXES`` and
``spotlights real complete``:

1. **Selection.** Boxes of the chosen classes (default: every vehicle class,
   :data:`spotlights.data.real.base.CLASSES`) are completed; others (pedestrians,
   bicycles, unlabelled boxes in a list) are kept as raw points, counted by reason.
2. **Crop.** Each box's points are those of
   :meth:`spotlights.geometry.boxes.Box.contains` with ``margin`` (default
   **0.15 m** on the sides and top) and its bottom raised by ``ground_clearance``
   (default **0.10 m**: the ground returns under a vehicle), the same cut as
   ``real extract``. A box with fewer than ``min_points`` (default **10**) is skipped.
3. **Input.** The crop in the box's unit frame (object frame / half the box diagonal),
   brought to 256 points by :func:`spotlights.learning.inference.prepare_partial`
   (canonical order, seeded random subset: the same points give the same input).
4. **Completion.** All objects in one batch (with ``heading_check``: twice as many, each
   also with its box turned by 180 degrees; the turned heading is kept when its completion
   is clearly closer to the observed points: fidelity lower by more than
   :data:`HEADING_MARGIN`, see :func:`heading_turns`).
5. **Output** in the scan's frame: per point ``source`` (0 raw, 1 partial input of an
   object, 2 completion) and ``object`` (see :func:`object_ids`; -1 for raw points outside
   every box). Boxes whose class or size is outside what the model learned get warnings.

Frames: points and boxes are in the scan's frame. ``axes`` (from ``--up/--forward``) turns a
scan whose up axis is not z into the object convention first and the results back after.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from ..data.vehicle_classes import VEHICLE_CLASSES, canonical_class
from ..errors import InputFileError, ParameterError, parameter_names, shown
from ..geometry.boxes import FLIP_Z, MAX_BOXES_PER_FRAME, Box, crop_boxes
from ..geometry.rotations import is_rotation, rigid_transform
from ..learning.fit import can_fit, require_fittable
from ..learning.inference import DEFAULT, complete_in_boxes, load_completer, prepare_partial, with_observed
from ..processes import shared_thread_pool
from ..timing import StageTimer
from .fidelities import FIDELITY_THREADS, Fidelities
from .results import ObjectResult, SceneResult, object_ids
from .scene_config import (
    HEADING_DOC,
    HEADING_MARGIN,
    SOURCE_COMPLETION,
    SOURCE_PARTIAL,
    SOURCE_RAW,
    SceneConfig,
    heading_turns,
)
from .writing import check_completed, describe, fallback_counts, scene_comments, write_scene

LOG = logging.getLogger(__name__)


def _selected(box: Box, config: SceneConfig) -> bool:
    if config.any_label:
        return True
    if box.cls is None:
        return False
    return config.classes is None or box.cls in config.classes


def scene_points(points) -> np.ndarray:
    """``points`` as the (N, 3) float64 scan :func:`complete_scene` works on; a one-line :class:`ParameterError`
    for anything else: another shape ((N, 4) with intensity: pass ``points[:, :3]``), a type that is not real
    numbers, or rows that are not finite (the command line's readers drop them; an array given here is not
    changed behind the caller's back)."""
    try:
        a = np.asarray(points)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"points must be an (N, 3) array of x y z in metres: {exc}") from None
    if a.ndim != 2 or a.shape[1] != 3:
        hint = (
            " (pass points[:, :3]: the other columns, such as intensity, are not used)"
            if a.ndim == 2 and a.shape[1] > 3
            else ""
        )
        raise ParameterError(f"points must be an (N, 3) array of x y z in metres, got shape {a.shape}{hint}")
    if a.dtype.kind not in "fiu":
        raise ParameterError(f"points must be real numbers (float or int), got dtype {a.dtype}")
    scan = a.astype(np.float64, copy=False)
    bad = ~np.isfinite(scan).all(axis=1)
    if bad.any():
        raise ParameterError(
            f"{int(bad.sum())} of the {len(scan)} points are not finite (NaN or inf); drop them first: "
            "points[np.isfinite(points).all(axis=1)]"
        )
    return scan


def check_scene_inputs(boxes, completer, config, axes) -> None:
    """One-line :class:`ParameterError` for what :func:`complete_scene` cannot use: ``boxes`` not a sequence of
    :class:`~spotlights.geometry.boxes.Box`, a ``completer`` without ``complete``, a ``config`` that is not a
    :class:`SceneConfig`, ``axes`` that are not a (3, 3) rotation (orthonormal, determinant +1, to 1e-3), more than
    :data:`~spotlights.geometry.boxes.MAX_BOXES_PER_FRAME` boxes."""
    if isinstance(boxes, Box) or not isinstance(boxes, Sequence) or isinstance(boxes, str):
        raise ParameterError(
            f"boxes must be a list of Box objects (for one box: [box], or spotlights.complete), got {type(boxes).__name__}"
        )
    if len(boxes) > MAX_BOXES_PER_FRAME:
        raise ParameterError(f"boxes holds {len(boxes):,} boxes; a frame takes at most {MAX_BOXES_PER_FRAME:,}")
    for i, b in enumerate(boxes):
        if not isinstance(b, Box):
            raise ParameterError(
                f"boxes[{i}] is a {type(b).__name__}, not a Box (spotlights.geometry.box_json.box_from_dict makes one "
                "from a dict with center, size and yaw)"
            )
    if not callable(getattr(completer, "complete", None)):
        raise ParameterError(
            f"completer must be a loaded model (spotlights.learning.runtime.load_completer) or a checkpoint name, "
            f"got {type(completer).__name__}"
        )
    if not isinstance(config, SceneConfig):
        raise ParameterError(f"config must be a SceneConfig, got {type(config).__name__}")
    if axes is not None:
        try:
            rotation = is_rotation(axes)
        except (TypeError, ValueError):  # not numbers
            rotation = False
        if not rotation:
            raise ParameterError(f"axes must be a (3, 3) rotation (orthonormal, determinant +1), got {axes!r}")


def complete_scene(
    points: np.ndarray,
    boxes: Sequence[Box],
    completer,
    config: SceneConfig | None = None,
    axes: np.ndarray | None = None,
    checkpoint: str | None = None,
    sensor: np.ndarray | None = None,
    extra_points: dict | None = None,
    fallback=None,
    fallback_name: str | None = None,
    crops: dict | None = None,
) -> SceneResult:
    """Complete every selected box of one scan (see the module docstring).

    Parameters
    ----------
    points : (N, 3) scan points, metres, the scan's frame (float32 or float64).
    boxes : the scan's boxes in the same frame (:class:`~spotlights.geometry.boxes.Box`, with ``cls``).
    completer : a :class:`~spotlights.learning.inference.Completer` (or any object with its
        ``complete``/``needs_box``/``domain``/``model_name``).
    axes : optional (3, 3) rotation scan coordinates -> object convention (x forward, y left, z up).
    sensor : (3,) the LiDAR's optical centre in the scan's frame, metres (default: the scan's origin); models
        that read free space (``sanet-local``) get it in each box's unit frame.
    extra_points : optional {box index: (k, 3) points, metres, scan frame}: more evidence of that object
        (other frames of its track, :mod:`spotlights.completion.fusion`) added to its crop for the model
        input (and counted towards ``min_points``); the scene's ``source``/``object`` fields keep the scan's own.
    fallback : optional second completer for the boxes whose class or size ``completer`` did not learn (its
        learned domain gates them) but ``fallback`` did, e.g. ``load_completer("classes")`` beside the car-only
        default: those boxes are completed by it (``ObjectResult.completed_by``: ``fallback_name``, else its
        model's name), the others by ``completer``.
    crops : optional {box index: (k,) int64 scan indices} of every valid box, :func:`scene_crops` of these
        ``points`` and ``boxes`` made elsewhere (a track worker process, :mod:`spotlights.completion.fusion`);
        used without ``axes`` and with ``config.crop``, else ignored.

    Returns a :class:`SceneResult`; raises :class:`ParameterError` for a scan with fewer than
    ``config.min_points`` points.
    """
    config = SceneConfig() if config is None else config
    timer = StageTimer()
    scan = scene_points(points)
    check_scene_inputs(boxes, completer, config, axes)
    _require_scan_size(scan, config)
    require_rays_to_snap(completer, config.snap)
    if config.fit:  # the fit differentiates a torch model: an ONNX export runs as its checkpoint
        completer = fittable(completer)
        require_fittable(completer)
        fallback = None if fallback is None else fittable(fallback)
    require_sensor(sensor)
    a = None if axes is None or np.allclose(axes, np.eye(3)) else np.asarray(axes, dtype=np.float64)
    with timer("crop"):
        work = scan if a is None else scan @ a.T
        lidar = np.zeros(3) if sensor is None else np.asarray(sensor, dtype=np.float64)
        lidar = lidar if a is None else a @ lidar
        member = np.full(len(scan), -1, np.int64)
        fb = None if fallback is None else (fallback, fallback_name or str(getattr(fallback, "model_name", "fallback")))
        given = crops if a is None and config.crop else None
        objects = _crop_objects(work, boxes, a, lidar, member, completer, config, extra_points, fb, given)
    todo = [o for o in objects if o.status == "completed"]
    shares: list[float] = []  # per completion: the share the network put inside its grown box (before the clamp)
    with timer("model"):
        scores = Fidelities(todo)  # scored on threads as each model's batch is decoded
        outs = _complete_objects(todo, completer, config, shares, fallback, scores) if todo else []
    with timer("assemble"):
        if todo:
            _finish_objects(todo, outs, config, a, scores, shares)
    return _scene_result(scan, objects, completer, checkpoint, config, timer, member)


def _scene_result(
    scan: np.ndarray, objects: list[ObjectResult], completer, checkpoint, config: SceneConfig, timer, member
) -> SceneResult:
    """The :class:`SceneResult` of a completed scan, with the stage times of ``timer`` (a
    :class:`~spotlights.timing.StageTimer`) in seconds; logs a one-line summary at debug level."""
    result = SceneResult(
        scan,
        objects,
        str(getattr(completer, "model_name", "model")),
        checkpoint,
        config,
        timings={f"{k}_s": v for k, v in timer.seconds.items()} | {"total_s": timer.total},
        member=member,
    )
    LOG.debug(
        "%d box(es), %d completed by %s; stages: %s",
        len(objects),
        len(result.completed),
        result.model,
        ", ".join(f"{k} {1000 * v:.0f} ms" for k, v in timer.seconds.items()),
    )
    return result


def _require_scan_size(scan: np.ndarray, config: SceneConfig) -> None:
    """Raise :class:`ParameterError` for a scan (N, 3) with fewer than ``config.min_points`` points."""
    if len(scan) < config.min_points:
        raise ParameterError(
            f"the scan holds {len(scan)} point{'s' if len(scan) != 1 else ''}; at least "
            f"{config.min_points} are needed to complete anything"
        )


def _finish_objects(
    todo: list[ObjectResult], outs: list, config: SceneConfig, a, scores: Fidelities, shares: list[float]
) -> None:
    """The completed objects' fidelities, headings and scan-frame completions (:func:`_assemble`), their share of
    the completion kept inside the box (``shares``: :func:`_complete_objects`' list), and their used boxes back in
    the scan's coordinates (``a``: the (3, 3) scan-to-object axes, None for none); in place."""
    # no KD-tree query runs here (Fidelities' threads do, each limited to one OpenMP thread once): no
    # threadpool limit around it (threadpoolctl's scan of the loaded libraries took ~5 ms a frame)
    _assemble(todo, outs, config, a, scores)
    for k, o in enumerate(todo):  # the share of the completion kept (turned around when the heading flipped)
        o.inside_box = shares[len(todo) + k] if o.flipped else shares[k]
    if a is not None:
        back = rigid_transform(a.T, np.zeros(3))
        for o in todo:
            o.used_box = _set(o.used_box).transformed(back)


#: torch twins of ONNX exports loaded for the fit (:func:`fittable`), by file, size and modification time
_TWINS: dict[tuple, Any] = {}
TWINS_KEPT = 4
"""Most torch twins kept loaded (a main model and its fallback need two)."""


def fittable(completer):
    """``completer`` when the evidence fit can run it (:func:`~spotlights.learning.fit.can_fit`), else its torch
    twin: the checkpoint beside its ONNX export (``NAME.pt`` next to ``NAME.onnx``, as the packaged models are
    shipped), loaded once on the CPU in float32; ``completer`` itself when it has none (the fit then refuses it)."""
    path = getattr(completer, "path", None)
    if can_fit(completer) or path is None or Path(path).suffix.lower() != ".onnx":
        return completer
    twin = Path(path).with_suffix(".pt")
    if not twin.is_file():
        return completer
    st = twin.stat()
    key = (str(twin.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _TWINS:
        LOG.info("the fit runs %s (the checkpoint of %s) with torch", twin.name, Path(path).name)
        _TWINS[key] = load_completer(str(twin), device="cpu")
        while len(_TWINS) > TWINS_KEPT:  # the oldest first
            _TWINS.pop(next(iter(_TWINS)))
    return _TWINS[key]


def scene_crops(points: np.ndarray, boxes: Sequence[Box], config: SceneConfig) -> dict[int, np.ndarray]:
    """{box index: (k,) int64 indices of the scan ``points`` (N, 3), metres, the boxes' frame} for every valid box:
    the crop :func:`complete_scene` makes (the box grown by ``config.margin``, bottom raised by
    ``config.ground_clearance``; one KD-tree, :func:`spotlights.geometry.boxes.crop_boxes`)."""
    work = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    valid = [i for i, b in enumerate(boxes) if b.is_valid()]
    return dict(zip(valid, crop_boxes(work, [boxes[i] for i in valid], config.margin, config.ground_clearance)))


def _crop_objects(
    work,
    boxes,
    a,
    lidar,
    member,
    completer,
    config: SceneConfig,
    extra_points,
    fallback: tuple | None = None,
    given: dict | None = None,
) -> list[ObjectResult]:
    """Every box's :class:`ObjectResult`: its crop of ``work`` (N, 3) (the scan in the object convention,
    metres), its 256-point model input (unit frame) and out-of-domain warnings, or why it is skipped.
    ``member`` (N,) int64 receives each point's first box index (-1: none); ``lidar`` (3,) the sensor."""
    to_work = None if a is None else rigid_transform(a, np.zeros(3))
    ids = object_ids(boxes)
    objects: list[ObjectResult] = []
    wbs = [b if to_work is None else b.transformed(to_work) for b in boxes]
    # one KD-tree crop of the scan for every box (geometry.boxes.crop_boxes: Box.crop's indices), unless given
    crops = (given if given is not None else scene_crops(work, wbs, config)) if config.crop else {}
    for i, b in enumerate(boxes):
        wb = wbs[i]
        if not wb.is_valid():
            objects.append(ObjectResult(i, ids[i], b, "invalid_box" if _selected(b, config) else "class_excluded"))
            continue
        idx = crops[i] if config.crop else np.arange(len(work))
        free = idx[member[idx] < 0]
        member[free] = i
        if not _selected(b, config):
            objects.append(ObjectResult(i, ids[i], b, "class_excluded", input_indices=idx))
            continue
        more = None if extra_points is None else extra_points.get(i)
        pts = work[idx] if more is None else np.concatenate([work[idx], more if a is None else more @ a.T])
        if len(pts) < config.min_points:
            objects.append(ObjectResult(i, ids[i], b, "too_few_points", input_indices=idx))
            continue
        unit = wb.normalization().to_unit(pts)
        partial = prepare_partial(unit, seed=config.seed, method=config.resample)
        o = ObjectResult(i, ids[i], b, "completed", used_box=wb, input_indices=idx, partial_unit=partial)
        o.sensor_unit = wb.normalization().to_unit(lidar)
        o.n_fused = None if more is None else len(pts)
        if more is not None and (config.snap or config.fit):
            o.seen_unit = wb.normalization().to_unit(work[idx]).astype(np.float32)
        _gate_by_domain(o, completer, config, fallback)
        objects.append(o)
    return objects


def _gate_by_domain(o: ObjectResult, completer, config: SceneConfig, fallback: tuple | None) -> None:
    """Route an object to be completed by what its model learned (``completer.domain``, a
    :class:`~spotlights.learning.domain.LearnedDomain`; no gate without one): its out-of-domain warnings, and for a
    box the model did not learn, the ``fallback`` (model, name) when that learned it, else completion anyway with
    ``config.complete_unknown``, else status ``not_learned`` with a hint of what would complete it; in place."""
    b = o.box
    domain = getattr(completer, "domain", None)
    if domain is None:
        return
    unlearned = domain.gate(b.cls, b.size) is not None
    # a box the main model did not learn goes to a fallback that did, whatever --complete-unknown says
    # (which is for what neither learned)
    fb = getattr(fallback[0], "domain", None) if unlearned and fallback is not None else None
    if fb is not None and fallback is not None and fb.gate(b.cls, b.size) is None:  # the fallback learned it
        o.completed_by = fallback[1]
        o.warnings.extend(fb.warnings(b.cls, b.size))
        return
    o.warnings.extend(domain.warnings(b.cls, b.size))
    if unlearned and not config.complete_unknown:
        o.status, o.used_box, o.partial_unit = "not_learned", None, None
        hint = _not_learned_hint(b, domain, fallback, fb)
        o.warnings.append(f"not completed (left as observed points; {hint}--complete-unknown completes it)")


def _not_learned_hint(b: Box, domain, fallback: tuple | None, fb) -> str:
    """What would complete a box that neither the model (``domain``) nor the ``fallback`` (whose domain is ``fb``)
    learned: the start of its warning's hint (empty when nothing but ``--complete-unknown`` would)."""
    if fallback is not None and fb is None:
        return f"the fallback {fallback[1]} records no learned domain, so it is not used; "
    if fallback is not None:
        return f"nor did the fallback {fallback[1]} learn it; "
    if fallback_hint(b.cls, domain):
        return "--fallback classes completes it with the class model; "
    return ""


def fallback_hint(cls: str | None, domain) -> bool:
    """True when a box of class ``cls`` that the model of ``domain`` (a
    :class:`~spotlights.learning.domain.LearnedDomain`) did not learn is of a vehicle class the packaged class
    model (``--fallback classes``: car, caravan, truck, bus, trailer) did learn: the hint a user needs beside a
    car-only model."""
    c = canonical_class(cls) if cls else None
    return c in VEHICLE_CLASSES and not domain.learned(c)


_T = TypeVar("_T")


def _set(value: _T | None) -> _T:
    """``value``, which a completed object always has (its used box, model input, sensor); a bug otherwise."""
    if value is None:
        raise RuntimeError("a completed object lacks its box, input or sensor (a bug in complete_scene)")
    return value


def _complete_objects(
    todo: list[ObjectResult], completer, config: SceneConfig, shares: list, fallback, scores: Fidelities
) -> list:
    """The completions (unit frame, clamped to the grown box) of every object of ``todo``, then (heading check)
    of every object turned around, in that order; ``shares`` receives each one's share inside its box. The
    objects the ``fallback`` model completes (``completed_by``) go through it in a batch of their own.
    ``scores`` (:class:`Fidelities`) starts scoring each batch's completions as soon as it is decoded."""
    own = [k for k, o in enumerate(todo) if o.completed_by is None]
    n = len(todo)
    if len(own) == len(todo) or fallback is None:
        res = _complete_batch(todo, completer, config, shares)
        scores.add(range(len(res)), res)
        return res
    width = 2 * n if config.heading_check else n
    outs: list = [None] * width
    inside: list = [float("nan")] * width
    others = sorted(set(range(n)) - set(own))
    # the fallback's batch runs on a thread beside the main model's (torch computes without the GIL)
    beside = None
    if own and others:
        beside = shared_thread_pool("fallback", 1).submit(
            _complete_batch_shares, [todo[k] for k in others], fallback, config
        )
    for model, idx, ready in ((completer, own, None), (fallback, others, beside)):
        if not idx:
            continue
        part, res = (
            ready.result() if ready is not None else _complete_batch_shares([todo[k] for k in idx], model, config)
        )
        at = list(idx) + ([n + k for k in idx] if config.heading_check else [])  # positions of res in outs
        for j, k in enumerate(at):
            outs[k], inside[k] = res[j], part[j]
        scores.add(at, res)
    shares.extend(inside)
    return outs


def _complete_batch_shares(todo: list[ObjectResult], completer, config: SceneConfig) -> tuple[list, list]:
    """(shares inside the box, completions) of :func:`_complete_batch`."""
    part: list[float] = []
    return part, _complete_batch(todo, completer, config, part)


def _complete_batch(todo: list[ObjectResult], completer, config: SceneConfig, shares: list) -> list:
    """:func:`_complete_objects` for objects that one model completes: one batch. With ``config.fit`` (and a model
    that can be fitted) each object's ``fitted`` is set (the gate's choice for the heading it keeps is set later)."""
    partials = np.stack([_set(o.partial_unit) for o in todo])
    sizes = np.stack([_set(o.used_box).size for o in todo])
    sensors = np.stack([_set(o.sensor_unit) for o in todo])
    classes = [o.box.cls for o in todo]
    if config.heading_check:
        classes = classes + classes
        partials = np.concatenate([partials, (partials @ FLIP_Z).astype(np.float32)])
        sizes = np.concatenate([sizes, sizes])
        sensors = np.concatenate([sensors, sensors @ FLIP_Z])
    fit: dict[str, Any] = {}
    if config.fit and can_fit(completer):
        flags: list[bool] = []
        fit = {"fit": config.fit_settings, "fitted": flags}
        if any(o.seen_unit is not None for o in todo):
            seen = [o.partial_unit if o.seen_unit is None else o.seen_unit for o in todo]
            fit["seen"] = seen + [s @ FLIP_Z for s in seen] if config.heading_check else seen
    out = complete_in_boxes(
        completer,
        partials,
        sizes,
        clip=DEFAULT if config.clip == "default" else config.clip,
        sensor_origins=sensors,
        inside=shares,
        classes=classes,
        **snap_options(completer, config.snap, config.snap_mirror, todo),
        **fit,
    )
    if fit:
        for k, o in enumerate(todo):
            o.fitted_headings = (flags[k], flags[len(todo) + k] if config.heading_check else None)
    return out


def require_rays_to_snap(completer, snap: float | None) -> None:
    """Raise :class:`ParameterError` when ``snap`` (a radius; 0 or None: off) asks a main model without rays (a
    point-set model) to snap: it could not snap a single box. (A point-set fallback completes unsnapped.)"""
    if snap and getattr(completer, "rig", None) is None:
        raise ParameterError(
            f"`snap`: {getattr(completer, 'model_name', 'this model')} has no rays to snap; snapping to the observed "
            "points needs an SA-Net (a point-set fallback completes its boxes unsnapped)",
            "snap",
        )


def require_sensor(sensor, name: str = "sensor") -> None:
    """Raise :class:`ParameterError` unless ``sensor`` (the LiDAR's place in the scan's frame, metres; option
    ``name``) is None or three finite numbers."""
    if sensor is not None and (np.shape(sensor) != (3,) or not np.all(np.isfinite(np.asarray(sensor, dtype=float)))):
        try:
            got = " ".join(f"{float(v):g}" for v in np.ravel(sensor))
        except (TypeError, ValueError):
            got = repr(sensor)
        raise ParameterError(
            f"{shown(name)}: give the LiDAR's X Y Z in the scan's frame (metres), got {got}",
            *parameter_names(name),
        )


def snap_options(completer, snap: float | None, snap_mirror: bool, todo: Sequence[ObjectResult] = ()) -> dict:
    """``snap``, ``snap_mirror`` and ``seen`` for one model's ``complete`` (through
    :func:`~spotlights.learning.inference.complete_in_boxes` or ``real evaluate``'s batches) and its objects
    ``todo``: the radius and mirror asked for an SA-Net (it has a rig), off for a point-set model (a ``--fallback``
    baseline completes its boxes unsnapped and ``real evaluate`` scores one as it is, as ``evaluate`` does;
    :func:`complete_scene` refuses one as the main model); ``seen``, when some objects have other frames fused in,
    each object's own points (:attr:`ObjectResult.seen_unit`, else its input) for the occlusion rule's free space."""
    rays = getattr(completer, "rig", None) is not None
    out: dict[str, Any] = {"snap": (snap or None) if rays else None, "snap_mirror": bool(snap_mirror) and rays}
    if out["snap"] and any(o.seen_unit is not None for o in todo):
        out["seen"] = [o.partial_unit if o.seen_unit is None else o.seen_unit for o in todo]
    return out


def _assemble(todo: list, outs: list, config: SceneConfig, a, scores: Fidelities) -> None:
    """Fidelity, heading choice and the scan-frame completion of every completed object (in place).

    ``outs`` come from :func:`complete_in_boxes`, clamped to the unit sphere: no completion point
    of any model leaves its box's sphere. ``scores``: their fidelities (:class:`Fidelities`, started already)."""
    n = len(todo)
    for k, o in enumerate(todo):
        comp = outs[k]
        o.fidelity = scores.get(k)
        if config.heading_check:
            comp_f = outs[n + k]
            flipped_partial = scores.partial(n + k)
            o.fidelity_flipped = scores.get(n + k)
            if o.fidelity_flipped is not None and bool(
                heading_turns(np.nan if o.fidelity is None else o.fidelity, o.fidelity_flipped, config.heading_margin)
            ):
                o.flipped, comp = True, comp_f
                o.used_box = o.used_box.flipped()
                o.partial_unit = flipped_partial.astype(np.float32)
        heads = o.fitted_headings
        if heads is not None:
            o.fitted = bool(heads[1] if o.flipped else heads[0])
        o.completion_unit = comp
        if len(comp) == 0:
            o.status = "empty_completion"
            continue
        if config.keep_observed:  # scored above on the predicted points alone
            comp = o.completion_unit = with_observed(comp, o.partial_unit)
        done = o.used_box.normalization().from_unit(comp.astype(np.float64))
        o.completion = done if a is None else done @ a


def require_points(points: np.ndarray, min_points: int, source) -> None:
    """A one-line error naming ``source`` when a scan holds fewer than ``min_points`` points."""
    if len(points) < min_points:
        raise InputFileError(
            source,
            f"holds {len(points)} point{'s' if len(points) != 1 else ''}; at least {min_points} "
            "are needed to complete anything",
        )


__all__ = [
    "HEADING_MARGIN",
    "SOURCE_COMPLETION",
    "SOURCE_PARTIAL",
    "SOURCE_RAW",
    "fallback_counts",
    "heading_turns",
    "scene_comments",
    "SceneConfig",
    "SceneResult",
    "ObjectResult",
    "complete_scene",
    "scene_crops",
    "write_scene",
    "check_completed",
    "object_ids",
    "describe",
    "HEADING_DOC",
    "Fidelities",
    "FIDELITY_THREADS",
]
