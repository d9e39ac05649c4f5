"""Real LiDAR data: dataset readers, vehicle extraction, consistency evaluation.

- :mod:`.base` - the reader interface (:class:`Box`, :class:`Frame`, :class:`SceneReader`).
- :mod:`.kitti`, :mod:`.av2`, :mod:`.kitti360`, :mod:`.generic` - one module per format.
- :mod:`.extract` - points inside vehicle boxes -> unit-frame partial observations (HDF5).
- :mod:`.evaluate` - completion of the observations and the consistency table (paper Table 2).
- :mod:`.show` - the paper's qualitative figure: raw scan, partial input, completion.

The file formats, frames and choices are documented in ``docs/real-data.md``.
"""

from __future__ import annotations

import os

from .base import CLASSES, Box, Frame, SceneReader

FORMATS = ("kitti", "kitti360", "av2", "generic")


def open_reader(source: str | os.PathLike, format: str, **options) -> SceneReader:
    """Open ``source`` with the reader of ``format`` (one of :data:`FORMATS`).

    ``options`` go to the reader: ``velodyne`` (kitti), ``sequences`` and
    ``frames`` (kitti360), ``boxes`` (generic). Raises
    :class:`spotlights.errors.InputFileError` for a bad folder or file.
    """
    from ...errors import ParameterError

    if format == "kitti":
        from .kitti import KittiReader

        return KittiReader(source, **options)
    if format == "av2":
        from .av2 import Av2Reader

        return Av2Reader(source, **options)
    if format == "kitti360":
        from .kitti360 import Kitti360Reader

        return Kitti360Reader(source, **options)
    if format == "generic":
        from .generic import GenericReader

        return GenericReader(source, **options)
    raise ParameterError(f"unknown format {format!r}; choose one of {', '.join(FORMATS)}")


def read_scan(path: str | os.PathLike):
    """Read a raw scan file of any reader: (N, 3) float32, metres, its sensor frame."""
    from .generic import read_points_file

    return read_points_file(path)


__all__ = ["CLASSES", "Box", "Frame", "SceneReader", "FORMATS", "open_reader", "read_scan"]
