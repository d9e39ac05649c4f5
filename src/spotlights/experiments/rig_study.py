"""Rig study: hit ratio and completeness of paper (cap) rigs and box-targeted rigs.

For every mesh of one or more folders and every rig of a list:

* normalise the mesh by its own axis-aligned box (the paper's step 1),
* encode it (one Embree call per rig; box rigs are built for the mesh's box),
* ``hit_ratio`` = rays with a hit / all rays of the rig,
* ``completeness`` = :func:`~spotlights.geometry.distances.completeness`: the mean
  distance from 16,384 points sampled uniformly
  (by area) on the mesh surface to the decoded hit points, both in the unit frame
  (the paper's Section 5.3 completeness: one-sided, not squared, mean over the
  surface samples; lower is better).

Results are deterministic: the surface samples of a mesh are seeded by the study
seed and the mesh's relative path, whatever the order or the number of workers.
Per-mesh results are cached under ``OUT/.cache`` so an interrupted run resumes.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import os
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ParameterError, SpotlightsError
from ..geometry.distances import completeness
from ..geometry.encode import MeshProbe, decode
from ..geometry.io import MESH_SUFFIXES, load_mesh
from ..geometry.rig import RigSpec, make_rig_spec
from ..geometry.sampling import sample_surface
from ..options import REQUIRED, non_negative_int, option, positive_int
from ..outputs import atomic_output, output_folder
from ..processes import process_map
from ..viz.study import plot_rig_study

CARS = "apolloscape-cars"
DEFAULT_RAYS = (2048, 4096, 8192)
DEFAULT_STUDY_MESHES = ("../shared/data/meshes/apolloscape-cars", "../shared/data/meshes/categories")
"""The mesh folders of ``spotlights study rigs`` (relative to the working folder)."""
SECONDARY = 64  # M; N = rays / M (the paper's 32 x 64 at 2048 rays)
N_SURFACE = 16384
MIN_PER_CATEGORY = 5
HIT_RATIO_FLOOR = 0.90
REFERENCE_CAP_ANGLE = 60.0
CACHE_VERSION = 1

# Rig variants per ray count: (label, keyword arguments of make_rig_spec besides N, M).
PAPER_RIGS = (
    ("cap 30", dict(angle=30.0)),
    ("cap 60", dict(angle=60.0)),
    ("cap 83 (r = R/4)", dict(radius=0.25)),
)
BOX_RIGS = (
    ("box volume s0.6", dict(kind="box", targets="volume", scale=0.6)),
    ("box volume s0.8", dict(kind="box", targets="volume", scale=0.8)),
    ("box volume s0.9", dict(kind="box", targets="volume", scale=0.9)),
    ("box volume s1", dict(kind="box", targets="volume", scale=1.0)),
    ("box surface s0.8", dict(kind="box", targets="surface", scale=0.8)),
    ("box surface s0.9", dict(kind="box", targets="surface", scale=0.9)),
    ("box visible s0.7", dict(kind="box", targets="visible", scale=0.7)),
    ("box visible s0.8", dict(kind="box", targets="visible", scale=0.8)),
    ("box ellipsoid s0.9", dict(kind="box", targets="ellipsoid", scale=0.9)),
    ("box ellipsoid s1", dict(kind="box", targets="ellipsoid", scale=1.0)),
    ("box ellipsoid s1 + cap 25%", dict(kind="box", targets="ellipsoid", scale=1.0, cap_share=0.25, angle=60.0)),
)


@dataclass(frozen=True)
class StudyRig:
    """One rig of the study: a display label (``family``) and its spec at one ray count."""

    label: str
    spec: RigSpec

    @property
    def family(self) -> str:
        """``"paper"`` for cap rigs, ``"box"`` for box-targeted ones."""
        return "paper" if self.spec.kind == "cap" else "box"


def default_box_spec(rays: int, secondary: int = SECONDARY) -> RigSpec:
    """The box rig a user gets with ``--rig-kind box`` (``BOX_DEFAULTS``) at ``rays`` rays."""
    return make_rig_spec(int(rays) // secondary, secondary, kind="box")


def study_rigs(rays: Sequence[int] = DEFAULT_RAYS, secondary: int = SECONDARY, variants=None) -> list[StudyRig]:
    """The study's rigs: every variant (default ``PAPER_RIGS + BOX_RIGS``) at every ray count.

    ``rays`` must be multiples of ``secondary`` (M); N = rays / M.
    """
    variants = tuple(variants) if variants is not None else PAPER_RIGS + BOX_RIGS
    out = []
    for k in rays:
        if int(k) < secondary or int(k) % secondary:
            raise ParameterError(f"ray count {k} must be a positive multiple of M = {secondary}")
        for label, kw in variants:
            out.append(StudyRig(label, make_rig_spec(int(k) // secondary, secondary, **kw)))
    return out


@dataclass
class MeshEntry:
    """A mesh of the study: its path, mesh set (folder name), category and id (path relative to the set)."""

    path: Path
    mesh_set: str
    category: str
    mesh_id: str


def find_meshes(folders: Sequence, min_per_category: int = MIN_PER_CATEGORY) -> list[MeshEntry]:
    """Meshes of each folder, category = first sub-folder, sorted by relative path.

    Categories with fewer than ``min_per_category`` meshes are left out (the paper's
    ablation averages over categories).
    """
    entries = []
    for folder in folders:
        root = Path(folder)
        if not root.is_dir():
            raise SpotlightsError(f"{root}: no such folder of meshes")
        files = sorted(p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in MESH_SUFFIXES)
        if not files:
            raise SpotlightsError(f"{root}: no mesh files ({', '.join(MESH_SUFFIXES)})")
        found = []
        for p in files:
            rel = p.relative_to(root)
            category = rel.parts[0] if len(rel.parts) > 1 else root.name
            found.append(MeshEntry(p, root.name, category, rel.as_posix()))
        counts = {}
        for e in found:
            counts[e.category] = counts.get(e.category, 0) + 1
        entries += [e for e in found if counts[e.category] >= min_per_category]
    return entries


def mesh_axes(path: Path) -> dict:
    """Keyword arguments of :func:`~spotlights.geometry.io.load_mesh` for a mesh file of the study: ``up="y"`` for glTF."""
    # glTF is y-up by its specification; other formats are read as they are (z up).
    return {"up": "y"} if path.suffix.lower() in (".glb", ".gltf") else {}


def evaluate_mesh(entry: MeshEntry, rigs: Sequence[StudyRig], seed: int = 0, n_surface: int = N_SURFACE) -> list[dict]:
    """Hit ratio and completeness of every rig on one mesh (see the module docstring).

    Returns
    -------
    list of dicts, one per rig: ``mesh_set, category, mesh, rig, label, family, rays,
    hits, hit_ratio, completeness`` (completeness in unit-frame units).
    """
    mesh = load_mesh(entry.path, **mesh_axes(entry.path))
    probe = MeshProbe(mesh)
    mesh_seed = (int(seed) << 32) ^ zlib.crc32(f"{entry.mesh_set}/{entry.mesh_id}".encode())
    surface = probe.normalization.to_unit(sample_surface(mesh, n_surface, mesh_seed))
    rows = []
    for r in rigs:
        rig = probe.rig_for(r.spec)
        depths = probe.encode(rig)
        points, mask = decode(depths, rig)
        hits = int(mask.sum())
        rows.append(
            {
                "mesh_set": entry.mesh_set,
                "category": entry.category,
                "mesh": entry.mesh_id,
                "rig": r.spec.name,
                "label": r.label,
                "family": r.family,
                "rays": rig.n_rays,
                "hits": hits,
                "hit_ratio": hits / rig.n_rays,
                # float64 queries: the distances do not depend on the decoded points' float32
                "completeness": completeness(
                    np.asarray(points[mask], dtype=np.float64), np.asarray(surface, dtype=np.float64)
                ),
            }
        )
    return rows


def _config_key(rigs: Sequence[StudyRig], seed: int, n_surface: int) -> str:
    # The rays themselves (for a reference box) enter the key, so a change of the rig
    # geometry code invalidates cached results.
    probe = np.array([0.8, 0.45, 0.4]) / np.linalg.norm([0.8, 0.45, 0.4])
    h = hashlib.sha256()
    h.update(
        json.dumps(
            {
                "v": CACHE_VERSION,
                "seed": seed,
                "n_surface": n_surface,
                "rigs": [[r.label, r.spec.to_dict()] for r in rigs],
            },
            sort_keys=True,
        ).encode()
    )
    for r in rigs:
        h.update(np.ascontiguousarray(r.spec.for_box(probe).directions).tobytes())
    return h.hexdigest()[:16]


def _job(args):
    entry, rigs, seed, n_surface, cache = args
    if cache is not None and cache.exists():
        return json.loads(cache.read_text())
    rows = evaluate_mesh(entry, rigs, seed, n_surface)  # its errors pickle whole (types, parameters) across processes
    if cache is not None:
        ignore = cache.parent.parent / ".gitignore"
        if not ignore.exists():
            with atomic_output(ignore, suffix="") as tmp:  # a cache inside a checkout stays out of git
                Path(tmp).write_text("*\n")
        with atomic_output(cache, suffix=".json") as tmp:
            Path(tmp).write_text(json.dumps(rows))
    return rows


def run_study(
    meshes: Sequence[MeshEntry],
    rigs: Sequence[StudyRig],
    seed: int = 0,
    n_surface: int = N_SURFACE,
    workers: int = 1,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = True,
):
    """Evaluate every rig on every mesh; returns a pandas DataFrame with one row per (mesh, rig).

    ``cache_dir``: per-mesh results are kept there (keyed by the study configuration)
    and reused, so an interrupted run resumes. ``workers`` > 1 uses processes over
    meshes; the rows do not depend on it.
    """
    import pandas as pd
    from tqdm import tqdm

    cache = None
    if cache_dir is not None:
        cache = Path(cache_dir) / _config_key(rigs, seed, n_surface)  # created with its first result

    def cache_file(e: MeshEntry):
        if cache is None:
            return None
        return cache / (hashlib.sha256(f"{e.mesh_set}/{e.mesh_id}".encode()).hexdigest()[:20] + ".json")

    jobs = [(e, list(rigs), seed, n_surface, cache_file(e)) for e in meshes]
    results = []
    with tqdm(total=len(jobs), desc="rig study", unit="mesh", disable=not progress) as bar:
        for rows in process_map(_job, jobs, workers, what="mesh"):
            results.append(rows)
            bar.update()
    return pd.DataFrame([row for rows in results for row in rows])


def summarize(df):
    """Means per (mesh set, category, rig) and per (mesh set, rig) over categories.

    Returns a DataFrame with ``mesh_set, category, label, family, rig, rays, n_meshes,
    hit_ratio, completeness``; category ``"all"`` rows average the mesh set's
    categories with equal weight (the paper's "Average" column) for category
    folders, and over every mesh for the cars (one benchmark set).
    """
    import pandas as pd

    keys = ["mesh_set", "category", "label", "family", "rig", "rays"]
    per_cat = (
        df.groupby(keys, sort=False)
        .agg(n_meshes=("mesh", "size"), hit_ratio=("hit_ratio", "mean"), completeness=("completeness", "mean"))
        .reset_index()
    )
    rows = []
    for mesh_set, sub in df.groupby("mesh_set", sort=False):
        if mesh_set == CARS:  # one benchmark set: mean over the cars
            agg = (
                sub.groupby(keys[2:], sort=False)
                .agg(n_meshes=("mesh", "size"), hit_ratio=("hit_ratio", "mean"), completeness=("completeness", "mean"))
                .reset_index()
            )
        else:  # mean of the category means
            cats = per_cat[per_cat.mesh_set == mesh_set]
            agg = (
                cats.groupby(keys[2:], sort=False)
                .agg(
                    n_meshes=("n_meshes", "sum"), hit_ratio=("hit_ratio", "mean"), completeness=("completeness", "mean")
                )
                .reset_index()
            )
        agg.insert(0, "category", "all")
        agg.insert(0, "mesh_set", mesh_set)
        rows.append(agg)
    return pd.concat([per_cat] + rows, ignore_index=True)


def best_box_variant(summary, mesh_set: str = CARS, rays: int = 2048, floor: float | None = HIT_RATIO_FLOOR):
    """The box variant with the lowest mean completeness among those with hit ratio >= ``floor``.

    ``floor=None``: among all box variants. Returns the summary row (a pandas Series),
    or None when no box variant reaches the floor.
    """
    s = summary[
        (summary.mesh_set == mesh_set)
        & (summary.category == "all")
        & (summary.rays == rays)
        & (summary.family == "box")
    ]
    if floor is not None:
        s = s[s.hit_ratio >= floor]
    return None if s.empty else s.sort_values("completeness").iloc[0]


def _ref_row(summary, mesh_set, rays, angle=REFERENCE_CAP_ANGLE):
    s = summary[
        (summary.mesh_set == mesh_set)
        & (summary.category == "all")
        & (summary.rays == rays)
        & (summary.rig == f"cap-{rays // SECONDARY}x{SECONDARY}-{angle:g}")
    ]
    return None if s.empty else s.iloc[0]


def _change(row, ref) -> str:
    pct = 100.0 * (row.completeness / ref.completeness - 1.0)
    return f"{abs(pct):.1f}% {'better' if pct < 0 else 'worse'} than cap 60"


def verdict_lines(summary, mesh_set: str, rays: int) -> list[str]:
    """One-line verdicts for a mesh set and ray count: the best box variant with hit ratio >= 0.90, and overall."""
    ref = _ref_row(summary, mesh_set, rays)
    if ref is None:
        return []
    lines = []
    best = best_box_variant(summary, mesh_set, rays)
    if best is None:
        lines.append(f"No box variant reaches a hit ratio of {HIT_RATIO_FLOOR:.2f} on {mesh_set}.")
    else:
        lines.append(
            f"Best box variant with hit ratio >= {HIT_RATIO_FLOOR:.2f}: {best.label} (`{best.rig}`), "
            f"hit ratio {best.hit_ratio:.3f}, completeness {best.completeness:.4f}, {_change(best, ref)} "
            f"(hit ratio {ref.hit_ratio:.3f}, completeness {ref.completeness:.4f})."
        )
    top = best_box_variant(summary, mesh_set, rays, floor=None)
    if top is not None and (best is None or top.rig != best.rig):
        lines.append(
            f"Best box variant by completeness alone: {top.label} (`{top.rig}`), hit ratio "
            f"{top.hit_ratio:.3f}, completeness {top.completeness:.4f}, {_change(top, ref)}."
        )
    return lines


def markdown_report(summary, meshes: Sequence[MeshEntry], seed: int, n_surface: int) -> str:
    """The study's Markdown report: per mesh set and ray count, every rig's means and the gain over cap 60."""
    lines = [
        "# Rig study: hit ratio and completeness",
        "",
        f"Completeness: mean distance from {n_surface:,} uniform surface samples to the Spotlights hit points "
        "(one-sided, not squared, unit frame; lower is better). Hit ratio: rays with a hit / all rays. "
        f"Rigs of N x {SECONDARY} rays (N = rays / {SECONDARY}); every mesh normalised by its own "
        f"axis-aligned box; surface samples seeded by seed {seed} and the mesh path. "
        f"'vs cap 60' = completeness change relative to the paper's 60-degree rig (negative = better).",
        "",
    ]
    sets = list(dict.fromkeys(e.mesh_set for e in meshes))
    for mesh_set in sets:
        cats = sorted({e.category for e in meshes if e.mesh_set == mesh_set})
        n = sum(e.mesh_set == mesh_set for e in meshes)
        avg = "mean over the meshes" if mesh_set == CARS else "mean of the category means"
        lines += [f"## {mesh_set}: {n} meshes ({', '.join(cats)}); {avg}", ""]
        for rays in sorted(summary.rays.unique()):
            sub = summary[(summary.mesh_set == mesh_set) & (summary.category == "all") & (summary.rays == rays)]
            ref = _ref_row(summary, mesh_set, rays)
            lines += [
                f"### {rays} rays",
                "",
                "| rig | name | hit ratio | completeness | vs cap 60 |",
                "|---|---|---|---|---|",
            ]
            for _, r in sub.iterrows():
                gain = f"{100 * (r.completeness / ref.completeness - 1):+.1f}%" if ref is not None else ""
                lines.append(f"| {r.label} | `{r.rig}` | {r.hit_ratio:.3f} | {r.completeness:.4f} | {gain} |")
            verdicts = verdict_lines(summary, mesh_set, rays)
            lines += ([""] + verdicts if verdicts else []) + [""]
        if len(cats) > 1:
            lines += [f"### {mesh_set}: completeness per category", ""]
            piv = summary[(summary.mesh_set == mesh_set) & (summary.category != "all")]
            for rays in sorted(summary.rays.unique()):
                p = piv[piv.rays == rays]
                lines += [f"{rays} rays:", "", "| rig | " + " | ".join(cats) + " |", "|---|" + "---|" * len(cats)]
                for label in dict.fromkeys(p.label):
                    vals = [p[(p.label == label) & (p.category == c)] for c in cats]
                    lines.append(
                        f"| {label} | "
                        + " | ".join(
                            f"{v.completeness.iloc[0]:.4f} ({v.hit_ratio.iloc[0]:.2f})" if len(v) else "" for v in vals
                        )
                        + " |"
                    )
                lines.append("")
            lines += ["(completeness, hit ratio in brackets)", ""]
    return "\n".join(lines) + "\n"


def plot_study(path, summary) -> Path:
    """Completeness against hit ratio, one panel per mesh set, one marker per rig and ray count (PNG)."""

    def reference(r) -> bool:  # the paper's 60-degree cap and the default box rig at each ray count
        return r.rig in (
            f"cap-{r.rays // SECONDARY}x{SECONDARY}-{REFERENCE_CAP_ANGLE:g}",
            default_box_spec(r.rays).name,
        )

    return plot_rig_study(
        path,
        summary,
        annotate=reference,
        floor=HIT_RATIO_FLOOR,
        floor_note="the best box variant is chosen among the rigs at or above it",
    )


@dataclass
class StudyResult:
    """Paths written by :func:`rig_study` and the summary table."""

    csv: Path
    per_mesh_csv: Path
    markdown: Path
    figure: Path
    summary: object = field(repr=False)


def rig_study(
    out_dir,
    mesh_dirs: Sequence,
    rays: Sequence[int] = DEFAULT_RAYS,
    seed: int = 0,
    n_surface: int = N_SURFACE,
    workers: int = 1,
    variants=None,
    progress: bool = True,
) -> StudyResult:
    """Run the study and write ``OUT/rigs.csv`` (means), ``OUT/rigs_per_mesh.csv.gz``, ``OUT/rigs.md``, ``OUT/rigs.png``.

    Parameters
    ----------
    out_dir : output folder (created); ``OUT/.cache`` keeps per-mesh results for resuming.
    mesh_dirs : folders of meshes, one sub-folder per category.
    rays : ray counts (multiples of 64).
    seed : seed of the surface samples.
    workers : processes over meshes (results do not depend on it).
    variants : ``(label, make_rig_spec kwargs)`` pairs (default ``PAPER_RIGS + BOX_RIGS``).
    """
    out = Path(out_dir)
    meshes = find_meshes(mesh_dirs)
    if not meshes:
        raise SpotlightsError("no category has enough meshes for the study")
    rigs = study_rigs(rays, variants=variants)
    with output_folder(out):  # created now, removed again if the study fails before writing anything
        df = run_study(
            meshes, rigs, seed=seed, n_surface=n_surface, workers=workers, cache_dir=out / ".cache", progress=progress
        )
    summary = summarize(df)
    paths = StudyResult(out / "rigs.csv", out / "rigs_per_mesh.csv.gz", out / "rigs.md", out / "rigs.png", summary)
    with atomic_output(paths.csv, suffix=".csv") as tmp:
        summary.to_csv(tmp, index=False, float_format="%.6f")
    with atomic_output(paths.per_mesh_csv, suffix=".gz") as tmp:  # no name or time in the gzip header
        Path(tmp).write_bytes(gzip.compress(df.to_csv(index=False, float_format="%.6f").encode(), mtime=0))
    with atomic_output(paths.markdown, suffix=".md") as tmp:
        Path(tmp).write_text(markdown_report(summary, meshes, seed, n_surface))
    plot_study(paths.figure, summary)
    return paths


def study_summary_lines(res) -> list[str]:
    """The lines ``spotlights study rigs`` prints for a :func:`rig_study` result: every mesh set's
    and ray count's verdicts (:func:`verdict_lines`), then the files written."""
    s = res.summary
    lines = [
        f"{mesh_set}, {rays} rays: {line}"
        for mesh_set in dict.fromkeys(s.mesh_set)
        for rays in sorted(s.rays.unique())
        for line in verdict_lines(s, mesh_set, rays)
    ]
    return lines + [f"wrote {res.csv}, {res.per_mesh_csv}, {res.markdown}, {res.figure}"]


@dataclass(frozen=True, kw_only=True)
class RigStudySettings:
    """What ``spotlights study rigs`` is asked to do: its options as one object, each field
    declaring its option (:func:`spotlights.options.option`)."""

    out: str = option(
        "--out",
        "-o",
        default=REQUIRED,
        metavar="DIR",
        help="output folder: rigs.csv (means), rigs_per_mesh.csv.gz, rigs.md, rigs.png; DIR/.cache resumes a run",
    )
    meshes: list = option(
        nargs="+",
        default=list(DEFAULT_STUDY_MESHES),
        metavar="DIR",
        help="mesh folders, one sub-folder per category; categories with fewer than 5 meshes are "
        "skipped (default: the shared cars and category meshes)",
    )
    rays: list = option(
        nargs="+",
        type=int,
        default=[2048, 4096, 8192],
        metavar="K",
        help="ray counts, multiples of 64 (N = K / 64 viewpoints x 64 rays; default 2048 4096 8192)",
    )
    seed: int = option(default=0, type=non_negative_int, help="seed of the 16,384 surface samples per mesh (default 0)")
    workers: int = option(
        "--workers",
        "-j",
        type=positive_int,
        default=1,
        help="processes over meshes (results do not depend on it; default 1)",
    )
    quiet: bool = option(default=False, quiet=True, help="no progress bar")


def run_rig_study(s: RigStudySettings) -> StudyResult:
    """``spotlights study rigs``: :func:`rig_study` as ``s`` says (``s.workers`` >= 1)."""
    if s.workers < 1:
        raise SpotlightsError(f"--workers must be >= 1, got {s.workers}")
    return rig_study(s.out, s.meshes, rays=s.rays, seed=s.seed, workers=s.workers, progress=not s.quiet)
