"""The ``spotlights`` command's entry point: the console script (``[project.scripts]``) and ``python -m spotlights``.

Ctrl-C is held back while the command line's modules load (numpy's C extension turns a KeyboardInterrupt during
its import into an ImportError with a page of advice; pybind11 modules may abort): it arrives once they are
loaded, as one line and exit code 130, like a Ctrl-C during the command (:func:`spotlights.cli.main`). This module
imports nothing heavy itself (``import spotlights`` loads no numpy), so the console script's own imports are
covered too. Python's start-up before this module runs (a few tens of milliseconds) is not.
"""

from __future__ import annotations

import signal
import sys


def main() -> int:
    """Run the command line on ``sys.argv``; returns its exit code (130 for a Ctrl-C while it loads)."""
    held = hasattr(signal, "pthread_sigmask")
    before = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if held else None
    try:
        try:
            from .cli import main as run
        finally:
            if held:
                signal.pthread_sigmask(signal.SIG_SETMASK, before)  # a Ctrl-C held meanwhile is raised here
    except KeyboardInterrupt:
        print("spotlights: interrupted", file=sys.stderr)
        exec("pass")  # noqa: S102 - clears CPython's unhandled-interrupt note (spotlights.cli._forget_interrupt)
        return 130
    return run()
