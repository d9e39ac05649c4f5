"""The mesh catalogue of a build: discovery (folder or manifest), loading, splits.

A build's models are the mesh files of its source folder(s), each a :class:`ModelEntry`
(name, file, category, axes, optional fixed split, file hash); :func:`load_model` turns
one into a :class:`LoadedModel` (object-frame vertices and faces in metres), and
:func:`assign_splits` deals the train/val/test labels (seeded, stratified by category).
"""

from __future__ import annotations

import csv
import hashlib
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...errors import InputFileError, ParameterError
from ...geometry.io import MESH_SUFFIXES, load_mesh
from ..store import SPLITS
from .config import STREAM_SPLIT, parse_split

# ----------------------------------------------------------------------------------------------
# models: discovery, loading, split
# ----------------------------------------------------------------------------------------------
@dataclass
class ModelEntry:
    """One mesh of the dataset: ``name`` (relative path without suffix), ``file`` (relative path),
    ``category``, its axes, an optional split from the manifest, and its file's SHA-256."""

    name: str
    file: str
    category: str
    up: str
    forward: str
    split: str | None = None
    sha256: str = ""


def model_key(name: str) -> int:
    """A stable 63-bit integer for a model name (seeds its random streams)."""
    return int.from_bytes(hashlib.sha256(name.encode("utf-8")).digest()[:8], "little") >> 1


def discover_models(folder: str | os.PathLike, manifest: str | os.PathLike | None = None, up: str = "z",
                    forward: str = "x") -> tuple[list[ModelEntry], list[dict]]:
    """Find the meshes of a dataset and their categories.

    With a manifest (``manifest`` or ``FOLDER/manifest.csv``): its rows, columns ``file``
    (relative to the folder) and ``category`` (optional ``up``, ``forward``, ``split``).
    Without: every mesh file under ``folder`` (sorted); the category is the first sub-folder
    (files directly in ``folder`` take the folder's name).

    Returns ``(entries sorted by name, problems)`` where problems are ``{"file", "problem"}``
    for manifest rows whose file is missing.
    """
    root = Path(folder)
    if not root.exists():
        raise InputFileError(root, "no such folder")
    if not root.is_dir():
        raise InputFileError(root, "is not a folder of meshes")
    man = Path(manifest) if manifest else (root / "manifest.csv" if (root / "manifest.csv").exists() else None)
    entries: list[ModelEntry] = []
    problems: list[dict] = []
    if man is not None:
        if not man.exists():
            raise InputFileError(man, "no such manifest")
        try:
            with open(man, newline="") as fh:
                rows = list(csv.DictReader(fh))
        except (OSError, UnicodeDecodeError, csv.Error) as exc:
            raise InputFileError(man, f"cannot read the manifest CSV ({exc})") from None
        if not rows or "file" not in rows[0]:
            raise InputFileError(man, "manifest needs a header with a 'file' column (and 'category')")
        for row in rows:
            rel = (row.get("file") or "").strip()
            if not rel:
                continue
            p = root / rel
            cat = (row.get("category") or "").strip() or (Path(rel).parts[0] if len(Path(rel).parts) > 1 else root.name)
            split = (row.get("split") or "").strip().lower() or None
            if split is not None and split not in SPLITS:
                raise InputFileError(man, f"row {rel}: split {split!r} is not one of {', '.join(SPLITS)}")
            if not p.is_file():
                problems.append({"file": rel, "problem": "listed in the manifest but missing"})
                continue
            entries.append(ModelEntry(name=str(Path(rel).with_suffix("").as_posix()), file=Path(rel).as_posix(),
                                      category=cat, up=(row.get("up") or "").strip() or up,
                                      forward=(row.get("forward") or "").strip() or forward, split=split))
    else:
        files = sorted(p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in MESH_SUFFIXES
                       and not any(part.startswith(".") for part in p.relative_to(root).parts))
        for p in files:
            rel = p.relative_to(root)
            cat = rel.parts[0] if len(rel.parts) > 1 else root.name
            entries.append(ModelEntry(name=rel.with_suffix("").as_posix(), file=rel.as_posix(), category=cat,
                                      up=up, forward=forward))
    if not entries and not problems:
        raise InputFileError(root, f"no mesh files ({' '.join(MESH_SUFFIXES)}) found" +
                             (f" from manifest {man}" if man else ""))
    names = [e.name for e in entries]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputFileError(root, f"several mesh files share the name {dup[0]!r} (differing only by suffix)")
    entries.sort(key=lambda e: e.name)
    return entries, problems


@dataclass
class LoadedModel:
    """A mesh ready for simulation: object-frame (x forward, y left, z up, metres) float64
    ``vertices`` (V, 3) without unreferenced vertices, int64 ``faces`` (F, 3)."""

    entry: ModelEntry
    vertices: np.ndarray
    faces: np.ndarray


def load_model(root: Path, entry: ModelEntry, scale: float = 1.0) -> LoadedModel:
    """Load one mesh (validated by :func:`~spotlights.geometry.io.load_mesh`), drop unreferenced
    vertices (they would enlarge the box), scale it and hash its file. Raises InputFileError."""
    path = root / entry.file
    mesh = load_mesh(path, up=entry.up, forward=entry.forward)
    used = np.unique(mesh.faces)
    remap = np.full(len(mesh.vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    v = np.asarray(mesh.vertices, dtype=np.float64)[used] * float(scale)
    f = remap[np.asarray(mesh.faces, dtype=np.int64)]
    entry.sha256 = hashlib.sha256(path.read_bytes()).hexdigest()
    return LoadedModel(entry=entry, vertices=v, faces=f)


def assign_splits(categories: list[str], spec: str, seed: int, stratify: bool = True,
                  fixed: list[str | None] | None = None) -> list[str]:
    """Assign every model to train/val/test.

    Parameters
    ----------
    categories : category of each model (in model order).
    spec : ``"64/8/7"`` counts (must add up to the number of models) or fractions
        (counts by the largest-remainder rule).
    seed : root seed; the assignment is a seeded permutation.
    stratify : when True, models are shuffled within each category and the categories laid
        end to end; splits are dealt along that list by an evenly spread label sequence, so every
        split gets each category in proportion (up to rounding) with the exact total counts.
    fixed : optional split per model from a manifest; when every model has one it is used as is.

    Returns
    -------
    list of split names, one per model.
    """
    n = len(categories)
    if fixed is not None and all(s is not None for s in fixed):
        return list(fixed)
    if fixed is not None and any(s is not None for s in fixed):
        raise ParameterError("the manifest gives a split for some models but not all")
    kind, vals = parse_split(spec)
    if kind == "counts":
        counts = [int(v) for v in vals]
        if sum(counts) != n:
            raise ParameterError(f"split {spec} adds up to {sum(counts)} models but there are {n} usable meshes")
    else:
        raw = [v * n for v in vals]
        counts = [int(math.floor(r)) for r in raw]
        order = sorted(range(3), key=lambda i: (-(raw[i] - counts[i]), i))
        for i in order[: n - sum(counts)]:
            counts[i] += 1
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(0, STREAM_SPLIT)))
    if stratify:
        cats = sorted(set(categories))
        order = []
        for c in cats:
            members = [i for i in range(n) if categories[i] == c]
            order.extend(members[j] for j in rng.permutation(len(members)))
    else:
        order = [int(i) for i in rng.permutation(n)]
    # Evenly spread label sequence with exact counts (largest deficit first, ties by split order).
    labels = []
    assigned = [0, 0, 0]
    for j in range(n):
        deficit = [counts[s] * (j + 1) / max(n, 1) - assigned[s] for s in range(3)]
        s = max((s for s in range(3) if assigned[s] < counts[s]), key=lambda s: (deficit[s], -s))
        assigned[s] += 1
        labels.append(SPLITS[s])
    out = [""] * n
    for pos, i in enumerate(order):
        out[i] = labels[pos]
    return out

