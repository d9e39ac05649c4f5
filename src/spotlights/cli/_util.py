"""Helpers shared by the CLI modules (formatting, argument types)."""

from __future__ import annotations

import argparse


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


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return v


def unit_interval(text: str) -> float:
    """argparse type: a finite number in [0, 1] (depth clips, thresholds in the unit frame)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not (0.0 <= v <= 1.0):
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return v


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}") from None
    if not (v > 0.0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return v


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0 (e.g. DataLoader workers, 0 = in-process)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return v
