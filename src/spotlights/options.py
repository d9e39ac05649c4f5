"""Command-line options declared where their values live: on the settings dataclasses.

A settings field made with :func:`option` carries its command-line flags, help text and argparse
keywords in ``field.metadata["cli"]``; ``spotlights.cli`` adds those options to a command's
parser in field order, so the default, the help and the field are written once (a settings
object and its command cannot disagree). The argparse value types below check numbers on the
command line (one usage line, exit code 2, when they do not fit).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from collections.abc import Callable
from typing import Any

from .errors import ParameterError

REQUIRED: Any = dataclasses.MISSING
"""The default of an :func:`option` the command line must give (argparse ``required=True``)."""

DEVICE_HELP = "torch device: cpu, cuda or cuda:N (default: cuda when available, else cpu)"


def option(*flags: str, default: Any = REQUIRED, help: str, group: str | None = None, **argparse_kw: Any) -> Any:
    """A dataclass field that is also a command-line option.

    flags : option strings (default ``--FIELD-NAME``). default : the field's and the option's
    default (a list is copied per instance; :data:`REQUIRED`: no default, a required option).
    help : the option's help. group : title of the ``--help`` section it is listed under (None:
    the command's own options). argparse_kw : ``type``, ``metavar``, ``choices``, ``action``,
    ``nargs``; ``quiet=True`` declares ``-q/--quiet`` with its hidden alias ``--no-progress``;
    ``mutex=NAME``: options naming the same NAME exclude each other.
    """
    md = {"cli": {"flags": flags, "help": help, "group": group, **argparse_kw}}
    if isinstance(default, list):
        return dataclasses.field(default_factory=lambda: list(default), metadata=md)
    return dataclasses.field(default=default, metadata=md)


def _number_type(cast: Callable[[str], Any], accept: Callable[[Any], bool], expected: str) -> Callable[[str], Any]:
    """An argparse type: ``cast(text)`` that must satisfy ``accept``, else a usage error saying ``expected``."""

    def parse(text: str):
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not accept(value):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    parse.__name__ = expected
    return parse


positive_int = _number_type(int, lambda v: v >= 1, "a whole number >= 1")
"""argparse type: an integer >= 1 (counts, batch sizes, epochs)."""
non_negative_int = _number_type(int, lambda v: v >= 0, "a whole number >= 0")
"""argparse type: an integer >= 0 (e.g. DataLoader workers, 0 = in-process)."""
unit_interval = _number_type(float, lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]")
"""argparse type: a finite number in [0, 1] (depth clips; NaN is refused)."""
positive_float = _number_type(float, lambda v: 0.0 < v < float("inf"), "a finite number > 0")
"""argparse type: a finite number > 0 (distance thresholds)."""
non_negative_float = _number_type(float, lambda v: 0.0 <= v < float("inf"), "a finite number >= 0")
"""argparse type: a finite number >= 0 (margins, noise levels)."""
port_number = _number_type(int, lambda v: 0 <= v <= 65535, "a TCP port number in 0..65535")
"""argparse type: a TCP port, 0 (the system picks a free one) to 65535."""

MAX_THREADS = max(64, 4 * (os.cpu_count() or 1))
"""The most CPU threads a ``--threads`` option (or a ``threads`` argument) takes: 4 per CPU here, at least 64.
More is no speed-up, and OpenMP fails to start (or segfaults) at tens of thousands of threads."""

_THREADS_EXPECTED = f"a whole number of threads in 1..{MAX_THREADS} (the bound: 4 per CPU, at least 64)"


def check_threads(threads: Any, option: str = "--threads") -> int | None:
    """``threads`` as an int (None stays None: the default count), or a one-line :class:`ParameterError` naming
    ``option`` when it is not a whole number in 1..:data:`MAX_THREADS` (the one bound of every thread count)."""
    if threads is None:
        return None
    try:
        n = int(threads)
        whole = not isinstance(threads, bool) and n == threads
    except (TypeError, ValueError, OverflowError):
        whole = False
    if not whole or not 1 <= n <= MAX_THREADS:
        raise ParameterError(f"{option}: expected {_THREADS_EXPECTED}, got {threads!r}")
    return n


thread_count = _number_type(int, lambda v: 1 <= v <= MAX_THREADS, _THREADS_EXPECTED)
"""argparse type: a thread count, 1..:data:`MAX_THREADS` (``--threads`` of every command; :func:`check_threads`)."""
