"""Pictures of Spotlights encodings: the decoded ordered point cloud, coloured by viewpoint."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..geometry.encode import decode
from .points import Layer, render_layers


def encoding_layers(encoding, clip: float | None = None, size: float = 3.0) -> tuple[list[Layer], np.ndarray]:
    """The decoded hits of an encoding as one layer coloured by viewpoint index, and the (n_rays,) hit mask.

    Points are in the unit frame; the colour bar reads "viewpoint index" (0 .. N-1): every
    viewpoint's bundle of rays lands as one patch of one colour.
    """
    rig = encoding.rig
    pts, mask = decode(encoding.depths, rig, clip)
    view_id = np.repeat(np.arange(rig.n_primary), rig.n_secondary)
    layer = Layer(
        pts[mask],
        view_id[mask].astype(np.float64),
        None,
        size,
        0.95,
        cmap="turbo",
        vmin=0.0,
        vmax=float(max(rig.n_primary - 1, 1)),
        colorbar=f"viewpoint index (the {rig.n_secondary} rays of a viewpoint share its colour)",
    )
    return [layer], mask


def render_encoding(path: str | os.PathLike, encoding, title: str | None = None, clip: float | None = None) -> Path:
    """Picture of an encoding's ordered point cloud (unit frame), coloured by viewpoint index, with a colour bar.

    Colouring by viewpoint shows the structure of the representation: each
    viewpoint's bundle of rays lands as one patch.
    """
    layers, mask = encoding_layers(encoding, clip)
    rig = encoding.rig
    ttl = title or (
        f"{rig.name}: {int(mask.sum())}/{rig.n_rays} rays hit ({mask.mean():.1%}), unit frame, colour = viewpoint"
    )
    return render_layers(path, layers, title=ttl)


def viewpoint_rays(encoding, index: int, clip: float | None = None) -> dict[str, np.ndarray]:
    """One viewpoint's ray bundle as segments in the unit frame.

    Returns ``origin`` (3,), ``hit_start``/``hit_end`` (H, 3) for rays that hit (origin to the
    surface) and ``miss_start``/``miss_end`` (M, 3) for rays that miss (origin to where
    they leave the unit sphere), H + M = n_secondary.
    """
    rig = encoding.rig
    if not 0 <= index < rig.n_primary:
        raise ParameterError(
            f"viewpoint {index} out of range: the rig has {rig.n_primary} viewpoints (0-{rig.n_primary - 1})"
        )
    m = rig.n_secondary
    o = rig.origins.reshape(rig.n_primary, m, 3)[index].astype(np.float64)
    d = rig.directions.reshape(rig.n_primary, m, 3)[index].astype(np.float64)
    pts, mask = decode(encoding.depths, rig, clip)
    pts = pts.reshape(rig.n_primary, m, 3)[index]
    hit = mask.reshape(rig.n_primary, m)[index]
    # a miss crosses the unit sphere: it leaves at t = -2 o.d (origins on the sphere)
    t_out = np.clip(-2.0 * np.einsum("ij,ij->i", o, d), 0.0, 2.0)
    miss_end = o + d * t_out[:, None]
    return {
        "origin": rig.primary[index].astype(np.float64),
        "hit_start": o[hit],
        "hit_end": pts[hit].astype(np.float64),
        "miss_start": o[~hit],
        "miss_end": miss_end[~hit],
    }
