"""User-facing errors.

Every error a user can cause (bad file, bad parameter) is raised as a
:class:`SpotlightsError`; the CLI prints its one-line message and exits with
its :attr:`~SpotlightsError.exit_code`, without a traceback: 2 for the input's
fault, 1 for a :class:`ProcessFailure` (the program's own machinery failed: a
helper process that died or hung), so that a script can tell the two apart.
"""

from __future__ import annotations

import os


class SpotlightsError(Exception):
    """An error caused by the user's input, with a one-line message."""

    #: The command line's exit code for it (2: the input's fault).
    exit_code: int = 2


class ProcessFailure(SpotlightsError):
    """Not the input's fault: a process the command started to help it ended or hung (killed by the system for
    memory, say). One line naming what failed and what to try, exit code 1; running again may succeed."""

    exit_code = 1


class InputFileError(SpotlightsError):
    """A problem with one input file: the message is ``"PATH: problem"``."""

    def __init__(self, path: str | os.PathLike, problem: str):
        self.path = os.fspath(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")

    def __reduce__(self):  # picklable, so it crosses process boundaries (worker pools)
        return (type(self), (self.path, self.problem))


class ParameterError(SpotlightsError, ValueError):
    """An invalid parameter value (e.g. a rig with N < 1)."""


class OutputFileError(SpotlightsError):
    """An output that cannot be written (read-only folder, full disk, ...): ``"PATH: problem"``."""

    def __init__(self, path: str | os.PathLike, problem: str):
        self.path = os.fspath(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")

    def __reduce__(self):
        return (type(self), (self.path, self.problem))
