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
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ...errors import InputFileError, ParameterError
from ...geometry.io import MESH_SUFFIXES, load_mesh
from ...inputs import path_inside
from ..store import SPLITS
from .config import PROCEDURAL_SOURCE, STREAM_AUGMENT, STREAM_PROCEDURAL, STREAM_SPLIT, MeshSource, parse_split
from .procedural import CLASS_BODIES, class_of_category, generate_vehicle, mesh_digest


# ----------------------------------------------------------------------------------------------
# models: discovery, loading, split
# ----------------------------------------------------------------------------------------------
@dataclass
class ModelEntry:
    """One model of the dataset: ``name`` (relative path without suffix, prefixed by the source's
    name in multi-source builds), ``file`` (relative to its source folder), ``category``, its
    axes, an optional split from the manifest, and its file's SHA-256.

    scale : per-file factor to metres from a manifest's ``scale`` column (None: the source's).
    source : the source's name ("" in a single-source build). origin : for an augmented copy,
    the name of the model it was made from ("" for a mesh file itself). augment : the copy's
    transform, ``{"scale": [sx, sy, sz], "mirror": bool}`` (None for a mesh file itself).
    vclass : the detector class (``car``, ``van``, ``truck``, ``bus``, ``trailer``, ``other``;
    "" when the build does not store classes). generator : a procedural vehicle's ``{"body",
    "seed"}`` (:mod:`.procedural`; None for a mesh file): its mesh is generated, not read.
    """

    name: str
    file: str
    category: str
    up: str
    forward: str
    split: str | None = None
    sha256: str = ""
    scale: float | None = None
    source: str = ""
    origin: str = ""
    augment: dict | None = None
    vclass: str = ""
    generator: dict | None = None

    def plan_dict(self) -> dict:
        """The entry as recorded in ``plan.json`` (the fields added for multi-source builds and
        augmentation only when set, so plans of older builds still match)."""
        d = asdict(self)
        for k in ("scale", "source", "origin", "augment", "vclass", "generator"):
            if not d[k]:
                del d[k]
        return d


def model_key(name: str) -> int:
    """A stable 63-bit integer for a model name (seeds its random streams)."""
    return int.from_bytes(hashlib.sha256(name.encode("utf-8")).digest()[:8], "little") >> 1


def discover_models(
    folder: str | os.PathLike, manifest: str | os.PathLike | None = None, up: str = "z", forward: str = "x"
) -> tuple[list[ModelEntry], list[dict]]:
    """Find the meshes of a dataset and their categories.

    With a manifest (``manifest`` or ``FOLDER/manifest.csv``): its rows, columns ``file``
    (relative to the folder) and ``category`` (optional ``up``, ``forward``, ``split``, ``scale``).
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
    if man is not None:
        entries, problems = _manifest_entries(root, man, up, forward)
    else:
        entries, problems = _folder_entries(root, up, forward), []
    if not entries and not problems:
        raise InputFileError(
            root, f"no mesh files ({' '.join(MESH_SUFFIXES)}) found" + (f" from manifest {man}" if man else "")
        )
    names = [e.name for e in entries]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputFileError(root, f"several mesh files share the name {dup[0]!r} (differing only by suffix)")
    entries.sort(key=lambda e: e.name)
    return entries, problems


def _manifest_entries(root: Path, man: Path, up: str, forward: str) -> tuple[list[ModelEntry], list[dict]]:
    """The entries of a manifest's rows (in row order) and the ``{"file", "problem"}`` of rows
    whose file is missing; raises InputFileError for an unreadable manifest or a bad row."""
    if not man.exists():
        raise InputFileError(man, "no such manifest")
    try:
        with open(man, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputFileError(man, f"cannot read the manifest CSV ({exc})") from None
    if not rows or "file" not in rows[0]:
        raise InputFileError(man, "manifest needs a header with a 'file' column (and 'category')")
    entries: list[ModelEntry] = []
    problems: list[dict] = []
    for row in rows:
        rel = (row.get("file") or "").strip()
        if not rel:
            continue
        p = path_inside(root, rel, man, "mesh file")
        cat = (row.get("category") or "").strip() or (Path(rel).parts[0] if len(Path(rel).parts) > 1 else root.name)
        split = _row_split(man, rel, row)
        scale = _row_scale(man, rel, row)
        if not p.is_file():
            problems.append({"file": rel, "problem": "listed in the manifest but missing"})
            continue
        entries.append(
            ModelEntry(
                name=str(Path(rel).with_suffix("").as_posix()),
                file=Path(rel).as_posix(),
                category=cat,
                up=(row.get("up") or "").strip() or up,
                forward=(row.get("forward") or "").strip() or forward,
                split=split,
                scale=scale,
            )
        )
    return entries, problems


def _row_split(man: Path, rel: str, row: dict) -> str | None:
    """A manifest row's ``split`` (lower case; None when empty); raises InputFileError."""
    split = (row.get("split") or "").strip().lower() or None
    if split is not None and split not in SPLITS:
        raise InputFileError(man, f"row {rel}: split {split!r} is not one of {', '.join(SPLITS)}")
    return split


def _row_scale(man: Path, rel: str, row: dict) -> float | None:
    """A manifest row's ``scale`` (a finite number > 0; None when empty); raises InputFileError."""
    scale = (row.get("scale") or "").strip() or None
    if scale is not None:
        try:
            scale = float(scale)
        except ValueError:
            scale = -1.0
        if not (math.isfinite(scale) and scale > 0):
            raise InputFileError(man, f"row {rel}: scale {row.get('scale')!r} is not a number > 0")
    return scale


def _folder_entries(root: Path, up: str, forward: str) -> list[ModelEntry]:
    """Every mesh file under ``root`` (sorted, hidden files and folders left out); the category is
    the first sub-folder (``root``'s name for files directly in it)."""
    files = sorted(
        p
        for p in root.rglob("*")
        if p.is_file()
        and p.suffix.lower() in MESH_SUFFIXES
        and not any(part.startswith(".") for part in p.relative_to(root).parts)
    )
    entries = []
    for p in files:
        rel = p.relative_to(root)
        cat = rel.parts[0] if len(rel.parts) > 1 else root.name
        entries.append(
            ModelEntry(name=rel.with_suffix("").as_posix(), file=rel.as_posix(), category=cat, up=up, forward=forward)
        )
    return entries


@dataclass
class LoadedModel:
    """A mesh ready for simulation: object-frame (x forward, y left, z up, metres) float64
    ``vertices`` (V, 3) without unreferenced vertices, int64 ``faces`` (F, 3)."""

    entry: ModelEntry
    vertices: np.ndarray
    faces: np.ndarray

    @property
    def size(self) -> np.ndarray:
        """(3,) float64 box size (length, width, height), metres."""
        return self.vertices.max(axis=0) - self.vertices.min(axis=0)

    def derive(self, entry: ModelEntry) -> LoadedModel:
        """The model of ``entry``, an augmented copy of this mesh (:func:`apply_augment`)."""
        return apply_augment(self, entry)


def load_model(root: Path, entry: ModelEntry, scale: float = 1.0) -> LoadedModel:
    """Load one mesh (validated by :func:`~spotlights.geometry.io.load_mesh`), drop unreferenced
    vertices (they would enlarge the box), scale it (``entry.scale`` when the manifest gives one,
    else ``scale``) and hash its file. Raises InputFileError.

    A procedural entry (``entry.generator``) is generated instead (``root`` and ``scale`` unused):
    :func:`~.procedural.generate_vehicle` seeded by ``(generator["seed"], model_key(name),
    STREAM_PROCEDURAL)``; its ``sha256`` is the mesh's bytes' (:func:`~.procedural.mesh_digest`)."""
    if entry.generator:
        seed = np.random.SeedSequence(
            int(entry.generator["seed"]), spawn_key=(model_key(entry.name), STREAM_PROCEDURAL)
        )
        v, f, _ = generate_vehicle(entry.generator["body"], seed)
        entry.sha256 = mesh_digest(v, f)
        return LoadedModel(entry=entry, vertices=v, faces=f)
    path = root / entry.file
    mesh = load_mesh(path, up=entry.up, forward=entry.forward)
    used = np.unique(mesh.faces)
    remap = np.full(len(mesh.vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    v = np.asarray(mesh.vertices, dtype=np.float64)[used] * float(entry.scale if entry.scale is not None else scale)
    f = remap[np.asarray(mesh.faces, dtype=np.int64)]
    entry.sha256 = hashlib.sha256(path.read_bytes()).hexdigest()
    return LoadedModel(entry=entry, vertices=v, faces=f)


def assign_splits(
    categories: list[str], spec: str, seed: int, stratify: bool = True, fixed: list[str | None] | None = None
) -> list[str]:
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
    counts = _split_counts(spec, n)
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(0, STREAM_SPLIT)))
    if stratify:
        cats = sorted(set(categories))
        order = []
        for c in cats:
            members = [i for i in range(n) if categories[i] == c]
            order.extend(members[j] for j in rng.permutation(len(members)))
    else:
        order = [int(i) for i in rng.permutation(n)]
    labels = _spread_labels(counts, n)
    out = [""] * n
    for pos, i in enumerate(order):
        out[i] = labels[pos]
    return out


def _split_counts(spec: str, n: int) -> list[int]:
    """The (train, val, test) model counts of a split ``spec`` for ``n`` models: counts as given
    (they must add up to ``n``; else ParameterError), fractions by the largest-remainder rule."""
    kind, vals = parse_split(spec)
    if kind == "counts":
        counts = [int(v) for v in vals]
        if sum(counts) != n:
            raise ParameterError(f"split {spec} adds up to {sum(counts)} models but there are {n} usable meshes")
        return counts
    raw = [v * n for v in vals]
    counts = [int(math.floor(r)) for r in raw]
    order = sorted(range(3), key=lambda i: (-(raw[i] - counts[i]), i))
    for i in order[: n - sum(counts)]:
        counts[i] += 1
    return counts


def _spread_labels(counts: list[int], n: int) -> list[str]:
    """``n`` split names, ``counts[s]`` of split ``s``, evenly spread along the sequence."""
    # Evenly spread label sequence with exact counts (largest deficit first, ties by split order).
    labels = []
    assigned = [0, 0, 0]
    for j in range(n):
        deficit = [counts[s] * (j + 1) / max(n, 1) - assigned[s] for s in range(3)]
        s = max((s for s in range(3) if assigned[s] < counts[s]), key=lambda s: (deficit[s], -s))
        assigned[s] += 1
        labels.append(SPLITS[s])
    return labels


# ----------------------------------------------------------------------------------------------
# augmented copies (extra models)
# ----------------------------------------------------------------------------------------------
def augment_mesh(
    vertices: np.ndarray, faces: np.ndarray, scale=(1.0, 1.0, 1.0), mirror: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """An augmented copy of a mesh in its object frame (x forward, y left, z up, metres).

    vertices : (V, 3) float64; faces : (F, 3) int64.
    scale : per-axis factors (sx, sy, sz) about the box centre (anisotropic scaling).
    mirror : reflect across the car's x-z plane through the box centre (y -> 2 c_y - y); the
        face winding is reversed so that normals keep pointing outwards.

    Returns ``(vertices (V, 3) float64, faces (F, 3) int64)``; the box centre stays where it was.
    """
    v = np.asarray(vertices, dtype=np.float64)
    c = (v.min(axis=0) + v.max(axis=0)) / 2.0
    out = c + (v - c) * np.asarray(scale, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if mirror:
        out[:, 1] = 2.0 * c[1] - out[:, 1]
        f = np.ascontiguousarray(f[:, ::-1])
    return out, f


def draw_scale_factors(size: np.ndarray, aug: dict, rng: np.random.Generator, tries: int = 200) -> np.ndarray:
    """Per-axis factors (3,) float64 for an anisotropically scaled copy of a box of ``size`` (l, w, h).

    Each factor is log-uniform in ``aug["factor"]`` intersected with what keeps that axis inside
    its realistic range (``aug["length"]``, ``["width"]``, ``["height"]``, metres); an axis the
    factor range cannot bring into its range gets the factor bound closest to it. Draws whose
    length/width or length/height ratio falls outside ``aug["length_width"]`` /
    ``aug["length_height"]`` are redrawn (at most ``tries`` times; then the draw with the
    smallest ratio violation is used). Deterministic given ``rng``.
    """
    size = np.asarray(size, dtype=np.float64)
    fmin, fmax = aug["factor"]
    lo = np.empty(3)
    hi = np.empty(3)
    for i, key in enumerate(("length", "width", "height")):
        a, b = max(fmin, aug[key][0] / size[i]), min(fmax, aug[key][1] / size[i])
        if a > b:  # out of reach: the bound nearest to the range
            a = b = fmax if size[i] * fmax < aug[key][0] else fmin
        lo[i], hi[i] = a, b
    best, best_bad = None, math.inf
    for _ in range(tries):
        f = np.exp(rng.uniform(np.log(lo), np.log(hi)))
        d = size * f
        lw, lh = d[0] / d[1], d[0] / d[2]
        bad = max(0.0, aug["length_width"][0] - lw, lw - aug["length_width"][1]) + max(
            0.0, aug["length_height"][0] - lh, lh - aug["length_height"][1]
        )
        if bad == 0.0:
            return f
        if bad < best_bad:
            best, best_bad = f, bad
    return best


def augment_entries(entry: ModelEntry, size: np.ndarray, aug: dict, seed: int) -> list[ModelEntry]:
    """The entries of the augmented copies of one mesh (not the mesh itself), in a fixed order.

    entry : the mesh's entry; size : (3,) its box (l, w, h) in metres; aug : the normalised
    augmentation (:func:`~spotlights.data.synthetic.config.normalize_augment`); seed : root seed.

    With ``copies = K`` and ``mirror``: ``NAME~mirror``, then for k = 1..K ``NAME~sK`` (scale
    factors from :func:`draw_scale_factors` with the stream ``(model_key(NAME), STREAM_AUGMENT,
    k)``) and ``NAME~sK-mirror`` (the same factors, mirrored). Copies keep the file, hash,
    category and split of their origin; ``entry.origin`` names it and ``entry.augment`` holds
    the transform (factors as floats: JSON keeps them exactly).
    """
    variants = []
    if aug["mirror"]:
        variants.append(("mirror", [1.0, 1.0, 1.0], True))
    for k in range(1, aug["copies"] + 1):
        rng = np.random.default_rng(
            np.random.SeedSequence(int(seed), spawn_key=(model_key(entry.name), STREAM_AUGMENT, k))
        )
        f = [float(x) for x in draw_scale_factors(size, aug, rng)]
        variants.append((f"s{k}", f, False))
        if aug["mirror"]:
            variants.append((f"s{k}-mirror", f, True))
    return [
        replace(entry, name=f"{entry.name}~{tag}", origin=entry.name, augment={"scale": f, "mirror": mirror})
        for tag, f, mirror in variants
    ]


def augmented_copies(model: LoadedModel, aug: dict, seed: int) -> list[LoadedModel]:
    """The augmented copies of one loaded mesh (:func:`augment_entries`, meshes by :func:`apply_augment`)."""
    return [apply_augment(model, e) for e in augment_entries(model.entry, model.size, aug, seed)]


def apply_augment(origin: LoadedModel, entry: ModelEntry) -> LoadedModel:
    """The copy ``entry`` (its ``augment`` transform) of the loaded mesh ``origin``."""
    v, f = augment_mesh(origin.vertices, origin.faces, entry.augment["scale"], entry.augment["mirror"])
    return LoadedModel(entry=entry, vertices=v, faces=f)


# ----------------------------------------------------------------------------------------------
# the catalogue of a build: every source, splits, augmented copies
# ----------------------------------------------------------------------------------------------
def discover_sources(cfg) -> tuple[list[ModelEntry], list[dict]]:
    """The entries of every mesh source of ``cfg`` (a :class:`BuildConfig`), names prefixed by the
    source's name when there are several; categories in ``cfg.exclude_categories`` left out.

    Returns ``(entries, problems)``; entries in source order, each source's sorted by name;
    problems ``{"file", "problem"}`` (``file`` prefixed like the names)."""
    entries, problems = [], []
    procedural = getattr(cfg, "procedural", None)
    for src in cfg.mesh_sources():
        found, probs = discover_models(src.path, src.manifest, src.up, src.forward)
        prefix = f"{src.name}/" if src.name else ""
        for e in found:
            if e.category in cfg.exclude_categories:
                continue
            e.name, e.source = prefix + e.name, src.name
            if procedural:
                e.vclass = class_of_category(e.category)
            entries.append(e)
        problems.extend({"file": prefix + p["file"], "problem": p["problem"]} for p in probs)
    if procedural:
        entries.extend(e for e in procedural_entries(procedural, cfg.seed) if e.category not in cfg.exclude_categories)
    names = [e.name for e in entries]
    if len(set(names)) != len(names):
        raise ParameterError(f"two models are named {sorted(n for n in names if names.count(n) > 1)[0]!r}")
    return entries, problems


def procedural_entries(procedural: dict, seed: int) -> list[ModelEntry]:
    """The entries of a build's procedural vehicles (``BuildConfig.procedural``): for each class,
    ``count`` vehicles ``procedural/CLASS/BODY-IIII`` whose body types take turns through
    :data:`~.procedural.CLASS_BODIES` (vehicle ``i`` of a class is the same whatever ``count``);
    category = body type, ``vclass`` = the class, ``generator = {"body", "seed"}``."""
    out = []
    for cls in procedural["classes"]:
        bodies = CLASS_BODIES[cls]
        for i in range(procedural["count"]):
            body = bodies[i % len(bodies)]
            name = f"{PROCEDURAL_SOURCE}/{cls}/{body}-{i:04d}"
            out.append(
                ModelEntry(
                    name=name,
                    file=f"{cls}/{body}-{i:04d}",
                    category=body,
                    up="z",
                    forward="x",
                    source=PROCEDURAL_SOURCE,
                    vclass=cls,
                    generator={"body": body, "seed": int(seed)},
                )
            )
    return out


def source_root(cfg, entry: ModelEntry) -> Path:
    """The folder ``entry.file`` is relative to (for a procedural vehicle, a name only: nothing is read)."""
    if entry.generator:
        return Path(PROCEDURAL_SOURCE)
    for src in cfg.mesh_sources():
        if src.name == entry.source:
            return Path(src.path)
    raise ParameterError(f"model {entry.name}: no mesh source named {entry.source!r}")


def source_scale(cfg, entry: ModelEntry) -> float:
    """The scale of ``entry``'s source (a manifest's per-file ``scale`` overrides it in load_model)."""
    if entry.generator:
        return 1.0
    return next(s.scale for s in cfg.mesh_sources() if s.name == entry.source)


def assign_model_splits(entries: list[ModelEntry], cfg) -> list[str]:
    """The split of every (loaded) model of a build, in order. See :func:`assign_splits` for the
    seeded, stratified dealing.

    Precedence: a source whose manifest gives every file a split uses those (some but not all:
    an error); then ``cfg.category_split`` (held-out categories); then a source's own ``split``
    (a split name: all its models; a spec: dealt over its remaining models alone); the rest
    are pooled and dealt by ``cfg.split``. With one source and none of these options this is
    exactly ``assign_splits(categories, cfg.split, cfg.seed, cfg.stratify, manifest splits)``.
    """
    out: list[str | None] = [None] * len(entries)
    pool = []
    proc = getattr(cfg, "procedural", None)
    pseudo = [MeshSource("", split=proc["split"], name=PROCEDURAL_SOURCE)] if proc else []
    for src in cfg.mesh_sources() + pseudo:
        pool.extend(_assign_source_splits(entries, src, cfg, out))
    if pool:
        _deal(entries, pool, cfg.split, cfg, out, "")
    return [str(s) for s in out]


def _assign_source_splits(entries: list[ModelEntry], src: MeshSource, cfg, out: list) -> list[int]:
    """Fill ``out`` for the models of source ``src`` (manifest splits, held-out categories, the
    source's own split); returns the indices left for the pooled ``cfg.split``."""
    idx = [i for i, e in enumerate(entries) if e.source == src.name]
    fixed = [entries[i].split for i in idx]
    if idx and all(s is not None for s in fixed):
        for i in idx:
            out[i] = entries[i].split
        return []
    if any(s is not None for s in fixed):
        raise ParameterError(
            "the manifest gives a split for some models but not all" + (f" (source {src.name})" if src.name else "")
        )
    rest = []
    for i in idx:
        held = cfg.category_split.get(entries[i].category)
        if held is not None:
            out[i] = held
        else:
            rest.append(i)
    if src.split is None:
        return rest
    if src.split in SPLITS:
        for i in rest:
            out[i] = src.split
    elif rest:
        _deal(entries, rest, src.split, cfg, out, f" of source {src.name}")
    return []


def _deal(entries, idx, spec, cfg, out, where) -> None:
    try:
        labels = assign_splits([entries[i].category for i in idx], spec, cfg.seed, cfg.stratify)
    except ParameterError as exc:
        raise ParameterError(f"{exc}{where}", *exc.parameters) from None
    for i, s in zip(idx, labels):
        out[i] = s


def load_locally(cfg, entries: list[ModelEntry], progress: bool = False) -> list[tuple]:
    """Load every entry in this process: ``[(LoadedModel or None, problem or None), ...]``."""
    out = []
    for e in tqdm(entries, desc="load meshes", unit="mesh", disable=not progress or len(entries) < 20, leave=False):
        try:
            out.append((load_model(source_root(cfg, e), e, source_scale(cfg, e)), None))
        except InputFileError as exc:
            out.append((None, exc.problem))
    return out


def build_catalogue(cfg, log=None, progress: bool = False, loader=None) -> tuple[list, list[dict]]:
    """Every model of a build, loaded, with its split: the meshes of every source (unreadable ones
    skipped and reported), then, after each mesh whose split ``cfg.augment`` covers, its
    augmented copies (same split: split by source mesh, never by copy).

    loader : ``loader(cfg, entries, progress) -> [(model or None, problem or None)]`` (default
        :func:`load_locally`); a model has ``entry`` (with ``sha256`` set), ``size`` and
        ``derive(entry)`` (a Ray backend returns handles to meshes in its object store).

    Returns ``(models, skipped)``; ``skipped`` lists ``{"file", "problem"}``. Raises
    InputFileError when no mesh can be read, ParameterError when the splits do not add up.
    """
    entries, skipped = discover_sources(cfg)
    models = []
    for e, (model, problem) in zip(entries, (loader or load_locally)(cfg, entries, progress)):
        if model is None:
            skipped.append({"file": (f"{e.source}/" if e.source else "") + e.file, "problem": problem})
        else:
            models.append(model)
    if log is not None:
        for s in skipped:
            log(f"warning: skipping {_skipped_path(cfg, s['file'])}: {s['problem']}")
    if not models:
        root = (
            cfg.mesh_sources()[0].path
            if len(cfg.mesh_sources()) == 1
            else ", ".join(s.path for s in cfg.mesh_sources())
        )
        raise InputFileError(root, f"none of the {len(entries) + len(skipped)} meshes could be read")
    splits = assign_model_splits([m.entry for m in models], cfg)
    for m, s in zip(models, splits):
        m.entry.split = s
    if not cfg.augment:
        return models, skipped
    out = []
    for m in models:
        out.append(m)
        if m.entry.split in cfg.augment["splits"] and not m.entry.generator:  # procedural: fresh draws instead
            out.extend(m.derive(e) for e in augment_entries(m.entry, m.size, cfg.augment, cfg.seed))
    return out, skipped


def _skipped_path(cfg, file: str) -> str:
    srcs = cfg.mesh_sources()
    if len(srcs) == 1:
        return str(Path(srcs[0].path) / file)
    name, _, rel = file.partition("/")
    return str(Path(next((s.path for s in srcs if s.name == name), name)) / rel)
