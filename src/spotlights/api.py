"""The public API: the handful of names a user of the library needs, importable from ``spotlights``.

``import spotlights`` is light (numpy only): each name below is imported from its home module on
first use (PEP 562, ``spotlights.__getattr__``). Examples of every name: ``docs/api.md``.

=================  ============================================================================
name               home
=================  ============================================================================
``Box``            :class:`spotlights.geometry.boxes.Box` (the one oriented box)
``make_rig``       :func:`spotlights.geometry.rig.make_rig` (the paper's cap rig, box rigs)
``load_mesh``      :func:`spotlights.geometry.io.load_mesh` (a mesh in the object frame)
``encode_mesh``    :func:`spotlights.geometry.encode.encode_mesh` (mesh + rig -> depths)
``decode``         :func:`spotlights.geometry.encode.decode` (depths + rig -> points)
``load_completer`` :func:`spotlights.learning.runtime.load_completer` (torch or onnx runtime)
``complete``       :func:`spotlights.experiments.scene.complete` (one object in its box)
``complete_frame`` :func:`spotlights.experiments.scene.complete_frame` (every vehicle of a frame)
``SceneResult``    :class:`spotlights.experiments.scene.SceneResult` (what ``complete_frame`` returns)
``read_frames``    :func:`read_frames` (LiDAR frames with their boxes, any supported format)
=================  ============================================================================
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from typing import Any

from .data.real import FORMATS, open_reader
from .data.real.base import Frame
from .experiments.scene import ObjectResult, SceneConfig, SceneResult, complete, complete_frame
from .geometry.boxes import Box
from .geometry.encode import decode, encode_mesh
from .geometry.io import load_mesh
from .geometry.rig import make_rig
from .learning.runtime import load_completer


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
    "Frame",
    "ObjectResult",
    "SceneConfig",
    "SceneResult",
    "complete",
    "complete_frame",
    "decode",
    "encode_mesh",
    "load_completer",
    "load_mesh",
    "make_rig",
    "read_frames",
]
