"""Reading what users and datasets bring, for every layer: a JSON file parsed with one clear error
whatever is wrong with it, and a path named inside a dataset kept inside that dataset's folder."""

from __future__ import annotations

import json
import os
from pathlib import Path

from .errors import InputFileError


class _BeyondInt64(ValueError):
    pass


def _int64(text: str) -> int:
    """A JSON integer, refused beyond 64 bits: no value a box, frame or timestamp (nanoseconds) holds needs more,
    and numpy cannot hold it (``float()`` and ``np.isfinite`` failed deep in the readers)."""
    value = int(text)
    if not -(2**63) <= value < 2**63:
        raise _BeyondInt64(f"an integer beyond 64 bits ({text[:20]}{'...' if len(text) > 20 else ''})")
    return value


def read_json(path: str | os.PathLike, what: str = "JSON file"):
    """Parse the JSON file ``path``; any fault of its text is an :class:`InputFileError` naming it.

    Besides a syntax error: text that is not UTF-8, nesting too deep for the parser
    (``RecursionError``), integers too long to convert (``ValueError``, Python's
    4,300-digit limit) and integers beyond 64 bits. A missing file is an :class:`InputFileError` too (``what`` names it).
    """
    p = Path(path)
    if not p.is_file():
        raise InputFileError(p, f"{what} not found" if not p.exists() else f"is not a file, expected a {what}")
    try:
        with open(p, encoding="utf-8") as fh:
            return json.load(fh, parse_int=_int64)
    except RecursionError:
        raise InputFileError(p, "not valid JSON (nested too deeply)") from None
    except _BeyondInt64 as exc:
        raise InputFileError(p, f"holds {exc}") from None
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError, an integer of thousands of digits
        first = (str(exc).splitlines() or [type(exc).__name__])[0][:160]
        if "integer string conversion" in first:
            first = "a number of thousands of digits"
        raise InputFileError(p, f"not valid JSON ({first})") from None


def path_inside(
    root: str | os.PathLike, name: str | os.PathLike, source: str | os.PathLike, what: str = "file"
) -> Path:
    """The file a dataset names, ``root / name``, refused unless it lies inside ``root``.

    ``name`` comes from inside a dataset (a table row, an index, a manifest) written by someone
    else: an absolute path, a ``..`` that climbs out, or a symbolic link that leads out of
    ``root`` (links are resolved) would make the tool read any file of the machine. Raises
    :class:`InputFileError` naming ``source`` (the file that holds ``name``). The returned path
    is ``root / name`` as written (not resolved), so messages show the dataset's own names.
    """
    text = os.fspath(name) if isinstance(name, (str, os.PathLike)) else None
    if not isinstance(text, str) or not text or "\x00" in text:
        raise InputFileError(source, f"{what} {name!r} is not a relative path inside {root}")
    if os.path.isabs(text) or Path(text).anchor or text.startswith(("/", "\\")):
        raise InputFileError(source, f"{what} {text!r} is an absolute path; it must lie inside {root}")
    base = Path(root)
    candidate = base / text
    real_root = os.path.realpath(base)
    real = os.path.realpath(candidate)
    if os.path.commonpath([real_root, real]) != real_root:
        plain = os.path.normpath(os.path.join(os.path.abspath(base), text))
        how = (
            " through a symbolic link"
            if os.path.commonpath([os.path.abspath(base), plain]) == os.path.abspath(base)
            else ""
        )
        raise InputFileError(source, f"{what} {text!r} leads outside {root}{how}")
    return candidate


#: An ``.npz`` member may unpack to at most this many times its compressed size once beyond
#: :data:`NPZ_FREE_BYTES`: numpy's zlib compresses real coordinates, depths and masks 1-10x, while a zip bomb
#: (2 MB of zeros declared as a 2 GB array) unpacks ~1000x. Smaller members are never judged.
NPZ_MAX_RATIO = 100

#: Members of at most this many unpacked bytes are read whatever their ratio (64 MiB).
NPZ_FREE_BYTES = 64 << 20


def check_npz_members(path: str | os.PathLike, what: str = ".npz file") -> None:
    """Refuse an ``.npz`` file (a zip archive) before numpy unpacks it, from its zip directory alone: a file that is
    not a zip archive, or a member that would unpack beyond :data:`NPZ_FREE_BYTES` and :data:`NPZ_MAX_RATIO` times
    its compressed size (a zip bomb). The directory's sizes are binding: Python's zip reader stops at the declared
    size (a member that holds more fails its check). :class:`InputFileError` naming ``path``, one line."""
    import zipfile

    p = Path(path)
    try:
        with zipfile.ZipFile(p) as zf:
            members = zf.infolist()
    except FileNotFoundError:
        raise InputFileError(p, f"{what} not found") from None
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise InputFileError(p, f"not a readable {what} ({type(exc).__name__})") from None
    for m in members:
        if m.file_size > NPZ_FREE_BYTES and m.file_size > NPZ_MAX_RATIO * max(m.compress_size, 1):
            raise InputFileError(
                p,
                f"member {m.filename[:60]!r} would unpack {m.compress_size:,} bytes into {m.file_size:,} "
                f"(more than {NPZ_MAX_RATIO}x beyond {NPZ_FREE_BYTES >> 20} MiB): refused as a zip bomb",
            )
