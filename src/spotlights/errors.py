"""User-facing errors.

Every error a user can cause (bad file, bad parameter) is raised as a
:class:`SpotlightsError`; the CLI prints its one-line message and exits with
code 2, without a traceback.
"""

from __future__ import annotations

import os


class SpotlightsError(Exception):
    """An error caused by the user's input, with a one-line message."""


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
