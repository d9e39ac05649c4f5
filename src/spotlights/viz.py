"""Headless pictures (matplotlib, Agg backend): meshes, point clouds, encodings.

Every function writes a PNG atomically and returns its path. Points are drawn
in whatever frame they are given; axes are equal so shapes are not distorted.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from .utils import atomic_output

# Two views: three-quarter front-left and top, as in most completion papers' figures.
DEFAULT_VIEWS = ((25.0, -60.0), (90.0, -90.0))


@dataclass
class Layer:
    """One point set to draw: (K, 3) points, a colour or (K,) values, a legend label, a marker size."""

    points: np.ndarray
    color: object = "tab:blue"
    label: str | None = None
    size: float = 2.0
    alpha: float = 0.9


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _equal_axes(ax, pts: np.ndarray):
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    c, r = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-9)
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")


def render_layers(
    path: str | os.PathLike,
    layers: Sequence[Layer],
    title: str | None = None,
    views: Sequence[tuple[float, float]] = DEFAULT_VIEWS,
    dpi: int = 110,
) -> Path:
    """Draw point layers from several viewpoints side by side into a PNG.

    Parameters
    ----------
    layers : point sets (same frame); the axes fit all of them.
    views : (elevation, azimuth) pairs in degrees, one panel each.
    """
    plt = _pyplot()
    allpts = np.concatenate([np.asarray(l.points, dtype=np.float64).reshape(-1, 3) for l in layers] or [np.zeros((1, 3))])
    if len(allpts) == 0:
        allpts = np.zeros((1, 3))
    fig = plt.figure(figsize=(5.0 * len(views), 5.0))
    for j, (elev, azim) in enumerate(views):
        ax = fig.add_subplot(1, len(views), j + 1, projection="3d")
        for layer in layers:
            p = np.asarray(layer.points, dtype=np.float64).reshape(-1, 3)
            if len(p) == 0:
                continue
            kw = {"c": layer.color} if not isinstance(layer.color, str) else {"color": layer.color}
            ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=layer.size, alpha=layer.alpha, label=layer.label,
                       depthshade=False, linewidths=0, **kw)
        _equal_axes(ax, allpts)
        ax.view_init(elev=elev, azim=azim)
        if abs(elev) >= 89:  # top view: the z ticks would pile up
            ax.set_zticks([])
            ax.set_zlabel("")
        if j == 0 and any(l.label for l in layers):
            ax.legend(loc="upper left", fontsize=8, markerscale=4)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_output(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return Path(path)


def render_mesh(path: str | os.PathLike, mesh, title: str | None = None, views=DEFAULT_VIEWS, max_faces: int = 20000) -> Path:
    """Shaded picture of a triangle mesh (faces subsampled beyond ``max_faces``)."""
    plt = _pyplot()
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces)
    if len(f) > max_faces:
        f = f[np.linspace(0, len(f) - 1, max_faces).astype(np.int64)]
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    shade = 0.35 + 0.65 * np.abs(n @ light)
    colors = np.clip(np.outer(shade, [0.55, 0.65, 0.85]), 0, 1)
    fig = plt.figure(figsize=(5.0 * len(views), 5.0))
    for j, (elev, azim) in enumerate(views):
        ax = fig.add_subplot(1, len(views), j + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(tri, facecolors=colors, edgecolors="none", linewidths=0))
        _equal_axes(ax, v)
        ax.view_init(elev=elev, azim=azim)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_output(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return Path(path)


def render_encoding(path: str | os.PathLike, encoding, title: str | None = None, clip: float | None = None) -> Path:
    """Picture of an encoding's ordered point cloud (unit frame), coloured by viewpoint index.

    Colouring by viewpoint shows the structure of the representation: each
    viewpoint's bundle of rays lands as one patch.
    """
    from .geometry.encode import decode

    pts, mask = decode(encoding.depths, encoding.rig, clip)
    view_id = np.repeat(np.arange(encoding.rig.n_primary), encoding.rig.n_secondary)
    plt = _pyplot()
    colors = plt.get_cmap("turbo")(view_id[mask] / max(encoding.rig.n_primary - 1, 1))
    ttl = title or (f"{encoding.rig.name}: {int(mask.sum())}/{encoding.rig.n_rays} rays hit "
                    f"({mask.mean():.1%}), colour = viewpoint")
    return render_layers(path, [Layer(pts[mask], colors, None, 3.0)], title=ttl)
