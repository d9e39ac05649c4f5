"""The index of a sharded dataset (JSON, ``format = "spotlights-completion-shards"``).

A sharded dataset is several ``spotlights-completion`` HDF5 files (whole models each) and
this index listing them in order: ``{"format", "format_version", "spotlights_version",
"dataset_format", "dataset_format_version", "n_models", "n_samples", "views_per_model",
"seed", "shards": [{"file", "n_models", "n_samples", "bytes"}]}``; shard paths are relative
to the index's folder. :func:`spotlights.data.store.open_dataset` reads the index like a
file; :func:`write_index` writes one (the last step of a sharded build).
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from .._version import __version__
from ..errors import InputFileError
from ..inputs import path_inside, read_json
from ..outputs import atomic_output

INDEX_FORMAT = "spotlights-completion-shards"
INDEX_FORMAT_VERSION = 1


def read_shard_index(path: Path) -> list[dict]:
    """The shards of a sharded dataset's index (JSON, ``format = "spotlights-completion-shards"``).

    Returns ``[{"path": Path, "n_models": int, "n_samples": int}, ...]`` in dataset order (shard
    paths resolved against the index's folder). Raises InputFileError naming the index."""
    idx = read_json(path, "shard index")
    if not isinstance(idx, dict) or idx.get("format") != INDEX_FORMAT:
        raise InputFileError(
            path, f"not a spotlights shard index (format {idx.get('format') if isinstance(idx, dict) else None!r})"
        )
    if str(idx.get("format_version")) != str(INDEX_FORMAT_VERSION):
        raise InputFileError(
            path, f"shard index version {idx.get('format_version')}, this spotlights reads {INDEX_FORMAT_VERSION}"
        )
    try:
        shards = [
            {
                "path": path_inside(path.parent, s["file"], path, "shard file"),
                "n_models": int(s["n_models"]),
                "n_samples": int(s["n_samples"]),
            }
            for s in idx["shards"]
        ]
    except (KeyError, TypeError, ValueError):
        raise InputFileError(path, "shard index without a valid 'shards' list") from None
    if not shards:
        raise InputFileError(path, "shard index lists no shards")
    return shards


def without_extra_rigs(config_json) -> dict | None:
    """A config_json string as a dict without ``extra_rigs`` (None if unreadable): shards of one
    dataset agree on this even while an add-rig is half done."""
    try:
        d = json.loads(config_json)
    except (TypeError, ValueError):
        return None
    d.pop("extra_rigs", None)
    return d


def is_shard_index(path: str | os.PathLike) -> bool:
    """True when ``path`` is a shard index (JSON) rather than an HDF5 file (looks at the first bytes)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(64).lstrip()
    except OSError:
        return False
    return head.startswith(b"{")


def write_index(
    index: Path,
    shards: list[Path],
    counts: list[tuple[int, int]],
    views_per_model: int,
    seed: int,
    dataset_format: str,
    dataset_format_version: int,
) -> None:
    """Write the index of a sharded dataset (atomically), then delete stale shards of an earlier
    build with the same name that the new index does not list.

    shards : the shard files (beside ``index``), in order; counts : ``(n_models, n_samples)`` of each.
    """
    doc = {
        "format": INDEX_FORMAT,
        "format_version": INDEX_FORMAT_VERSION,
        "spotlights_version": __version__,
        "dataset_format": dataset_format,
        "dataset_format_version": int(dataset_format_version),
        "n_models": int(sum(c[0] for c in counts)),
        "n_samples": int(sum(c[1] for c in counts)),
        "views_per_model": int(views_per_model),
        "seed": int(seed),
        "shards": [
            {"file": p.name, "n_models": int(c[0]), "n_samples": int(c[1]), "bytes": p.stat().st_size}
            for p, c in zip(shards, counts)
        ],
    }
    with atomic_output(index, suffix=".json") as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n")
    keep = {p.name for p in shards}
    pattern = re.compile(re.escape(index.stem) + r"-\d{5}-of-\d{5}\.h5")
    for p in index.parent.glob(f"{index.stem}-*-of-*.h5"):
        if pattern.fullmatch(p.name) and p.name not in keep:
            p.unlink(missing_ok=True)


def shard_paths(index: Path, n: int) -> list[Path]:
    """The shard files of an index ``DIR/NAME.json``: ``DIR/NAME-00000-of-0000N.h5``, ..."""
    return [index.with_name(f"{index.stem}-{k:05d}-of-{n:05d}.h5") for k in range(n)]
