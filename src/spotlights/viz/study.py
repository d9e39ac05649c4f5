"""The rig study's figure: completeness against hit ratio, one marker per rig and ray count."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from pathlib import Path

from ..geometry.rig import RigSpec
from ._figure import colormap, new_figure, save_png

#: colour family per target set of a rig (cap rigs: blues)
FAMILY_CMAPS = {"cap": "Blues", "volume": "Greens", "surface": "Purples", "visible": "Oranges", "ellipsoid": "Reds"}


def plot_rig_study(
    path: str | os.PathLike,
    summary,
    annotate: Callable[[object], bool] | None = None,
    floor: float | None = None,
    floor_note: str = "",
    dpi: int = 110,
) -> Path:
    """Completeness against hit ratio, one panel per mesh set (PNG, atomic write).

    Parameters
    ----------
    summary : DataFrame with ``mesh_set, category, label, family, rig, rays, hit_ratio,
        completeness`` (the study's means; rows with ``category == "all"`` are drawn).
    annotate : row -> True for the rows to name beside their marker (e.g. the reference rigs).
    floor : a hit ratio to mark with a dotted line (None: no line); ``floor_note`` says what it means.

    The legend sits below the panels (never over the points): one entry per rig variant
    (colour family = where the rays are aimed, shade = variant; black edge = the paper's
    cap rigs), one per ray count (marker shape), and the dotted line.
    """
    sets = list(dict.fromkeys(summary.mesh_set))
    ray_counts = sorted(summary.rays.unique())
    markers = {r: m for r, m in zip(ray_counts, "os^Dv")}
    fam, colors = _rig_colors(summary)
    paper = set(summary.label[summary.family == "paper"])
    fig = new_figure(6.2 * len(sets), 6.2)
    axes = fig.subplots(1, len(sets), squeeze=False)[0]
    for ax, mesh_set in zip(axes, sets):
        sub = summary[(summary.mesh_set == mesh_set) & (summary.category == "all")]
        _draw_panel(ax, sub, markers, colors, paper, annotate)
        if floor is not None:
            ax.axvline(floor, color="gray", ls=":", lw=1.2, zorder=1)
        ax.set_xlabel("hit ratio (fraction of rays that hit the object)")
        ax.set_ylabel("completeness (unit frame, lower is better)")
        ax.set_title(f"{mesh_set} (mean over meshes)", fontsize=10)
        ax.grid(alpha=0.3)
    handles = _legend_handles(fam, colors, paper, markers, ray_counts, floor, floor_note)
    ncol = min(5, max(2, len(handles) // 4 + 1))
    nrows_legend = -(-len(handles) // ncol)
    bottom = min(0.45, 0.03 + 0.034 * nrows_legend)
    fig.legend(handles=handles, loc="lower center", ncol=ncol, fontsize=7, frameon=False, bbox_to_anchor=(0.5, 0.0))
    fig.tight_layout(rect=(0, bottom, 1, 1))
    return save_png(fig, path, dpi)


def _rig_colors(summary) -> tuple[dict[str, list[str]], dict]:
    """``(family -> its rig labels in order of appearance, label -> RGBA colour)``: one colour map per
    target set (:data:`FAMILY_CMAPS`), one shade per label."""
    fam: dict[str, list[str]] = {}
    for label, rig in dict.fromkeys(zip(summary.label, summary.rig)):
        spec = RigSpec.from_name(rig)
        fam.setdefault(spec.targets or "cap", [])
        if label not in fam[spec.targets or "cap"]:
            fam[spec.targets or "cap"].append(label)
    colors = {}
    for key, labels in fam.items():
        cmap = colormap(FAMILY_CMAPS.get(key, "Greys"))
        for j, label in enumerate(labels):
            colors[label] = cmap(0.4 + 0.55 * j / max(len(labels) - 1, 1))
    return fam, colors


def _draw_panel(ax, sub, markers: dict, colors: dict, paper: set, annotate) -> None:
    """One mesh set's markers (and the names ``annotate`` asks for) on ``ax``."""
    mid = 0.5 * (float(sub.hit_ratio.min()) + float(sub.hit_ratio.max())) if len(sub) else 0.5
    for _, r in sub.iterrows():
        ax.scatter(
            r.hit_ratio,
            r.completeness,
            marker=markers[r.rays],
            color=colors[r.label],
            s=42,
            edgecolors="black" if r.label in paper else "none",
            linewidths=0.8,
            zorder=3,
        )
        if annotate is not None and annotate(r):
            right = r.hit_ratio > mid  # name on the inner side: never past the panel's edge
            ax.annotate(
                f"{r.rays}: {r.label}",
                (r.hit_ratio, r.completeness),
                fontsize=7,
                xytext=(-6 if right else 6, 3),
                textcoords="offset points",
                ha="right" if right else "left",
            )


def _legend_handles(fam, colors, paper, markers, ray_counts, floor, floor_note) -> list:
    """The legend's entries: one per rig variant, one per ray count, and the dotted line."""
    from matplotlib.lines import Line2D

    handles = [
        Line2D(
            [],
            [],
            ls="none",
            marker="o",
            ms=6,
            color=colors[label],
            markeredgecolor="black" if label in paper else "none",
            label=label,
        )
        for labels in fam.values()
        for label in labels
    ]
    handles += [Line2D([], [], ls="none", marker=markers[r], ms=6, color="gray", label=f"{r} rays") for r in ray_counts]
    if floor is not None:
        handles.append(
            Line2D(
                [],
                [],
                color="gray",
                ls=":",
                lw=1.2,
                label=f"hit ratio {floor:g}" + (f": {floor_note}" if floor_note else ""),
            )
        )
    return handles


def annotate_rigs(names: Iterable[str]) -> Callable[[object], bool]:
    """An ``annotate`` predicate naming the rows whose rig is one of ``names``."""
    names = set(names)
    return lambda row: row.rig in names
