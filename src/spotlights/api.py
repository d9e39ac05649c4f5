"""The public API: the handful of names a user of the library needs, importable from ``spotlights``.

``import spotlights`` is light (numpy only): each name below is imported from its home module on
first use (PEP 562, ``spotlights.__getattr__``). Examples of every name: ``docs/api.md``.

==================  ===========================================================================
name                home
==================  ===========================================================================
``Box``             :class:`spotlights.geometry.boxes.Box` (the one oriented box; ``load_box`` reads a box file)
``make_rig``        :func:`spotlights.geometry.rig.make_rig` (the paper's cap rig, box rigs)
``load_mesh``       :func:`spotlights.geometry.io.load_mesh` (a mesh in the object frame)
``load_points``     :func:`spotlights.geometry.io.load_points` (a point file: PLY, PCD, XYZ, NPY, ...)
``save_points``     :func:`spotlights.geometry.io.save_points` (points to a file, by suffix)
``encode_mesh``     :func:`spotlights.geometry.encode.encode_mesh` (mesh + rig -> depths)
``decode``          :func:`spotlights.geometry.encode.decode` (depths + rig -> points)
``Frame``           :class:`spotlights.data.real.base.Frame` (a LiDAR frame with its boxes)
``read_frames``     :func:`read_frames` (LiDAR frames with their boxes, any supported format)
``load_completer``  :func:`spotlights.learning.runtime.load_completer` (torch or onnx runtime)
``BaseCompleter``   :class:`spotlights.learning.inference.BaseCompleter` (what ``load_completer`` returns)
``SceneConfig``     :class:`spotlights.completion.scene_config.SceneConfig` (the options of a frame's completion)
``complete``        :func:`complete` (one object in its box)
``complete_frame``  :func:`complete_frame` (every vehicle of a frame: ``completion.frame.complete_scene``)
``SceneResult``     :class:`spotlights.completion.results.SceneResult` (what ``complete_frame`` returns;
                    ``save(path)`` writes the PLY and JSON ``spotlights complete`` writes)
``ObjectResult``    :class:`spotlights.completion.results.ObjectResult` (one box's outcome)
``track_boxes``     :func:`spotlights.tracking.tracker.track_boxes` (a detector's boxes of many frames -> tracks)
==================  ===========================================================================
"""

from __future__ import annotations

import dataclasses
import difflib
import logging
import os
import threading
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from .completion.frame import complete_scene
from .completion.results import ObjectResult, SceneResult
from .completion.scan import AUTO_FALLBACK, resolve_fallback
from .completion.scene_config import SceneConfig
from .data.real import FORMATS, open_reader
from .data.real.base import Frame
from .errors import ParameterError
from .geometry.box_json import load_box
from .geometry.boxes import Box
from .geometry.encode import decode, encode_mesh
from .geometry.io import load_mesh, load_points, save_points
from .geometry.rig import make_rig
from .learning.checkpoint import PRETRAINED
from .learning.inference import BaseCompleter
from .learning.runtime import fallback_runtime, load_completer
from .tracking.tracker import track_boxes

LOG = logging.getLogger(__name__)

CompleterLike = BaseCompleter | str | os.PathLike | None
"""A model as the API takes it: loaded (:func:`load_completer`), or its name or file (``"default"``, ``"classes"``,
``"paper"``, ``model.pt``, ``model.onnx``); None: the default (for a fallback: none)."""


def complete_frame(
    points: np.ndarray,
    boxes: Sequence[Box],
    completer: CompleterLike = "default",
    config: SceneConfig | None = None,
    *,
    axes: np.ndarray | None = None,
    checkpoint: str | None = None,
    fallback: CompleterLike = AUTO_FALLBACK,
    sensor: np.ndarray | None = None,
    **options: Any,
) -> SceneResult:
    """Complete every vehicle of one LiDAR frame: :func:`~spotlights.completion.frame.complete_scene` (what
    ``spotlights complete`` and ``real complete`` run) with the model given by name or object and the options
    as keywords.

    Parameters
    ----------
    points : (N, 3) scan points, metres, the scan's frame (float32 or float64).
    boxes : the frame's :class:`~spotlights.geometry.boxes.Box` objects in the same frame; only boxes with a
        vehicle ``cls`` are completed (``any_label=True`` completes every box).
    completer : a loaded completer (:func:`spotlights.learning.runtime.load_completer`), or a checkpoint
        name or file (``"default"``, ``"paper"``, ``"classes"``, ``model.pt``, ``model.onnx``) loaded on the CPU/GPU with
        the runtime its suffix implies, on the first call only (a model given by name, and the fallback, are kept
        for the next calls: :data:`NAMED_MODELS_KEPT`; a file that changed is loaded again).
    config : a :class:`~spotlights.completion.frame.SceneConfig`; or give its fields as keyword ``options`` (``margin=0.2``,
        ``heading_check=True``, ...), not both.
    axes : optional (3, 3) rotation scan coordinates -> object convention (x forward, y left, z up).
    checkpoint : the model's name for the result's summary (default: ``completer`` when it is a name).
    fallback : a second model (loaded, or a name such as ``"classes"``) for the boxes ``completer`` did not learn
        but it did (``ObjectResult.completed_by`` names it); ``"auto"`` (default): the packaged class model
        ``"classes"`` when ``completer`` is the name ``"default"`` (or None), else none
        (:func:`~spotlights.completion.scan.resolve_fallback`, as ``--fallback``); ``"none"`` or None:
        such boxes are left as observed points.
    sensor : (3,) the LiDAR's position in the scan's frame, metres (default: the scan's origin, as in a sensor-frame
        scan): the free space of the ray-local model and the ``snap`` option's occlusion rule.

    Returns a :class:`~spotlights.completion.frame.SceneResult` (scan frame, metres): ``xyz``, ``source`` and
    ``object`` per point, one :class:`~spotlights.completion.frame.ObjectResult` per box. Raises :class:`~spotlights.errors.ParameterError` for
    unknown options or a scan with fewer than ``min_points`` points.
    """
    config = _scene_config(config, options)
    by_name = completer is None or isinstance(completer, (str, os.PathLike))
    if isinstance(fallback, (str, os.PathLike)) or fallback is None:
        # a loaded main model is not the packaged default as far as "auto" knows: no fallback beside it
        fallback = resolve_fallback(
            None if fallback is None else str(fallback), str(completer or "default") if by_name else ""
        )
    if completer is None or isinstance(completer, (str, os.PathLike)):
        name = "default" if completer is None else str(os.fspath(completer))
        completer = _named_completer(name)
        checkpoint = name if checkpoint is None else checkpoint
    fallback_name = None
    if isinstance(fallback, str):  # beside a loaded model: with its runtime and precision where the fallback can
        runtime = "auto" if by_name else fallback_runtime(getattr(completer, "runtime", "torch"), fallback)
        precision = "auto" if by_name else getattr(completer, "precision", "fp32")
        precision = precision if precision in ("fp32", "bf16") else "auto"
        fallback_name, fallback = fallback, _named_completer(fallback, runtime, precision)
    return complete_scene(
        points,
        boxes,
        completer,
        config,
        axes=axes,
        checkpoint=checkpoint,
        sensor=sensor,
        fallback=fallback,
        fallback_name=fallback_name,
    )


#: models that :func:`complete_frame` and :func:`complete` loaded by name, kept for the next call
_NAMED: dict[tuple, BaseCompleter] = {}
_NAMED_LOCK = threading.Lock()
NAMED_MODELS_KEPT = 4
"""At most this many models given by name are kept (the least recently used is dropped first)."""


def _new_named_lock_after_fork() -> None:
    """In a forked child: the lock may have been held by a thread of the parent (loading a model) at the fork."""
    global _NAMED_LOCK
    _NAMED_LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_new_named_lock_after_fork)


def _named_completer(name: str, runtime: str = "auto", precision: str = "auto") -> BaseCompleter:
    """The model ``name`` (a packaged name or a checkpoint/ONNX file) as :func:`load_completer` loads it, loaded once
    and kept for later calls (a frame loop of ``complete_frame(points, boxes)`` loaded the default and the class
    model on every call: 0.14 s a nuScenes frame against 0.08 s with models loaded once). A file is loaded again
    when it changed (its inode, size, modification or change time); its older model is dropped then. ``runtime``
    and ``precision``: as :func:`load_completer` takes them."""
    key: tuple = (name, runtime, precision)
    if name not in PRETRAINED:
        try:
            path = os.path.realpath(os.path.expanduser(name))
            st = os.stat(path)
        except OSError:  # load_completer names the missing file
            return load_completer(name, runtime=runtime, precision=precision)  # type: ignore[arg-type]
        key = (path, runtime, precision, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)
    with _NAMED_LOCK:  # one load per key, whatever the callers' threads
        model = _NAMED.pop(key, None)
        if model is None:
            for old in [k for k in _NAMED if k[:3] == key[:3]]:  # an older version of the same file
                del _NAMED[old]
            model = load_completer(name, runtime=runtime, precision=precision)  # type: ignore[arg-type]
            LOG.info("loaded the model %s (%s)", name, getattr(model, "device", "?"))
        _NAMED[key] = model  # the most recently used last
        while len(_NAMED) > NAMED_MODELS_KEPT:
            _NAMED.pop(next(iter(_NAMED)))
    return model


def complete(
    points: np.ndarray,
    box: Box,
    completer: CompleterLike = "default",
    *,
    axes: np.ndarray | None = None,
    fallback: CompleterLike = AUTO_FALLBACK,
    **options: Any,
) -> ObjectResult:
    """Complete one object: the points of ``points`` (N, 3) inside ``box`` (scan frame, metres; grown by
    ``margin``, bottom raised by ``ground_clearance``, as in :func:`complete_frame`; ``crop=False`` uses
    every point), whatever the box's label.

    ``completer``, ``fallback`` (``"auto"``: the packaged class model completes a van, truck, bus or trailer beside
    the default model; ``"none"``: no second model) and ``options`` (the fields of
    :class:`~spotlights.completion.frame.SceneConfig`) as in :func:`complete_frame`. Returns the box's :class:`~spotlights.completion.frame.ObjectResult`: ``completion`` (K, 3) float64 in the scan's frame,
    ``completion_unit`` (K, 3) float32 in the box's unit frame, ``partial_unit`` (256, 3) float32 (the
    model's input), ``input_indices`` (the scan rows used). Raises
    :class:`~spotlights.errors.ParameterError` when the box is invalid, holds fewer than ``min_points``
    points or the completion is empty.
    """
    config = dataclasses.replace(_scene_config(None, options), any_label=True)
    o = complete_frame(points, [box], completer, config, axes=axes, fallback=fallback).objects[0]
    if o.status == "invalid_box":
        raise ParameterError(f"the box is not valid (sizes must be positive and finite): {box!r}")
    if o.status == "too_few_points":
        raise ParameterError(
            f"{len(o.input_indices)} point(s) lie in the box; at least {config.min_points} are needed "
            "(is the box in the points' frame?)"
        )
    if o.status == "not_learned":
        raise ParameterError(
            f"the model did not learn this box ({'; '.join(o.warnings[:-1])}); pass complete_unknown=True to "
            "complete it anyway"
        )
    if o.status == "empty_completion":
        raise ParameterError("the completion is empty (every ray was clipped); try clip=None")
    return o


def _scene_config(config: SceneConfig | None, options: dict) -> SceneConfig:
    """``config``, or a :class:`~spotlights.completion.frame.SceneConfig` of the keyword ``options`` (unknown
    names: an error naming the nearest)."""
    if config is not None:
        if options:
            raise ParameterError(f"give either a config or its fields ({', '.join(sorted(options))}), not both")
        return config
    known = [f.name for f in dataclasses.fields(SceneConfig)]
    for name in options:
        if name not in known:
            near = difflib.get_close_matches(name, known, n=1)
            hint = f" (did you mean {near[0]}?)" if near else f"; known: {', '.join(known)}"
            raise ParameterError(f"unknown option {name!r}{hint}")
    if isinstance(options.get("classes"), str):
        options["classes"] = (options["classes"],)
    return SceneConfig(**options)


def read_frames(
    source: str | os.PathLike | Sequence[str | os.PathLike], format: str, **options: Any
) -> Iterator[Frame]:
    """The frames of a LiDAR dataset, one at a time, in sequence then time order.

    Parameters
    ----------
    source : a dataset folder (or, for ``format="generic"``, a scan file or a folder of scans),
        or a list of several of one format.
    format : one of ``kitti``, ``kitti360``, ``av2``, ``nuscenes``, ``generic`` (see docs/real-data.md).
    options : reader options: ``velodyne`` (kitti), ``sequences`` (kitti360, nuscenes), ``frames``
        (kitti360), ``boxes`` (generic, the box file of one scan).

    Yields :class:`~spotlights.data.real.base.Frame` objects: ``points`` (P, 3) float32 in the sensor
    frame (metres), ``boxes`` (:class:`Box`, sensor frame, with ``cls``), ``sequence``, ``frame_id``,
    ``timestamp``. The folder is checked before the first frame is read: a bad one raises
    :class:`~spotlights.errors.InputFileError` naming the file.
    """
    reader = open_reader(list(source) if isinstance(source, (list, tuple)) else source, format, **options)
    return reader.frames()


__all__ = [
    "FORMATS",
    "Box",
    "BaseCompleter",
    "CompleterLike",
    "Frame",
    "ObjectResult",
    "SceneConfig",
    "SceneResult",
    "complete",
    "complete_frame",
    "decode",
    "encode_mesh",
    "load_box",
    "load_completer",
    "load_mesh",
    "load_points",
    "make_rig",
    "read_frames",
    "save_points",
    "track_boxes",
]
