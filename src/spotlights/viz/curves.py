"""Learning curves: validation metrics of several training runs against samples seen or minutes."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ._figure import new_figure, save_png

# Distinct colours (matplotlib's tab10), in the order the runs are given.
_COLOURS = [
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
]


def render_learning_curves(
    path: str | os.PathLike,
    curves: Mapping[str, Mapping[str, Sequence[float]]],
    metrics: Sequence[tuple[str, str]],
    x: str,
    x_label: str,
    title: str,
    log_y: bool = True,
) -> Path:
    """One panel per metric, one line per run, written as a PNG.

    Parameters
    ----------
    curves : run name -> column name -> values (one per validation; all columns of a run have
        the same length), e.g. the columns of a run's ``log.csv``.
    metrics : (column, panel title) pairs, one panel each (e.g. ``("val_chamfer_l1", "CD-L1")``).
    x : the column used as abscissa (e.g. ``"samples_seen"`` or ``"budget_minutes"``).
    log_y : logarithmic y axis (distances in the unit frame span an order of magnitude early on).
    """
    fig = new_figure(4.3 * len(metrics), 3.6, layout="constrained")
    axes = fig.subplots(1, len(metrics), squeeze=False)[0]
    for ax, (col, label) in zip(axes, metrics):
        for k, (name, cols) in enumerate(curves.items()):
            xs = np.asarray(cols[x], dtype=np.float64)
            ys = np.asarray(cols[col], dtype=np.float64)
            ok = np.isfinite(xs) & np.isfinite(ys)
            if ok.any():
                ax.plot(xs[ok], ys[ok], marker="o", ms=2.5, lw=1.3, color=_COLOURS[k % len(_COLOURS)], label=name)
        if log_y:
            ax.set_yscale("log")
        ax.set_title(label, fontsize=10)
        ax.set_xlabel(x_label, fontsize=9)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.tick_params(labelsize=8)
    handles, labels = axes[0].get_legend_handles_labels()
    if labels:  # none when every curve is empty (all-NaN validation metrics of a short run)
        fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 5), fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=11)
    return save_png(fig, path, dpi=110)
