"""Pictures of dataset samples: partial scan, uniform ground truth, Spotlights points."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..utils import atomic_output

PARTIAL_COLOR = "#7b2cbf"  # purple
GT_COLOR = "#8c8c8c"  # grey
SPOTLIGHTS_COLOR = "#2a9d3f"  # green


def render_sample(path: str | os.PathLike, sample: dict, rig, clip: float | None = None,
                  elev: float = 25.0, azim: float = -60.0, dpi: int = 100) -> Path:
    """Draw one sample side by side: partial (purple), uniform ground truth (grey), Spotlights
    points (green, decoded from the ground-truth depths with ``rig``), and all three overlaid with
    an arrow toward the sensor. All in the unit frame, axes fixed to [-1, 1].

    ``sample`` is a dict from :meth:`~spotlights.data.store.CompletionDataset.sample`.
    """
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from ..geometry.encode import decode

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
        ("overlay, arrow: toward the sensor", [(gt, GT_COLOR, 1.0), (spot, SPOTLIGHTS_COLOR, 2.0),
                                              (partial, PARTIAL_COLOR, 4.0)]),
    ]
    fig = plt.figure(figsize=(4.2 * len(panels), 4.6))
    for j, (title, layers) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), j + 1, projection="3d")
        for pts, color, size in layers:
            if len(pts):
                ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=size, color=color, depthshade=False, linewidths=0)
        if j == len(panels) - 1:
            ax.quiver(0, 0, 0, *(0.9 * to_sensor), color="black", arrow_length_ratio=0.15, linewidth=1.5)
        for setlim in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
            setlim(-1.0, 1.0)
        ax.set_box_aspect((1, 1, 1))
        ax.set_xlabel("x (forward)")
        ax.set_ylabel("y (left)")
        ax.set_zlabel("z")
        ax.view_init(elev=elev, azim=azim)
        ax.set_title(title, fontsize=9)
    fig.suptitle(f"{sample['model']} ({sample['category']}, {sample['split']}), view {sample['view']}: "
                 f"{sample.get('distance', float('nan')):.1f} m from the sensor, unit frame", fontsize=11)
    fig.tight_layout()
    with atomic_output(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return Path(path)
