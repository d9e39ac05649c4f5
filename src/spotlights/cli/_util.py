"""Helpers shared by the CLI modules (formatting, argument types)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from ..errors import ParameterError
from ..options import (  # noqa: F401 - the argparse types, importable from here by every command module
    DEVICE_HELP,
    MAX_BATCH,
    MAX_CROP_M,
    SEED_HELP,
    batch_size_number,
    crop_metres,
    non_negative_float,
    non_negative_int,
    port_number,
    positive_float,
    positive_int,
    seed_number,
    settings_from_namespace,
    thread_count,
    unit_interval,
)
from ..outputs import check_suffix


def argparse_type(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """``parse`` (text -> value, raising :class:`~spotlights.errors.ParameterError`) as an argparse type: its
    message becomes the usage error ``argument --OPTION: MESSAGE`` (exit code 2)."""

    def convert(text: str):
        try:
            return parse(text)
        except ParameterError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    convert.__name__ = parse.__name__
    return convert


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


def add_quiet(p: argparse.ArgumentParser, what: str = "no progress bar") -> None:
    """``-q/--quiet`` (progress bars and summary lines off; errors and warnings still on
    stderr), with ``--no-progress`` kept as a hidden alias for older scripts."""
    p.add_argument(
        "--quiet", "-q", action="store_true", help=f"{what} and no summary lines (errors and warnings still shown)"
    )
    p.add_argument("--no-progress", dest="quiet", action="store_true", help=argparse.SUPPRESS)


CROP_MARGIN_HELP = f"grow each box by M metres on its sides and top, |M| <= {MAX_CROP_M:g} (default 0.15)"
"""Help of ``--margin`` (``complete``, ``real complete``, ``real extract``): metres within :data:`MAX_CROP_M`."""
CROP_GROUND_HELP = f"drop points below M metres over the box bottom (ground), |M| <= {MAX_CROP_M:g} (default 0.10)"
"""Help of ``--ground-clearance`` (``complete``, ``real complete``, ``real extract``)."""


#: Settings fields whose command-line type is fixed here whatever their declaration says: every ``--threads``
#: is bounded by :data:`spotlights.options.MAX_THREADS` (torch's OpenMP crashes on absurd counts).
FIELD_TYPES = {"threads": thread_count}


def add_options(
    parser: argparse.ArgumentParser, cls, only: tuple = (), grouped: bool = True, exclude: tuple = ()
) -> None:
    """Add the options declared on the dataclass ``cls`` (:func:`spotlights.options.option`) to ``parser``,
    in field order; the one way a command declares its options.

    only : these fields alone (default: every field with an option). exclude : all but these fields.
    grouped : under their sections' titles (a section the parser already has is reused, so blocks of
    options added by several calls share it). Options naming the same ``mutex`` exclude each other. A
    field of :data:`FIELD_TYPES` takes its type from there. A flag without leading dashes (the field's
    name) is a positional argument; every other option's ``dest`` is its field's name.
    """
    import dataclasses

    sections: dict = {}
    for f in dataclasses.fields(cls):
        kw = dict(f.metadata.get("cli") or {})
        if not kw or (only and f.name not in only) or f.name in exclude:
            continue
        if f.name in FIELD_TYPES and "type" in kw:
            kw["type"] = FIELD_TYPES[f.name]
        flags, title = kw.pop("flags") or (f"--{f.name.replace('_', '-')}",), kw.pop("group")
        target = _option_target(parser, sections, title if grouped else None, kw.pop("mutex", None))
        _add_field_option(target, cls, f, flags, kw)


def _option_target(parser: argparse.ArgumentParser, sections: dict, title: str | None, mutex: str | None):
    """Where an option goes: the parser, its section ``title`` (one the parser already has is reused) and, for
    options naming the same ``mutex``, a mutually exclusive group in it (``sections``: those made so far)."""
    target = parser
    if title is not None:
        if title not in sections:
            known = [g for g in parser._action_groups if g.title == title]  # noqa: SLF001 - no public lookup
            sections[title] = known[0] if known else parser.add_argument_group(title)
        target = sections[title]
    if mutex is not None:
        key = ("mutex", mutex)
        if key not in sections:
            sections[key] = target.add_mutually_exclusive_group()
        target = sections[key]
    return target


def _add_field_option(target, cls, f, flags: tuple, kw: dict) -> None:
    """Add the option (or positional, or ``-q``) of the dataclass field ``f`` with argparse keywords ``kw``."""
    import dataclasses

    has_default = f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
    default = f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
    if not flags[0].startswith("-"):  # a positional argument: its name is its dest
        if flags != (f.name,):
            raise ValueError(f"{cls.__name__}.{f.name}: a positional is named as its field, got {flags}")
        target.add_argument(*flags, **({"default": default} if has_default else {}), **kw)
    elif kw.pop("quiet", False):
        add_quiet(target, kw["help"])
    elif has_default:
        target.add_argument(*flags, default=default, dest=kw.pop("dest", f.name), **kw)
    else:
        target.add_argument(*flags, required=True, dest=kw.pop("dest", f.name), **kw)


def settings_of(cls, args: argparse.Namespace, **values):
    """The settings dataclass ``cls`` of a command: each field from the parsed option of the same
    name (``--gt-points`` -> ``gt_points``), or from ``values`` (fields named otherwise);
    :func:`spotlights.options.settings_from_namespace`."""
    return settings_from_namespace(cls, args, **values)


PICTURE_SUFFIXES = (".png",)


def check_picture(path, option: str = "--out") -> None:
    """Pictures are written as PNG: refuse another extension rather than write PNG bytes under it."""
    check_suffix(path, PICTURE_SUFFIXES, "the picture", option)
