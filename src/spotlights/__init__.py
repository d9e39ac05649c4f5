"""spotlights: the Spotlights shape representation (Wei et al.) as a library.

The public API (``docs/api.md``)::

    import spotlights
    rig = spotlights.make_rig()                                   # the paper's 32 x 64 cap rig
    depths = spotlights.encode_mesh(spotlights.load_mesh(path), rig)
    points, hit = spotlights.decode(depths, rig)
    result = spotlights.complete_frame(scan_points, boxes)        # every vehicle of a LiDAR frame
    for frame in spotlights.read_frames(folder, format="kitti"): ...

``import spotlights`` imports numpy only: every name is loaded from its home module on first use
(PEP 562 ``__getattr__``; the table in :mod:`spotlights.api`). Layers (imports point down only)::

    cli -> experiments -> learning -> viz -> data / analysis -> metrics -> geometry

``spotlights.geometry`` (rig, normalisation, ray casting, encoding, I/O) needs only
numpy/scipy/trimesh/embreex; torch is imported only by ``spotlights.learning``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ._version import __version__

if TYPE_CHECKING:  # the names as type checkers and IDEs see them
    from .api import (
        Box,
        SceneResult,
        complete,
        complete_frame,
        decode,
        encode_mesh,
        load_completer,
        load_mesh,
        make_rig,
        read_frames,
    )

#: public name -> the module that defines it (imported on first use)
_HOMES = {
    "Box": "spotlights.geometry.boxes",
    "make_rig": "spotlights.geometry.rig",
    "load_mesh": "spotlights.geometry.io",
    "encode_mesh": "spotlights.geometry.encode",
    "decode": "spotlights.geometry.encode",
    "load_completer": "spotlights.learning.runtime",
    "complete": "spotlights.api",
    "complete_frame": "spotlights.api",
    "SceneResult": "spotlights.completion.frame",
    "read_frames": "spotlights.api",
}

__all__ = [
    "__version__",
    "Box",
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


def __getattr__(name: str) -> Any:
    """PEP 562: import a public name's home module on first use, then keep the name here."""
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'spotlights' has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
