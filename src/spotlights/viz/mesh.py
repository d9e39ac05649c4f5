"""Pictures of triangle meshes: z-buffered, shaded, every face drawn (see :mod:`.raster`)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ._figure import new_figure, save_png
from .points import DEFAULT_VIEWS
from .raster import shade_mesh, view_basis


def _axis_triad(ax, elev: float, azim: float) -> None:
    """Small x (red), y (green), z (blue) arrows in the lower-left corner: the view's orientation."""
    basis = view_basis(elev, azim)
    origin = np.array([0.12, 0.12])
    for k, (name, col) in enumerate(zip("xyz", ("#d62728", "#2ca02c", "#1f77b4"))):
        e = np.zeros(3)
        e[k] = 1.0
        d = np.array([e @ basis[0], e @ basis[1]]) * 0.08
        if np.linalg.norm(d) < 1e-3:  # pointing at the viewer: a dot
            ax.plot(*origin, marker="o", ms=3, color=col, transform=ax.transAxes)
        else:
            ax.annotate(
                "",
                xy=origin + d,
                xytext=origin,
                xycoords="axes fraction",
                arrowprops=dict(arrowstyle="-|>", color=col, lw=1.2, mutation_scale=8),
            )
        ax.text(*(origin + d * 1.35), name, color=col, fontsize=8, ha="center", va="center", transform=ax.transAxes)


def figure_mesh(
    mesh,
    title: str | None = None,
    views: Sequence[tuple[float, float]] = DEFAULT_VIEWS,
    max_faces: int | None = None,
    size: int = 800,
):
    """The :class:`~matplotlib.figure.Figure` of :func:`render_mesh` (not saved)."""
    from matplotlib.ticker import MaxNLocator

    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    if max_faces is not None and len(f) > max_faces:
        f = f[np.linspace(0, len(f) - 1, max_faces).astype(np.int64)]
    lo, hi = v.min(axis=0), v.max(axis=0)
    center, half = (lo + hi) / 2.0, max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-9) * 1.02
    fig = new_figure(5.0 * len(views), 5.2, layout="constrained")
    for j, (elev, azim) in enumerate(views):
        ax = fig.add_subplot(1, len(views), j + 1)
        rgba, extent = shade_mesh(v, f, elev, azim, size=size, center=center, half=half)
        ax.imshow(rgba, extent=extent, interpolation="antialiased", origin="upper")
        ax.set_aspect("equal")
        if elev >= 89.0 and abs(((azim + 90.0) + 180.0) % 360.0 - 180.0) < 1e-6:  # top view: x right, y up
            ax.set_xlabel("x")
            ax.set_ylabel("y")
            for axis in (ax.xaxis, ax.yaxis):
                axis.set_major_locator(MaxNLocator(6, steps=[1, 2, 2.5, 5, 10]))
            ax.tick_params(labelsize=8)
            ax.grid(alpha=0.25, lw=0.5)
            ax.set_title("top view (from +z)", fontsize=9)
        else:
            ax.set_xticks([])
            ax.set_yticks([])
            for sp in ax.spines.values():
                sp.set_visible(False)
            _axis_triad(ax, elev, azim)
            ax.set_title(f"elevation {elev:g} deg, azimuth {azim:g} deg", fontsize=9)
    if title:
        fig.suptitle(title, fontsize=11)
    return fig


def render_mesh(
    path: str | os.PathLike,
    mesh,
    title: str | None = None,
    views=DEFAULT_VIEWS,
    max_faces: int | None = None,
    dpi: int = 110,
) -> Path:
    """Shaded picture of a triangle mesh from several views into a PNG (atomic write).

    Every face is rasterised with a depth test (no painter's-algorithm artefacts, no face
    subsampling unless ``max_faces`` is given). ``mesh``: anything with ``vertices`` (V, 3)
    and ``faces`` (F, 3). Orthographic views, one scale for all panels; the top view has
    x / y ticks in the mesh's units, the others an axis triad.
    """
    return save_png(figure_mesh(mesh, title, views, max_faces), path, dpi)
