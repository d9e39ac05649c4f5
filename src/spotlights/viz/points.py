"""Pictures of point sets: a three-quarter 3-D view beside a top view.

Points are drawn in whatever frame they are given, with equal scales on every axis.
Occlusion is honest: the layers of one picture are drawn as **one** depth-sorted set of
markers (the nearest point last), so a layer cannot hide another one that lies in front
of it merely because it was drawn later. The top view is a plain 2-D plot of x and y
(seen from +z, the highest point drawn last), with its own ticks and no clipping.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._figure import add_axes3d, colormap, cube_limits, equal_axes3d, new_figure, save_png

# Two views: three-quarter front-left and top, as in most completion papers' figures.
DEFAULT_VIEWS = ((25.0, -60.0), (90.0, -90.0))


@dataclass
class Layer:
    """One point set to draw.

    points : (K, 3) float, any frame (all layers of a picture in the same one).
    color : a matplotlib colour, a (K,) array of values (mapped with ``cmap``), or (K, 3|4) RGB(A).
    label : legend label (None: not in the legend).
    size : marker area in points^2. alpha : opacity.
    cmap, vmin, vmax : colour map of (K,) values (default: "viridis" over the values' range).
    colorbar : label of a colour bar for the (K,) values (None: no colour bar).
    """

    points: np.ndarray
    color: object = "tab:blue"
    label: str | None = None
    size: float = 2.0
    alpha: float = 0.9
    cmap: str | None = None
    vmin: float | None = None
    vmax: float | None = None
    colorbar: str | None = None

    def rgba(self) -> np.ndarray:
        """(K, 4) float RGBA of every point (alpha included)."""
        from matplotlib.colors import to_rgba, to_rgba_array

        n = len(np.asarray(self.points).reshape(-1, 3))
        c = self.color
        if isinstance(c, (str, tuple)):  # one colour for every point
            out = np.tile(to_rgba(c), (n, 1))
        else:
            arr = np.asarray(c)
            if arr.ndim == 1 and len(arr) == n and np.issubdtype(arr.dtype, np.number):
                out = colormap(self.cmap or "viridis")(self.norm()(arr.astype(np.float64)))
            else:
                out = to_rgba_array(arr)
                if len(out) == 1:
                    out = np.tile(out, (n, 1))
        out = np.array(out, dtype=np.float64)
        out[:, 3] *= self.alpha
        return out

    def norm(self):
        """The value -> [0, 1] normalisation of (K,) colour values."""
        from matplotlib.colors import Normalize

        v = np.asarray(self.color, dtype=np.float64)
        lo = float(np.min(v)) if self.vmin is None and len(v) else (self.vmin or 0.0)
        hi = float(np.max(v)) if self.vmax is None and len(v) else (self.vmax if self.vmax is not None else 1.0)
        return Normalize(lo, hi if hi > lo else lo + 1.0)


#: Points drawn at most in one picture, all layers together: beyond it every layer is thinned evenly (deterministic,
#: in proportion to its size). A picture of 10 million points took 115 s and 6.5 GB; 200,000 take seconds and
#: look the same at the picture's resolution.
MAX_DRAWN_POINTS = 200_000


def thin_layers(layers: Sequence[Layer], max_points: int = MAX_DRAWN_POINTS) -> list[Layer]:
    """The layers with at most ``max_points`` points in all: each layer of K points keeps an even subsample of
    ``ceil(K * max_points / total)`` rows (per-point colours thinned with them); unchanged when they fit."""
    import dataclasses
    import math

    sizes = [len(np.asarray(layer.points).reshape(-1, 3)) for layer in layers]
    total = sum(sizes)
    if total <= max_points:
        return list(layers)
    out = []
    for layer, n in zip(layers, sizes):
        k = min(n, math.ceil(n * max_points / total))
        idx = np.linspace(0, n - 1, k).astype(np.int64) if k else np.zeros(0, np.int64)
        color = layer.color
        if not isinstance(color, (str, tuple)) and len(np.asarray(color)) == n and n > 1:
            color = np.asarray(color)[idx]
        out.append(dataclasses.replace(layer, points=np.asarray(layer.points).reshape(-1, 3)[idx], color=color))
    return out


def merge_layers(layers: Sequence[Layer]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All layers as one set: points (K, 3) float64, RGBA (K, 4), marker sizes (K,)."""
    pts, cols, sizes = [], [], []
    for layer in layers:
        p = np.asarray(layer.points, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0:
            continue
        pts.append(p)
        cols.append(layer.rgba())
        sizes.append(np.full(len(p), float(layer.size)))
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0)
    return np.concatenate(pts), np.concatenate(cols), np.concatenate(sizes)


def draw_points3d(
    ax, layers: Sequence[Layer], elev: float, azim: float, center=None, half=None, labels=("x", "y", "z")
) -> None:
    """Draw layers on a 3-D axes as one depth-sorted scatter, with equal axes (cube around all points)."""
    p, c, s = merge_layers(layers)
    if len(p):
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=s, c=c, depthshade=False, linewidths=0)
    if center is None:
        center, half = cube_limits(p)
    equal_axes3d(ax, center, half, labels)
    ax.view_init(elev=elev, azim=azim)


def draw_top(ax, layers: Sequence[Layer], center=None, half=None, labels=("x", "y")) -> None:
    """Draw layers seen from +z on a 2-D axes (x right, y up, equal scales; highest point on top)."""
    from matplotlib.ticker import MaxNLocator

    p, c, s = merge_layers(layers)
    if len(p):
        order = np.argsort(p[:, 2], kind="stable")
        ax.scatter(p[order, 0], p[order, 1], s=s[order], c=c[order], linewidths=0)
    if center is None:
        center, half = cube_limits(p)
    ax.set_xlim(center[0] - half, center[0] + half)
    ax.set_ylim(center[1] - half, center[1] + half)
    ax.set_aspect("equal")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(MaxNLocator(6, steps=[1, 2, 2.5, 5, 10]))
    ax.tick_params(labelsize=8)
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.grid(alpha=0.25, lw=0.5)


def _legend(ax, layers: Sequence[Layer]) -> None:
    from matplotlib.lines import Line2D

    handles = [
        Line2D([], [], ls="none", marker="o", ms=6, color=layer.color, label=layer.label)
        for layer in layers
        if layer.label and isinstance(layer.color, (str, tuple))
    ]
    if handles:
        ax.legend(handles=handles, loc="upper left", fontsize=8, framealpha=0.8)


def figure_layers(
    layers: Sequence[Layer], title: str | None = None, views: Sequence[tuple[float, float]] = DEFAULT_VIEWS
):
    """The :class:`~matplotlib.figure.Figure` of :func:`render_layers` (not saved); at most
    :data:`MAX_DRAWN_POINTS` points are drawn (:func:`thin_layers`)."""
    from matplotlib.cm import ScalarMappable

    layers = thin_layers(layers)

    p, _, _ = merge_layers(layers)
    center, half = cube_limits(p, 0.0)
    half *= 1.04  # a margin: points on the extremes stay whole
    bars = [layer for layer in layers if layer.colorbar]
    fig = new_figure(5.0 * len(views) + (1.0 if bars else 0.0), 5.2, layout="constrained")
    axes = []
    for j, (elev, azim) in enumerate(views):
        if elev >= 89.0:  # a view from straight above: a 2-D plot with its own ticks
            ax = fig.add_subplot(1, len(views), j + 1)
            draw_top(ax, layers, center, half)
            ax.set_title("top view (from +z)", fontsize=9)
        else:
            ax = add_axes3d(fig, 1, len(views), j + 1)
            draw_points3d(ax, layers, elev, azim, center, half)
            ax.set_title(f"elevation {elev:g} deg, azimuth {azim:g} deg", fontsize=9)
        axes.append(ax)
    if any(layer.label for layer in layers):
        _legend(axes[0], layers)
    if title:
        fig.suptitle(title, fontsize=11)
    for layer in bars:
        sm = ScalarMappable(norm=layer.norm(), cmap=colormap(layer.cmap or "viridis"))
        cb = fig.colorbar(sm, ax=axes, fraction=0.03, pad=0.02, aspect=30)
        cb.set_label(layer.colorbar, fontsize=9)
        cb.ax.tick_params(labelsize=8)
    return fig


def render_layers(
    path: str | os.PathLike,
    layers: Sequence[Layer],
    title: str | None = None,
    views: Sequence[tuple[float, float]] = DEFAULT_VIEWS,
    dpi: int = 110,
) -> Path:
    """Draw point layers from several viewpoints side by side into a PNG (atomic write); at most
    :data:`MAX_DRAWN_POINTS` points in all (an even subsample of each layer beyond).

    Parameters
    ----------
    layers : point sets (same frame); the axes fit all of them (equal scales).
    views : (elevation, azimuth) pairs in degrees, one panel each; an elevation of +-90
        gives a 2-D top view.
    """
    fig = figure_layers(layers, title, views)
    return save_png(fig, path, dpi)
