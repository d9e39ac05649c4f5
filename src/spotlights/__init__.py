"""spotlights: the Spotlights shape representation (Wei et al.) as a library.

The public API (``docs/api.md``)::

    import spotlights
    rig = spotlights.make_rig()                                   # the paper's 32 x 64 cap rig
    depths = spotlights.encode_mesh(spotlights.load_mesh(path), rig)
    points, hit = spotlights.decode(depths, rig)
    result = spotlights.complete_frame(scan_points, boxes)        # every vehicle of a LiDAR frame
    result.save("out/frame.ply")                                  # the PLY and JSON ``spotlights complete`` writes
    for frame in spotlights.read_frames(folder, format="kitti"): ...

``import spotlights`` imports numpy only: every name is loaded from its home module on first use
(PEP 562 ``__getattr__``; the table in :mod:`spotlights.api`). Layers (imports point down only)::

    cli -> experiments -> completion -> tracking -> learning -> viz -> data / analysis -> metrics -> geometry

``spotlights.geometry`` (rig, normalisation, ray casting, encoding, I/O) needs only
numpy/scipy/trimesh/embreex; torch is imported only by ``spotlights.learning``.
"""

from __future__ import annotations


def _hold_sigint_for_the_command() -> object:
    """When this import starts the ``spotlights`` command (``python -m spotlights``, or the console script), block
    Ctrl-C (SIGINT) in this thread at once and return the signal mask before, else None. A Ctrl-C that came while
    the package, numpy or :mod:`spotlights.entry` loaded gave a traceback and exit -2; held here, it is raised by
    :func:`spotlights.entry.main` once the command line's modules are loaded: one line, exit 130."""
    import os
    import signal
    import sys

    argv = list(getattr(sys, "orig_argv", ()))
    by_module = any(a == "-m" and b in ("spotlights", "spotlights.__main__") for a, b in zip(argv, argv[1:]))
    main = getattr(sys.modules.get("__main__"), "__file__", None) or ""
    by_script = (
        bool(sys.argv)
        and os.path.basename(sys.argv[0]) in ("spotlights", "spotlights.exe")
        and (os.path.basename(main) in ("spotlights", "spotlights.exe", "__main__.py"))
    )
    if not (by_module or by_script) or not hasattr(signal, "pthread_sigmask"):
        return None
    return signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})


#: the signal mask before the command held Ctrl-C (None: imported as a library); taken by spotlights.entry.main
_SIGINT_MASK_BEFORE = _hold_sigint_for_the_command()

import importlib  # noqa: E402 - after the hold above: a Ctrl-C while these load waits for the command
import logging  # noqa: E402
from typing import TYPE_CHECKING, Any  # noqa: E402

from ._version import __version__  # noqa: E402

if TYPE_CHECKING:  # the names as type checkers and IDEs see them
    from .api import (
        BaseCompleter,
        Box,
        Frame,
        ObjectResult,
        SceneConfig,
        SceneResult,
        complete,
        complete_frame,
        decode,
        encode_mesh,
        load_box,
        load_completer,
        load_mesh,
        load_points,
        make_rig,
        read_frames,
        save_points,
        track_boxes,
    )

logging.getLogger("spotlights").addHandler(logging.NullHandler())  # silent unless the application configures it

#: public name -> the module that defines it (imported on first use); the one list of public names
_HOMES = {
    "Box": "spotlights.geometry.boxes",
    "load_box": "spotlights.geometry.box_json",
    "make_rig": "spotlights.geometry.rig",
    "load_mesh": "spotlights.geometry.io",
    "load_points": "spotlights.geometry.io",
    "save_points": "spotlights.geometry.io",
    "encode_mesh": "spotlights.geometry.encode",
    "decode": "spotlights.geometry.encode",
    "Frame": "spotlights.data.real.base",
    "read_frames": "spotlights.api",
    "BaseCompleter": "spotlights.learning.inference",
    "load_completer": "spotlights.learning.runtime",
    "SceneConfig": "spotlights.completion.scene_config",
    "ObjectResult": "spotlights.completion.results",
    "SceneResult": "spotlights.completion.results",
    "complete": "spotlights.api",
    "complete_frame": "spotlights.api",
    "track_boxes": "spotlights.tracking.tracker",
}

#: the same names as :data:`_HOMES` (tests/test_api.py checks it)
__all__ = [
    "__version__",
    "Box",
    "load_box",
    "make_rig",
    "load_mesh",
    "load_points",
    "save_points",
    "encode_mesh",
    "decode",
    "Frame",
    "read_frames",
    "BaseCompleter",
    "load_completer",
    "SceneConfig",
    "ObjectResult",
    "SceneResult",
    "complete",
    "complete_frame",
    "track_boxes",
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
