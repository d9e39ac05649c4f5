"""Figures of many clouds at once (the reproduction's figures) and of one viewpoint's ray bundle."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ._figure import add_axes3d, new_figure, save_png
from .points import Layer, merge_layers


def render_cloud_grid(
    path: str | os.PathLike,
    rows: Sequence[Sequence[tuple]],
    title: str,
    row_labels: Sequence[str] | None = None,
    elev: float = 22.0,
    azim: float = -60.0,
    limit: float = 0.9,
    dpi: int = 90,
) -> Path:
    """A grid of 3-D scatter panels (PNG, atomic write), axes fixed to ``[-limit, limit]`` (unit frame).

    ``rows``: lists of ``(panel title, [(points (K, 3), colour, size), ...])``; the layers of a
    panel are drawn as one depth-sorted set. ``row_labels`` prefix the first panel's title.
    """
    nrow, ncol = len(rows), max(len(r) for r in rows)
    fig = new_figure(2.7 * ncol, 2.8 * nrow + 0.5)
    for i, row in enumerate(rows):
        for j, (ttl, layers) in enumerate(row):
            ax = add_axes3d(fig, nrow, ncol, i * ncol + j + 1)
            p, c, s = merge_layers([Layer(pts, color, None, size, 1.0) for pts, color, size in layers])
            if len(p):
                ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=s, c=c, linewidths=0, depthshade=False)
            for setlim in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
                setlim(-limit, limit)
            ax.set_box_aspect((1, 1, 1), zoom=1.25)
            ax.view_init(elev=elev, azim=azim)
            ax.set_axis_off()
            label = f"{row_labels[i]}\n{ttl}" if (row_labels and j == 0) else ttl
            ax.set_title(label, fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_png(fig, path, dpi)


def render_rig_rays(
    path: str | os.PathLike, rig, depths: np.ndarray, index: int, surface: np.ndarray, title: str, dpi: int = 100
) -> Path:
    """One viewpoint's rays on an object, in the unit frame (PNG, atomic write).

    Parameters
    ----------
    rig : the :class:`~spotlights.geometry.rig.Rig`. depths : (n_rays,) its encoding (0 = miss).
    index : the viewpoint whose ``n_secondary`` rays are drawn: hits (green, solid) end on the
        surface, misses (orange, dashed) cross the unit sphere.
    surface : (K, 3) surface samples of the object (purple), unit frame.
    """
    m = rig.n_secondary
    depth = np.asarray(depths, dtype=np.float64).reshape(rig.n_primary, m)[index]
    o = rig.origins.reshape(rig.n_primary, m, 3)[index]
    d = rig.directions.reshape(rig.n_primary, m, 3)[index]
    t_hit = 2.0 * depth
    chord = np.clip(-2.0 * np.einsum("ij,ij->i", o, d), 0.0, 2.0)
    fig = new_figure(6.5, 6.0)
    ax = add_axes3d(fig, 1, 1, 1)
    u, v = np.mgrid[0 : 2 * np.pi : 25j, 0 : np.pi : 13j]
    ax.plot_wireframe(np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v), color="0.85", lw=0.4)
    ax.scatter(*np.asarray(surface).T, s=0.6, color="#7b2cbf", alpha=0.5, linewidths=0, depthshade=False)
    ax.scatter(*rig.primary.T, s=10, color="black", depthshade=False)
    for k in range(m):
        hit = t_hit[k] > 0
        end = o[k] + d[k] * (t_hit[k] if hit else chord[k])
        ax.plot(*np.stack([o[k], end]).T, color="#2a9d3f" if hit else "#f4a261", lw=0.7, ls="-" if hit else "--")
    ax.scatter(*o[0], s=40, color="red", depthshade=False)
    ax.set_box_aspect((1, 1, 1), zoom=1.2)
    ax.set_axis_off()
    ax.view_init(elev=20, azim=-50)
    ax.set_title(title, fontsize=8)
    return save_png(fig, path, dpi)
