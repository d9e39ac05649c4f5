"""Figures without pyplot: every picture is a :class:`matplotlib.figure.Figure` drawn by Agg.

Nothing here touches matplotlib's global state: no backend is selected (``matplotlib.use``
is never called), no pyplot figure manager holds the figures, so drawing from a
library, a notebook or a thread leaves the caller's matplotlib set-up as it was.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..outputs import atomic_output


def new_figure(width: float, height: float, layout: str | None = None):
    """A (width x height inch) :class:`~matplotlib.figure.Figure` with its own Agg canvas.

    ``layout``: None (place axes yourself or call ``tight_layout``) or "constrained".
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout=layout)
    FigureCanvasAgg(fig)
    return fig


def png_bytes(fig, dpi: int = 110, deterministic: bool = False, tight: bool = False) -> bytes:
    """``fig`` drawn by Agg and encoded as PNG: the bytes :func:`save_png` writes.

    ``deterministic`` drops the "Software" metadata (matplotlib's version) so that equal
    figures give equal bytes across matplotlib versions. ``tight`` crops the page to what is
    drawn (plus 0.1 inch), so no label that the layout pushed past the edge is cut off.
    """
    import io

    meta = {"Software": None} if deterministic else None
    extra = {"bbox_inches": "tight", "pad_inches": 0.1} if tight else {}
    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png", metadata=meta, **extra)
    return buf.getvalue()


def write_png(data: bytes, path: str | os.PathLike) -> Path:
    """Write PNG bytes (:func:`png_bytes`) atomically (temporary name, then rename); returns ``path``."""
    with atomic_output(path, suffix=".png") as tmp:
        Path(tmp).write_bytes(data)
    return Path(path)


def save_png(fig, path: str | os.PathLike, dpi: int = 110, deterministic: bool = False, tight: bool = False) -> Path:
    """Write ``fig`` as a PNG atomically (temporary name, then rename); returns ``path``. ``deterministic`` and
    ``tight``: see :func:`png_bytes`."""
    return write_png(png_bytes(fig, dpi, deterministic, tight), path)


def colormap(name: str):
    """A registered matplotlib colormap by name (no pyplot)."""
    import matplotlib

    return matplotlib.colormaps[name]


def add_axes3d(fig, *args, **kwargs):
    """``fig.add_subplot(*args, projection="3d")`` with the 3-D projection registered."""
    import mpl_toolkits.mplot3d  # noqa: F401  (registers the "3d" projection)

    return fig.add_subplot(*args, projection="3d", **kwargs)


def cube_limits(points: np.ndarray, pad: float = 0.0) -> tuple[np.ndarray, float]:
    """Centre (3,) and half-side of the smallest axis-aligned cube around (K, 3) points (+ pad)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros(3), 1.0
    lo, hi = p.min(axis=0), p.max(axis=0)
    return (lo + hi) / 2.0, max(float((hi - lo).max()) / 2.0, 1e-9) + pad


def equal_axes3d(ax, center: np.ndarray, half: float, labels=("x", "y", "z"), n_ticks: int = 5) -> None:
    """Equal scales on a 3-D axes: a cube of half-side ``half`` around ``center``.

    At most ``n_ticks`` ticks per axis and none at the ends of an axis (where the labels of
    two axes meet in a corner), so that tick labels never run into each other (``-0.20.0``).
    """
    from matplotlib.ticker import MaxNLocator

    for setlim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), center):
        setlim(c - half, c + half)
    ax.set_box_aspect((1, 1, 1))
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(n_ticks, steps=[1, 2, 2.5, 5, 10], prune="both"))
    ax.tick_params(labelsize=7, pad=0)
    if labels:
        ax.set_xlabel(labels[0], labelpad=-2)
        ax.set_ylabel(labels[1], labelpad=-2)
        ax.set_zlabel(labels[2], labelpad=-4)


def add_scale_bar(ax, length: float | None = None, label: str = "m", loc: str = "lower left") -> float:
    """A scale bar on a 2-D axes with equal aspect (data units); returns its length.

    ``length`` default: a round number near a fifth of the axes' width (1, 2 or 5 x 10^k).
    """
    from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar

    x0, x1 = ax.get_xlim()
    if length is None:
        length = nice_length(abs(x1 - x0) / 5.0)
    text = f"{length:g} {label}".strip()
    bar = AnchoredSizeBar(
        ax.transData,
        length,
        text,
        loc,
        pad=0.3,
        borderpad=0.4,
        sep=3,
        frameon=False,
        size_vertical=0,
        fontproperties={"size": 7},
    )
    ax.add_artist(bar)
    return length


def nice_length(x: float) -> float:
    """The largest of 1, 2, 5 x 10^k not above ``x`` (x > 0)."""
    if not np.isfinite(x) or x <= 0:
        return 1.0
    k = np.floor(np.log10(x))
    for m in (5.0, 2.0, 1.0):
        if m * 10**k <= x:
            return float(m * 10**k)
    return float(10**k)
