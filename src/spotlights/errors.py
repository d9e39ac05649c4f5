"""User-facing errors.

Every error a user can cause (bad file, bad parameter) is raised as a
:class:`SpotlightsError`; the CLI prints its one-line message and exits with
its :attr:`~SpotlightsError.exit_code`, without a traceback: 2 for the input's
fault, 1 for a :class:`ProcessFailure` (the program's own machinery failed: a
helper process that died or hung), so that a script can tell the two apart.
"""

from __future__ import annotations

import importlib.util
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
    """An invalid parameter value (e.g. a rig with N < 1).

    The message names the library's parameters (``heading_margin``); ``parameters`` lists the ones it names, so
    that the command line can write them as its options instead (``--heading-margin``:
    :func:`spotlights.options.option_names`)."""

    def __init__(self, message: str, *parameters: str):
        self.parameters = parameters
        super().__init__(message)

    def __reduce__(self):  # picklable with its parameters (worker pools, Ray)
        return (type(self), (str(self), *self.parameters))


def shown(label: str) -> str:
    """A parameter's name as a message shows it: ```threads``` (the command line writes its option there,
    ``--threads``); any other label (``"train.seed"``, ``"the seed"``) as it is."""
    return f"`{label}`" if label.isidentifier() else label


def parameter_names(*labels: str) -> tuple[str, ...]:
    """The labels that are Python parameter names (``"threads"``, ``"batch_size"``), for
    :attr:`ParameterError.parameters`; option spellings (``"--seed"``) and descriptions (``"train.seed"``, ``"the
    seed"``) are left out (they are shown as written)."""
    return tuple(x for x in labels if x.isidentifier())


class OutputFileError(SpotlightsError):
    """An output that cannot be written (read-only folder, full disk, ...): ``"PATH: problem"``."""

    def __init__(self, path: str | os.PathLike, problem: str):
        self.path = os.fspath(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")

    def __reduce__(self):
        return (type(self), (self.path, self.problem))


#: optional package (top-level module) -> the extra of ``pyproject.toml`` that installs it
EXTRAS = {
    "torch": "learn",
    "pandas": "real",
    "pyarrow": "real",
    "laspy": "las",
    "lazrs": "las",
    "plotly": "viewer",
    "ray": "distributed",
    "onnx": "onnx",
    "onnxruntime": "onnx",
    "onnxscript": "onnx",
    "rerun": "rerun",
    "filterpy": "track",
    "shapely": "track",
    "motmetrics": "track",
}


def missing_extra(exc: ImportError) -> str | None:
    """The one line for an optional package that is not installed (``exc`` from its import): which package and
    which extra installs it; None when ``exc`` is not about one of :data:`EXTRAS` (a bug or a broken install)."""
    name = (getattr(exc, "name", None) or "").split(".")[0]
    if name not in EXTRAS or (exc.name != name and importlib.util.find_spec(name) is not None):
        return None  # a broken install of the package (a submodule missing), not a missing extra
    extra = EXTRAS[name]
    return f"this needs the optional package {name}: pip install 'spotlights[{extra}]' (or 'spotlights[all]')"
