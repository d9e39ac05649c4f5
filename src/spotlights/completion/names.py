"""Output file names: how a frame id, a sequence or a track id becomes a file or folder name (one owner).

``real complete`` writes ``OUT/[SEQUENCE/]FRAME.{ply,png,html,json}``, ``OUT/summary.json`` and, with ``--fuse``,
``OUT/[SEQUENCE/]tracks/TRACK.ply`` and ``OUT/tracks.json``: names come from the data (any text), so distinct
texts must never share a file, none may be a file of the run, and the frames' and the tracks' sequence folders
must be the same folders.
"""

from __future__ import annotations

import hashlib
import re
from collections import Counter

from ..errors import SpotlightsError

#: Files and folders of the run itself in the output folder (``tracks``: the folder of tracks without a sequence).
RUN_FILES = ("summary.json", "plotly.min.js", "tracks.json", "tracks")
#: What each frame adds to its stem.
FRAME_SUFFIXES = (".ply", ".png", ".html", ".json", "_objects")
#: Frame names that a frame beside the run files (no sequence) may not take: ``summary`` -> ``summary.json``,
#: ``tracks`` -> ``tracks.json``.
RESERVED_FRAMES = ("summary", "tracks")


def safe_name(text: str, empty: str = "frame") -> str:
    """``text`` as a file name: runs of characters other than letters, digits, ``.``, ``_`` and ``-`` become ``_``
    (``empty`` when nothing is left)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", str(text)).strip("._") or empty


def _digest(text) -> str:
    return hashlib.sha256(str(text).encode("utf-8", "surrogatepass")).hexdigest()[:8]


def file_stem(text, empty: str = "frame") -> str:
    """``text`` (a frame id, a sequence name, a track id) as a file name that no other text maps to:
    :func:`safe_name`, plus ``-`` and 8 hex digits of the SHA-256 of ``text`` when sanitising changed it (``../a`` ->
    ``a-3b1d...``, ``汽车`` -> ``frame-...``, a name of over 100 characters cut there); a safe name is kept as it is
    (``000123``, ``scene-0523``)."""
    name = safe_name(text, empty)[:100]
    return name if name == str(text) else f"{name}-{_digest(text)}"


def unique_names(texts, reserved=(), empty: str = "frame") -> dict[str, str]:
    """{text: file name}: :func:`file_stem` of each, with the digest added as well to names that would coincide with
    another or with ``reserved`` when letter case is ignored (macOS, Windows)."""
    names = {t: file_stem(t, empty) for t in texts}
    count = Counter(n.casefold() for n in names.values())
    taken = {r.casefold() for r in reserved}
    out = {
        t: f"{safe_name(t, empty)[:100]}-{_digest(t)}" if count[n.casefold()] > 1 or n.casefold() in taken else n
        for t, n in names.items()
    }
    if len({n.casefold() for n in out.values()} | taken) != len(out) + len(taken):
        raise SpotlightsError("frame, sequence or track names map to one output file; rename them")  # a SHA-256 clash
    return out


def sequence_folders(keys) -> dict[str, str]:
    """{sequence: folder name} of the sequences of frame keys ``(sequence, frame_id)`` (a run's selection): the
    folders of both the frames and the tracks."""
    return unique_names(sorted({str(s) for s, _ in keys if s}), reserved=RUN_FILES)
