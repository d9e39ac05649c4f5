"""Predictions beside their ground truth: partial input, each model's completion, the ground truth.

Each prediction is coloured by its distance to the ground truth (nearest ground-truth point,
unit frame; one colour scale for the whole figure, with a colour bar), so that where a model
is wrong shows at a glance, not only whether its outline looks plausible. Each panel's title
gives the mean of those distances (= the report's "accuracy" when the ground truth is the
dense one).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..geometry.distances import nearest_distances
from ._figure import add_axes3d, colormap, new_figure, save_png
from .points import Layer, merge_layers

PARTIAL_COLOR, GT_COLOR = "#7b2cbf", "#8c8c8c"


def render_predictions(
    path: str | os.PathLike,
    examples: Sequence[dict],
    title: str | None = None,
    vmax: float | None = None,
    max_gt_points: int = 4096,
    elev: float = 22.0,
    azim: float = -60.0,
    dpi: int = 90,
) -> Path:
    """One row per example: partial (purple), each prediction (coloured by distance to the ground truth), ground truth (grey).

    Parameters
    ----------
    examples : dicts with ``label`` (str, row title), ``partial`` (K, 3), ``gt`` (G, 3) the
        ground truth, ``predictions`` a list of ``(name, points (L, 3))``; all in the unit frame.
    vmax : top of the distance colour scale (default: the 95th percentile of all distances).
    max_gt_points : ground-truth points drawn at most (an even subsample; distances use all).

    Returns ``path`` (PNG, atomic write).
    """
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    examples = list(examples)
    if not examples:
        raise ParameterError("no example to draw")
    dists = [
        [
            nearest_distances(np.asarray(p, dtype=np.float64).reshape(-1, 3), np.asarray(e["gt"], dtype=np.float64))
            if len(p)
            else np.zeros(0)
            for _, p in e["predictions"]
        ]
        for e in examples
    ]
    flat = np.concatenate([d for row in dists for d in row] + [np.zeros(1)])
    top = float(vmax) if vmax is not None else max(float(np.percentile(flat, 95)), 1e-6)
    norm, cmap = Normalize(0.0, top), "viridis"
    ncol = 2 + max(len(e["predictions"]) for e in examples)
    nrow = len(examples)
    fig = new_figure(2.6 * ncol + 0.8, 2.7 * nrow + 0.6)
    cells = []
    for i, e in enumerate(examples):
        gt = np.asarray(e["gt"], dtype=np.float64).reshape(-1, 3)
        shown_gt = gt[np.linspace(0, len(gt) - 1, min(len(gt), max_gt_points)).astype(np.int64)] if len(gt) else gt
        partial = np.asarray(e["partial"], dtype=np.float64).reshape(-1, 3)
        row = [(f"{e['label']}\npartial input ({len(partial)} pts)", [Layer(partial, PARTIAL_COLOR, None, 4.0, 1.0)])]
        for (name, pred), d in zip(e["predictions"], dists[i]):
            pred = np.asarray(pred, dtype=np.float64).reshape(-1, 3)
            ttl = f"{name} ({len(pred)} pts)\nmean dist. to GT {d.mean():.4f}" if len(pred) else f"{name}: empty"
            row.append((ttl, [Layer(pred, d, None, 2.5, 1.0, cmap=cmap, vmin=0.0, vmax=top)]))
        row.append((f"ground truth ({len(gt)} pts)", [Layer(shown_gt, GT_COLOR, None, 0.8, 1.0)]))
        for j, (ttl, layers) in enumerate(row):
            ax = add_axes3d(fig, nrow, ncol, i * ncol + j + 1)
            p, c, s = merge_layers(layers)
            if len(p):
                ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=s, c=c, linewidths=0, depthshade=False)
            for setlim in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
                setlim(-0.85, 0.85)
            ax.set_box_aspect((1, 1, 1), zoom=1.45)
            ax.view_init(elev=elev, azim=azim)
            ax.set_axis_off()
            ax.set_title(ttl, fontsize=7.5)
            cells.append(ax)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0, 1 - 0.8 / (2.6 * ncol + 0.8), 1 - 0.45 / (2.7 * nrow + 0.6)))
    cax = fig.add_axes((1 - 0.7 / (2.6 * ncol + 0.8), 0.15, 0.012, 0.7))
    cb = fig.colorbar(ScalarMappable(norm=norm, cmap=colormap(cmap)), cax=cax, extend="max")
    cb.set_label("prediction: distance to the nearest ground-truth point (unit frame)", fontsize=9)
    cb.ax.tick_params(labelsize=7)
    return save_png(fig, path, dpi)
