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
import difflib
import os
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

from .errors import InputFileError, ParameterError, SpotlightsError, parameter_names, shown

REQUIRED: Any = dataclasses.MISSING
"""The default of an :func:`option` the command line must give (argparse ``required=True``)."""

DEVICE_HELP = "torch device: cpu, cuda or cuda:N (default: cuda when available, else cpu)"


def option(*flags: str, default: Any = REQUIRED, help: str, group: str | None = None, **argparse_kw: Any) -> Any:
    """A dataclass field that is also a command-line option.

    flags : option strings (default ``--FIELD-NAME``); one name without leading dashes, the field's
    own, declares a positional argument instead. The field's name is the option's ``dest``
    (``--no-track-worker`` on a field ``track_worker``). default : the field's and the option's
    default (a list is copied per instance; :data:`REQUIRED`: no default, a required option or a
    positional). help : the option's help. group : title of the ``--help`` section it is listed under
    (None: the command's own options). argparse_kw : ``type``, ``metavar``, ``choices``, ``action``
    (``argparse.BooleanOptionalAction`` too), ``nargs``; ``quiet=True`` declares ``-q/--quiet`` with
    its hidden alias ``--no-progress``; ``mutex=NAME``: options naming the same NAME exclude each other.
    """
    md = {"cli": {"flags": flags, "help": help, "group": group, **argparse_kw}}
    if isinstance(default, list):
        return dataclasses.field(default_factory=lambda: list(default), metadata=md)
    return dataclasses.field(default=default, metadata=md)


def number_type(cast: Callable[[str], Any], accept: Callable[[Any], bool], expected: str) -> Callable[[str], Any]:
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


positive_int = number_type(int, lambda v: v >= 1, "a whole number >= 1")
"""argparse type: an integer >= 1 (counts, batch sizes, epochs)."""
non_negative_int = number_type(int, lambda v: v >= 0, "a whole number >= 0")
"""argparse type: an integer >= 0 (e.g. DataLoader workers, 0 = in-process)."""
unit_interval = number_type(float, lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]")
"""argparse type: a finite number in [0, 1] (depth clips; NaN is refused)."""
positive_float = number_type(float, lambda v: 0.0 < v < float("inf"), "a finite number > 0")
"""argparse type: a finite number > 0 (distance thresholds)."""
non_negative_float = number_type(float, lambda v: 0.0 <= v < float("inf"), "a finite number >= 0")
"""argparse type: a finite number >= 0 (margins, noise levels)."""
port_number = number_type(int, lambda v: 0 <= v <= 65535, "a TCP port number in 0..65535")
"""argparse type: a TCP port, 0 (the system picks a free one) to 65535."""

MAX_THREADS = max(64, 4 * (os.cpu_count() or 1))
"""The most CPU threads a ``--threads`` option (or a ``threads`` argument) takes: 4 per CPU here, at least 64.
More is no speed-up, and OpenMP fails to start (or segfaults) at tens of thousands of threads."""

_THREADS_EXPECTED = f"a whole number of threads in 1..{MAX_THREADS} (the bound: 4 per CPU, at least 64)"


def check_threads(threads: Any, option: str = "threads") -> int | None:
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
        raise ParameterError(
            f"{shown(option)}: expected {_THREADS_EXPECTED}, got {threads!r}", *parameter_names(option)
        )
    return n


thread_count = number_type(int, lambda v: 1 <= v <= MAX_THREADS, _THREADS_EXPECTED)
"""argparse type: a thread count, 1..:data:`MAX_THREADS` (``--threads`` of every command; :func:`check_threads`)."""


# ---------------------------------------------------------------------------- seeds and batch sizes

MAX_SEED = 2**63 - 1
"""The largest seed of every ``--seed`` option and every config's ``seed``: a seed is stored as a signed 64-bit
integer (an HDF5 attribute of the dataset, NumPy int64) and handed to ``torch.manual_seed``, which unpacks a 64-bit
integer; a larger one failed there (a TypeError at the end of a dataset build, "Overflow when unpacking long long"
in torch). 0..2**63-1 is every seed NumPy, torch and HDF5 all accept."""

_SEED_EXPECTED = "a whole number in 0..2**63-1"


def check_seed(seed: Any, what: str = "seed") -> int:
    """``seed`` as an int, or a one-line :class:`ParameterError` naming ``what`` when it is not a whole number in
    0..:data:`MAX_SEED` (the one bound of every seed)."""
    whole = isinstance(seed, int) and not isinstance(seed, bool)
    if not whole and hasattr(seed, "dtype") and getattr(seed.dtype, "kind", "") in "iu":  # a NumPy integer
        seed, whole = int(seed), True
    elif not whole and isinstance(seed, float) and seed.is_integer():  # 3.0 from a JSON or YAML config
        seed, whole = int(seed), True
    if not whole or not 0 <= seed <= MAX_SEED:
        raise ParameterError(f"{shown(what)} must be {_SEED_EXPECTED}, got {seed!r}", *parameter_names(what))
    return int(seed)


seed_number = number_type(int, lambda v: 0 <= v <= MAX_SEED, _SEED_EXPECTED)
"""argparse type: a seed, 0..:data:`MAX_SEED` (every ``--seed``; :func:`check_seed`)."""

SEED_HELP = "0..2**63-1"
"""Said in every ``--seed`` option's help: its range (:data:`MAX_SEED`)."""

MAX_BATCH = 4096
"""The largest batch size (``train --batch-size`` and ``train.batch_size``, ``evaluate``/``real complete``
``--batch-size``, ``bench models --batch``): 128 times the paper's 32. Memory grows with it: PCN's folding decoder
alone holds 16,384 points x 512 channels (32 MB float32) per sample and layer, so 4096 samples already fill an
80 GB GPU; 100,000 asked for 26 GB at the first step and 10^8 for 300 GB."""

batch_size_number = number_type(int, lambda v: 1 <= v <= MAX_BATCH, f"a batch size in 1..{MAX_BATCH}")
"""argparse type: a batch size, 1..:data:`MAX_BATCH`."""


def check_batch_size(value: Any, what: str = "batch_size") -> int:
    """``value`` as an int, or a one-line :class:`ParameterError` naming ``what`` when it is not a whole number in
    1..:data:`MAX_BATCH` (the one bound of every batch size)."""
    whole = isinstance(value, int) and not isinstance(value, bool)
    if not whole and isinstance(value, float) and value.is_integer():  # YAML 1e3
        value, whole = int(value), True
    if not whole or not 1 <= value <= MAX_BATCH:
        raise ParameterError(
            f"{shown(what)} must be a whole number in 1..{MAX_BATCH} (batch sizes are bounded: memory "
            f"grows with them), got {value!r}",
            *parameter_names(what),
        )
    return int(value)


# ---------------------------------------------------------------------------- axis values

AXIS_OPTIONS = ("--up", "--forward")
"""Options whose value is an axis (x, y, z, -x, -y, -z): ``--up -z`` is read as the value ``-z`` (argparse alone
takes ``-z`` for an option and says "expected one argument"); ``--up=-z`` works either way."""

_AXIS_VALUES = frozenset(f"{s}{a}" for s in ("-", "+") for a in "xyzXYZ")


def join_axis_values(argv: list[str]) -> list[str]:
    """``argv`` with every ``--up -z`` / ``--forward -x`` (an :data:`AXIS_OPTIONS` option followed by a signed axis)
    written as one token ``--up=-z``; nothing after ``--`` is touched."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        if a == "--":
            out.extend(argv[i:])
            break
        if a in AXIS_OPTIONS and i + 1 < len(argv) and argv[i + 1] in _AXIS_VALUES:
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


# ---------------------------------------------------------------------------- crop margins

MAX_CROP_M = 10.0
"""The largest crop margin or ground clearance, metres, either sign (``complete`` and ``real complete``/``real
extract`` ``--margin``, ``--crop``, ``--ground-clearance``): a box grown by more takes in the vehicles of the next
lanes (a lane is 3.5 m wide) and the road; the defaults are 0.15 and 0.10. 1e300 overflowed NumPy's squared
norms and ran on with a crop of the whole scan."""

crop_metres = number_type(
    float, lambda v: -MAX_CROP_M <= v <= MAX_CROP_M, f"a number of metres in [-{MAX_CROP_M:g}, {MAX_CROP_M:g}]"
)
"""argparse type: a crop margin or ground clearance, metres in [-:data:`MAX_CROP_M`, :data:`MAX_CROP_M`]."""


# ---------------------------------------------------------------------------- error messages as the CLI shows them


def option_names(exc: Exception, parser: argparse.ArgumentParser) -> str:
    """The error's message with the library parameters it names (:attr:`ParameterError.parameters`, shown as
    ```heading_margin```: :func:`spotlights.errors.shown`) written as the command line's options:
    ``--heading-margin`` (the option whose ``dest`` it is, in any command; else the name with dashes)."""
    message = str(exc)
    names = getattr(exc, "parameters", ())
    if not names:
        return message
    options = _options_by_dest(parser)
    for name in sorted(names, key=len, reverse=True):
        dashed = "--" + name.replace("_", "-")
        flags = options.get(name, [])
        flag = dashed if dashed in flags or not flags else flags[0]
        message = message.replace(f"`{name}`", flag)
    return message


def _options_by_dest(parser: argparse.ArgumentParser) -> dict[str, list[str]]:
    """``{dest: its long options}`` over a parser and all its sub-commands."""
    out: dict[str, list[str]] = {}
    for action in parser._actions:  # noqa: SLF001 - argparse has no public walk of its actions
        for flag in (o for o in action.option_strings if o.startswith("--")):
            if flag not in out.setdefault(action.dest, []):
                out[action.dest].append(flag)
        if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
            for sub in action.choices.values():
                for dest, flags in _options_by_dest(sub).items():
                    out.setdefault(dest, []).extend(f for f in flags if f not in out[dest])
    return out


# ---------------------------------------------------------------------------- settings read from dicts and namespaces

_T = TypeVar("_T")


def did_you_mean(key: object, known: Iterable[str]) -> str:
    """``" (did you mean 'x'?)"`` for the closest known name to ``key``, or ``""``."""
    close = difflib.get_close_matches(str(key), list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def settings_from_dict(cls: type, d: object, where: str | os.PathLike | None = None, **fixed: object):
    """The one policy for reading a settings dataclass from a mapping (a YAML file, a JSON
    record, a dataset's attributes): every key must be a field of ``cls``; an unknown key is an
    error naming ``where`` and suggesting the closest field; a non-mapping is an error too.

    Parameters
    ----------
    cls : a dataclass type.
    d : the mapping (None reads as empty).
    where : a file path (the error is an :class:`InputFileError` naming it) or a label such as
        ``"sensor"`` (a :class:`ParameterError` prefixed with it).
    fixed : values passed to ``cls`` beside ``d``'s (not checked against ``d``).

    Returns ``cls(**d, **fixed)``; a wrong value that ``cls`` itself rejects keeps its own error.
    """

    def fail(msg: str) -> SpotlightsError:
        if where is not None and Path(os.fspath(where)).suffix.lower() in (".yaml", ".yml", ".json", ".h5", ".hdf5"):
            return InputFileError(where, msg)
        return ParameterError(f"{where}: {msg}" if where else msg)

    if d is None:
        d = {}
    if not isinstance(d, Mapping):
        raise fail(f"expected a mapping of {cls.__name__} settings, got {type(d).__name__}")
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    for key in d:
        if key not in names:
            raise fail(f"unknown setting {key!r}{did_you_mean(key, names)} (known: {', '.join(names)})")
    return cls(**dict(d), **fixed)


def settings_from_namespace(cls: type[_T], namespace: object, **values: object) -> _T:
    """The settings dataclass ``cls`` of an object with one attribute per field (an ``argparse.Namespace``):
    each field the namespace has is taken from the attribute of its name (or from ``values``, for fields
    named otherwise), the others keep their defaults; attributes that are no field are ignored (the
    command-line options map one to one onto the fields)."""
    names = [f.name for f in dataclasses.fields(cls) if f.init and f.name not in values]  # type: ignore[arg-type]
    return cls(**{n: getattr(namespace, n) for n in names if hasattr(namespace, n)}, **values)
