"""Pictures of dataset samples: partial scan, uniform ground truth, Spotlights points."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..geometry.encode import decode
from ._figure import add_axes3d, new_figure, save_png
from .points import Layer, draw_points3d

PARTIAL_COLOR = "#7b2cbf"  # purple
GT_COLOR = "#8c8c8c"  # grey
SPOTLIGHTS_COLOR = "#2a9d3f"  # green


def render_sample(
    path: str | os.PathLike,
    sample: dict,
    rig,
    clip: float | None = None,
    elev: float = 25.0,
    azim: float = -60.0,
    dpi: int = 100,
) -> Path:
    """Draw one sample side by side: partial (purple), uniform ground truth (grey), Spotlights
    points (green, decoded from the ground-truth depths with ``rig``), and all three overlaid with
    an arrow toward the sensor. All in the unit frame, axes fixed to [-1, 1].

    ``sample`` is a dict from :meth:`~spotlights.data.store.CompletionDataset.sample`.
    """
    partial = np.asarray(sample["partial"], dtype=np.float64)
    gt = np.asarray(sample["gt_points"], dtype=np.float64)
    spot, mask = decode(sample["gt_depths"], rig, clip)
    spot = spot[mask].astype(np.float64)
    m = np.asarray(sample["sensor_to_unit"], dtype=np.float64)
    sensor = m[:3, 3]  # the sensor origin in the unit frame
    to_sensor = sensor / max(np.linalg.norm(sensor), 1e-12)

    panels = [
        (f"partial scan ({len(partial)} pts, {sample.get('n_raw', '?')} raw)", [(partial, PARTIAL_COLOR, 4.0)]),
        (f"uniform ground truth ({len(gt)} pts)", [(gt, GT_COLOR, 1.5)]),
        (f"Spotlights {rig.name} ({len(spot)}/{rig.n_rays} hits)", [(spot, SPOTLIGHTS_COLOR, 2.5)]),
        (
            "overlay, arrow: toward the sensor",
            [(gt, GT_COLOR, 1.0), (spot, SPOTLIGHTS_COLOR, 2.0), (partial, PARTIAL_COLOR, 4.0)],
        ),
    ]
    fig = new_figure(4.2 * len(panels), 4.8)
    for j, (title, layers) in enumerate(panels):
        ax = add_axes3d(fig, 1, len(panels), j + 1)
        draw_points3d(
            ax,
            [Layer(pts, color, None, size, 1.0) for pts, color, size in layers],
            elev,
            azim,
            np.zeros(3),
            1.0,
            ("x (forward)", "y (left)", "z"),
        )
        if j == len(panels) - 1:
            ax.quiver(0, 0, 0, *(0.9 * to_sensor), color="black", arrow_length_ratio=0.15, linewidth=1.5)
        ax.set_title(title, fontsize=9)
    fig.suptitle(
        f"{sample['model']} ({sample['category']}, {sample['split']}), view {sample['view']}: "
        f"{sample.get('distance', float('nan')):.1f} m from the sensor, unit frame",
        fontsize=11,
    )
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    return save_png(fig, path, dpi)
