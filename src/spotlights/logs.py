"""The library's logging: every module logs under the ``spotlights`` logger (stdlib :mod:`logging`), silent
unless the application configures it (``import spotlights`` adds a :class:`logging.NullHandler`). The command line
configures it: warnings on stderr, ``-v`` adds the info lines, ``-vv`` the debug lines, ``-q`` keeps errors only.

Functions that report summary lines take a ``say`` (and ``warn``) callback; their default is :func:`info`
(:func:`warning`): the lines go to the logger, where a Python user reads them by configuring logging, e.g.
``logging.basicConfig(level=logging.INFO)``.
"""

from __future__ import annotations

import logging

LOGGER = logging.getLogger("spotlights")


def info(line: str) -> None:
    """A summary line, logged at INFO under ``spotlights`` (the default ``say`` callback)."""
    LOGGER.info(line)


def warning(line: str) -> None:
    """A warning line, logged at WARNING under ``spotlights`` (the default ``warn`` callback)."""
    LOGGER.warning(line)


def configure(verbosity: int = 0, stream=None) -> logging.Handler:
    """Show the ``spotlights`` logger's records on ``stream`` (default stderr) as ``spotlights: LINE`` lines:
    warnings and errors at ``verbosity`` 0, info lines at 1, debug at 2 and more, errors only below 0. Returns the
    handler (remove it with ``LOGGER.removeHandler``); the command line calls this once per run."""
    handler = logging.StreamHandler(stream)
    handler.setFormatter(logging.Formatter("spotlights: %(message)s"))
    level = logging.ERROR if verbosity < 0 else {0: logging.WARNING, 1: logging.INFO}.get(verbosity, logging.DEBUG)
    LOGGER.setLevel(level)
    LOGGER.addHandler(handler)
    return handler
