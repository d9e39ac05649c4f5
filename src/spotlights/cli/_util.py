"""Helpers shared by the CLI modules (formatting, argument types)."""

from __future__ import annotations

import argparse

from ..errors import ParameterError


def add_command(sub, name: str, help: str, example: str, func=None) -> argparse.ArgumentParser:
    """Add a sub-command whose ``--help`` ends with an example."""
    p = sub.add_parser(
        name,
        help=help,
        description=help,
        epilog=f"example:\n  {example}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    if func is not None:
        p.set_defaults(func=func)
    return p


def add_group(sub, name: str, help: str, example: str, metavar: str = "SUBCOMMAND"):
    """Add (or reuse) a command group such as ``spotlights dataset``; return its sub-parsers.

    The group alone prints its help and exits with code 2. Several modules may add
    sub-commands to the same group (e.g. ``bench``): the second call reuses the first's.
    """
    existing = sub.choices.get(name)
    if existing is not None:
        for action in existing._actions:
            if isinstance(action, argparse._SubParsersAction):
                return action
    group = add_command(sub, name, help, example)
    group.set_defaults(func=lambda args: (group.print_help(), 2)[1])
    return group.add_subparsers(dest=f"{name}_command", metavar=metavar, parser_class=type(group))


def _number_type(cast, accept, expected: str):
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


def add_quiet(p: argparse.ArgumentParser, what: str = "no progress bar") -> None:
    """``-q/--quiet`` (progress bars and summary lines off; errors and warnings still on
    stderr), with ``--no-progress`` kept as a hidden alias for older scripts."""
    p.add_argument(
        "--quiet", "-q", action="store_true", help=f"{what} and no summary lines (errors and warnings still shown)"
    )
    p.add_argument("--no-progress", dest="quiet", action="store_true", help=argparse.SUPPRESS)


def settings_of(cls, args: argparse.Namespace, **values):
    """The settings dataclass ``cls`` of a command: each field from the parsed option of the same
    name (``--gt-points`` -> ``gt_points``), or from ``values`` (fields named otherwise)."""
    import dataclasses

    names = [f.name for f in dataclasses.fields(cls) if f.init and f.name not in values]
    return cls(**{n: getattr(args, n) for n in names if hasattr(args, n)}, **values)


DEVICE_HELP = "torch device: cpu, cuda or cuda:N (default: cuda when available, else cpu)"
PICTURE_SUFFIXES = (".png",)


def check_suffix(path, suffixes: tuple, what: str, option: str = "--out") -> None:
    """Refuse an output whose extension would not match what is written (one line naming it).

    ``suffixes``: the accepted lower-case extensions, e.g. ``(".h5", ".hdf5")``.
    """
    from pathlib import Path

    if path is None:
        return
    suffix = Path(path).suffix.lower()
    if suffix not in suffixes:
        shown = " or ".join(suffixes)
        raise ParameterError(
            f"{option} {path}: {what} is written as {shown}; name it {Path(path).stem or 'FILE'}{suffixes[0]}"
        )


def check_picture(path, option: str = "--out") -> None:
    """Pictures are written as PNG: refuse another extension rather than write PNG bytes under it."""
    check_suffix(path, PICTURE_SUFFIXES, "the picture", option)
