"""The paper's qualitative figure on real scans: raw scan (grey), partial input (purple), completion (green).

Everything is drawn back in the **sensor frame** of the scan: partials and
completions are mapped from their unit frames with each observation's
``unit_to_sensor`` transform. Left: a bird's-eye view of the scan around the
objects (points subsampled, boxes outlined). Right: a 3D close-up of each
object, seen from the sensor's side (as the LiDAR saw it), with the raw points
within 1 m of its box.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ...errors import InputFileError, ParameterError
from .extract import Observations

GREY, PURPLE, GREEN = "#9a9a9a", "#8e44ad", "#27ae60"


def to_sensor(points_unit: np.ndarray, unit_to_sensor: np.ndarray) -> np.ndarray:
    """(K, 3) unit-frame points -> (K, 3) float64 sensor frame, with a (4, 4) unit->sensor matrix."""
    p = np.asarray(points_unit, dtype=np.float64).reshape(-1, 3)
    return p @ unit_to_sensor[:3, :3].T + unit_to_sensor[:3, 3]


def frame_rows(obs: Observations, sequence: str | None = None, frame_id: str | None = None) -> list[int]:
    """Rows of one frame. Default frame: the one with the most observations (first in file order on ties)."""
    frames: dict[tuple[str, str], list[int]] = {}
    for i, key in enumerate(zip(obs.sequence, obs.frame_id)):
        frames.setdefault(key, []).append(i)
    if not frames:
        raise ParameterError("the observation file is empty: nothing to show")
    if frame_id is None:
        cands = [k for k in frames if sequence is None or k[0] == sequence]
        if not cands:
            raise ParameterError(f"no frame of sequence {sequence!r} in the file")
        key = max(cands, key=lambda k: len(frames[k]))
        return frames[key]
    cands = [k for k in frames if k[1] == frame_id and (sequence is None or k[0] == sequence)]
    if not cands:
        known = ", ".join(sorted({f for _, f in frames})[:8])
        raise ParameterError(f"frame {frame_id!r} has no observation in the file (frames: {known}{', ...' if len(frames) > 8 else ''})")
    if len(cands) > 1:
        raise ParameterError(f"frame {frame_id!r} exists in several sequences ({', '.join(k[0] for k in cands)}); give --sequence")
    return frames[cands[0]]


def _box_outline(center, size, rotation) -> np.ndarray:
    """(5, 2) closed bird's-eye outline of a box (x, y in the sensor frame)."""
    l, w = size[0] / 2, size[1] / 2
    c = np.array([[l, w, 0], [l, -w, 0], [-l, -w, 0], [-l, w, 0], [l, w, 0]])
    return (c @ rotation.T + center)[:, :2]


def render_frame(
    path: str | os.PathLike,
    obs: Observations,
    rows: Sequence[int],
    completions: Sequence[np.ndarray] | None = None,
    scan: np.ndarray | None = None,
    title: str | None = None,
    max_scan_points: int = 40000,
    seed: int = 0,
    dpi: int = 110,
) -> Path:
    """Draw one frame's observations into a PNG (atomic write).

    Parameters
    ----------
    obs, rows : the observations and the rows to draw (all of one scan).
    completions : one (K_i, 3) unit-frame array per row, or None (no green).
    scan : (N, 3) raw scan in the sensor frame, or None to read ``obs.scan_path`` of the first row.
    max_scan_points : grey points drawn at most in the bird's-eye view (random subset, seeded).
    """
    from ...utils import atomic_output
    from ...viz import _pyplot
    from . import read_scan

    rows = list(rows)
    if not rows:
        raise ParameterError("no observation to draw")
    if scan is None:
        sp = obs.scan_path[rows[0]]
        if not Path(sp).is_file():
            raise InputFileError(sp, "raw scan not found (moved since extraction?)")
        scan = read_scan(sp)
    scan = np.asarray(scan, dtype=np.float64)
    partial_s = [to_sensor(obs.partial[i], obs.unit_to_sensor[i]) for i in rows]
    comp_s = [to_sensor(c, obs.unit_to_sensor[i]) for c, i in zip(completions, rows)] if completions is not None else None

    centers = obs.box_center[rows]
    reach = 0.5 * np.linalg.norm(obs.box_size[rows], axis=1)
    lo = (centers[:, :2] - reach[:, None]).min(axis=0) - 8.0
    hi = (centers[:, :2] + reach[:, None]).max(axis=0) + 8.0
    lo = np.minimum(lo, -3.0)  # keep the sensor in view
    hi = np.maximum(hi, 3.0)
    in_view = np.all((scan[:, :2] >= lo) & (scan[:, :2] <= hi), axis=1)
    bev = scan[in_view]
    if len(bev) > max_scan_points:
        bev = bev[np.sort(np.random.default_rng(seed).choice(len(bev), max_scan_points, replace=False))]

    plt = _pyplot()
    n_obj = len(rows)
    ncol = min(3, n_obj)
    nrow = math.ceil(n_obj / ncol)
    fig = plt.figure(figsize=(7.0 + 3.8 * ncol, max(6.5, 3.8 * nrow)))
    gs = fig.add_gridspec(nrow, ncol + 2)
    ax = fig.add_subplot(gs[:, :2])
    ax.scatter(bev[:, 0], bev[:, 1], s=0.4, color=GREY, linewidths=0, label="raw scan")
    for k, i in enumerate(rows):
        ol = _box_outline(obs.box_center[i], obs.box_size[i], obs.box_rotation[i])
        ax.plot(ol[:, 0], ol[:, 1], color="black", lw=0.6)
        if comp_s is not None:
            ax.scatter(comp_s[k][:, 0], comp_s[k][:, 1], s=1.2, color=GREEN, linewidths=0, label="completion" if k == 0 else None)
        ax.scatter(partial_s[k][:, 0], partial_s[k][:, 1], s=2.5, color=PURPLE, linewidths=0, label="partial input" if k == 0 else None)
        ax.annotate(str(k + 1), obs.box_center[i, :2] + reach[k] * 0.6, fontsize=8)
    ax.plot([0], [0], marker="^", color="black", ms=6)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, sensor frame)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper right", fontsize=8, markerscale=5)
    ax.set_title("bird's-eye view")

    for k, i in enumerate(rows):
        a3 = fig.add_subplot(gs[k // ncol, 2 + k % ncol], projection="3d")
        c = obs.box_center[i]
        near = scan[np.sum((scan - c) ** 2, axis=1) <= (reach[k] + 1.0) ** 2]
        r = reach[k] + 0.3
        layers = [(near, GREY, 0.8)]
        if comp_s is not None:
            layers.append((comp_s[k], GREEN, 2.0))
        layers.append((partial_s[k], PURPLE, 4.0))
        for p, col, s in layers:
            if len(p):
                a3.scatter(p[:, 0], p[:, 1], p[:, 2], s=s, color=col, linewidths=0, depthshade=False)
        a3.set_xlim(c[0] - r, c[0] + r)
        a3.set_ylim(c[1] - r, c[1] + r)
        a3.set_zlim(c[2] - r, c[2] + r)
        a3.set_box_aspect((1, 1, 1), zoom=1.35)
        azim = math.degrees(math.atan2(c[1], c[0])) + 180.0  # look from the sensor's side
        a3.view_init(elev=20, azim=azim)
        a3.set_axis_off()
        a3.set_title(f"{k + 1}: {obs.cls[i]} ({obs.label[i]}), {int(obs.n_points_raw[i])} pts", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_output(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return Path(path)
