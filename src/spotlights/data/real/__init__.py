"""Real LiDAR data: dataset readers, scan and box files, vehicle extraction.

- :mod:`.base` - the reader interface (:class:`Frame`, :class:`SceneReader`; boxes are
  :class:`spotlights.geometry.boxes.Box`).
- :mod:`.kitti`, :mod:`.av2`, :mod:`.kitti360`, :mod:`.nuscenes`, :mod:`.generic` - one module per format.
- :mod:`.scans` - raw scan files of every kind; :mod:`.boxfiles` - box files users bring.
- :mod:`.extract` - points inside vehicle boxes -> unit-frame partial observations (HDF5).
- :mod:`.show` - the paper's qualitative figure: raw scan, partial input, completion.

Completion of real scans and the consistency report (they run models) live one layer up,
in :mod:`spotlights.experiments.real_evaluation` and :mod:`spotlights.completion.frame`.
The file formats, frames and choices are documented in ``docs/real-data.md``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

from ...errors import InputFileError, ParameterError
from ...geometry.boxes import Box
from .av2 import Av2Reader
from .base import CLASSES, PAPER_CLASSES, Frame, SceneReader
from .generic import GenericReader
from .kitti import KittiReader
from .kitti360 import Kitti360Reader
from .nuscenes import NuScenesReader
from .scans import read_scan as _read

FORMATS = ("kitti", "kitti360", "av2", "nuscenes", "generic")

#: The options each reader takes (:func:`open_reader`'s ``**options``); any other is refused by name.
READER_OPTIONS = {
    "kitti": ("velodyne",),
    "kitti360": ("sequences", "frames"),
    "av2": (),
    "nuscenes": ("sequences",),
    "generic": ("boxes",),
}


def open_reader(source: str | os.PathLike | Sequence, format: str, **options) -> SceneReader:
    """Open ``source`` with the reader of ``format`` (one of :data:`FORMATS`).

    ``source`` may be a list of several sources of that format: their frames are read one
    after another (:class:`MultiReader`). ``options`` go to the reader: ``velodyne`` (kitti),
    ``sequences`` and ``frames`` (kitti360), ``sequences`` (nuscenes: scene names),
    ``boxes`` (generic, one scan file). Raises :class:`spotlights.errors.InputFileError`
    for a bad folder or file.
    """
    if format not in FORMATS:
        raise ParameterError(f"unknown format {format!r}; choose one of {', '.join(FORMATS)}")
    unknown = sorted(set(options) - set(READER_OPTIONS[format]))
    if unknown:
        allowed = ", ".join(READER_OPTIONS[format]) or "none"
        raise ParameterError(
            f"option(s) {', '.join(unknown)} are not options of the {format} reader (it takes: {allowed})"
        )
    if isinstance(source, (list, tuple)):
        if not source:
            raise ParameterError("no source given: name a dataset folder or scan file (or a list of them)")
        if len(source) == 1:
            source = source[0]
        else:
            if options.get("boxes") is not None:
                raise ParameterError("`boxes` names the box file of a single scan SOURCE, not of several", "boxes")
            return MultiReader([open_reader(s, format, **options) for s in source])
    if format == "kitti":
        return KittiReader(source, **options)
    if format == "av2":
        return Av2Reader(source, **options)
    if format == "kitti360":
        return Kitti360Reader(source, **options)
    if format == "nuscenes":
        return NuScenesReader(source, scenes=options.pop("sequences", None), **options)
    if format == "generic":
        return GenericReader(source, **options)
    raise ParameterError(f"unknown format {format!r}; choose one of {', '.join(FORMATS)}")


class MultiReader(SceneReader):
    """Several readers of one format as one dataset: their frames in the order of the readers.

    Frames keep their own sequence names, so two sources that name the same sequence are one
    sequence (tracks join across them: a drive split into several folders); a (sequence,
    frame_id) key found in two sources is an error naming both.
    """

    def __init__(self, readers: Sequence[SceneReader]):
        self.readers = list(readers)
        self.format = self.readers[0].format
        self.root = self.readers[0].root
        self.roots = [r.root for r in self.readers]
        self._owner: dict[tuple[str, str], SceneReader] = {}
        for r in self.readers:
            for key in r.frame_keys():
                if key in self._owner:
                    raise InputFileError(
                        r.root,
                        f"frame {key[1]!r} of sequence {key[0]!r} is also in {self._owner[key].root}: "
                        "give the sources different sequence names",
                    )
                self._owner[key] = r

    def frame_keys(self) -> list[tuple[str, str]]:
        keys = [k for r in self.readers for k in r.frame_keys()]
        # frames of one sequence spread over several sources are put in time order on load; keep source order here
        return keys

    def load(self, key: tuple[str, str]) -> Frame:
        return self._owner[key].load(key)


def read_scan(path: str | os.PathLike):
    """Read a raw scan file of any kind (see :mod:`.scans`): (N, 3) metres, its sensor frame."""
    return _read(path)


__all__ = [
    "CLASSES",
    "PAPER_CLASSES",
    "Box",
    "Frame",
    "SceneReader",
    "MultiReader",
    "FORMATS",
    "open_reader",
    "read_scan",
]
