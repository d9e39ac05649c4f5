"""A picture sheet of every object of some classes in a real observation file: per object (its
observation with the most points), the observed points and each checkpoint's completion in the box's unit
frame, with the box grown by 0.15 m drawn as dots; titles give the object's size and each completion's share
of points inside the grown box before the clamp.

    PYTHONPATH=src python3 scripts/class_sheet.py nuscenes.h5 --classes truck,bus,trailer \\
        --checkpoint default run/best.pt --names default classes --out docs/results/classes/scene0523_sheet.png

``--projections``: instead of the 3-D views, each completion seen from the side (x-z) and from above (x-y) in the
box frame, metres, with the observed points (purple) and the box (dotted): profiles that a perspective view hides
(a body raised over its wheels, a flat roof, square ends).
"""

from __future__ import annotations

import argparse
import io
import itertools

import numpy as np

from spotlights.data.real.extract import read_observations
from spotlights.geometry.box_clamp import grown_half_extents
from spotlights.learning.inference import complete_in_boxes, load_completer
from spotlights.viz.grid import render_cloud_grid


def box_dots(half: np.ndarray, n: int = 24) -> np.ndarray:
    """(12 n, 3) points along the 12 edges of the box ``[-half, half]``."""
    t = np.linspace(-1.0, 1.0, n)
    out = []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        for s1, s2 in itertools.product((-1.0, 1.0), repeat=2):
            p = np.zeros((n, 3))
            p[:, axis] = t * half[axis]
            p[:, others[0]] = s1 * half[others[0]]
            p[:, others[1]] = s2 * half[others[1]]
            out.append(p)
    return np.concatenate(out)


def draw_projections(out, obs, rows_i, classes, sizes, names, comps, dpi: int) -> None:
    """One row per object: for each checkpoint its completion from the side (x-z) and from above (x-y), box frame,
    metres, the observed points in purple, the box dotted (``out``: a PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ncol = 2 * len(names)
    fig, axes = plt.subplots(len(rows_i), ncol, figsize=(3.2 * ncol, 1.5 * len(rows_i)), squeeze=False)
    for j, i in enumerate(rows_i):
        size = np.asarray(sizes[j], dtype=np.float64)
        r = float(np.linalg.norm(size)) / 2
        seen = np.asarray(obs.partial[i], dtype=np.float64) * r
        for k, (name, (done, inside)) in enumerate(zip(names, comps)):
            pts = np.asarray(done[j], dtype=np.float64) * r
            for v, (a0, a1, view) in enumerate(((0, 2, "side"), (0, 1, "top"))):
                ax = axes[j, 2 * k + v]
                ax.scatter(pts[:, a0], pts[:, a1], s=0.05, c="#1f77b4", rasterized=True)
                ax.scatter(seen[:, a0], seen[:, a1], s=1.5, c="#7b2cbf")
                ax.add_patch(
                    plt.Rectangle((-size[a0] / 2, -size[a1] / 2), size[a0], size[a1], fill=False, ls=":", lw=0.6)
                )
                ax.set_aspect("equal")
                ax.tick_params(labelsize=4)
                ls = " x ".join(f"{v:.1f}" for v in size)
                ax.set_title(
                    f"{classes[j]} {obs.track_id[i][:6]} {ls} m, {obs.n_points_raw[i]} pts; {name} {view}, "
                    f"{100 * inside[j]:.0f}% in",
                    fontsize=4.5,
                )
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi * 2)
    plt.close(fig)
    from PIL import Image  # a 32-colour palette: a fifth of the bytes of the full-colour page, the same picture

    Image.open(buf).convert("RGB").quantize(colors=32).save(out, optimize=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("observations")
    ap.add_argument("--classes", default="truck,bus,trailer")
    ap.add_argument("--checkpoint", nargs="+", default=["default"])
    ap.add_argument("--names", nargs="+", default=None)
    ap.add_argument("--per-row", type=int, default=2)
    ap.add_argument("--dpi", type=int, default=45)
    ap.add_argument("--out", required=True)
    ap.add_argument("--projections", action="store_true", help="side and top views in metres instead of 3-D views")
    a = ap.parse_args()
    obs = read_observations(a.observations)
    want = a.classes.split(",")
    best: dict = {}
    for i, (seq, tid, c) in enumerate(zip(obs.sequence, obs.track_id, obs.cls)):
        if c in want and tid:
            k = (c, seq, tid)
            if k not in best or obs.n_points_raw[i] > obs.n_points_raw[best[k]]:
                best[k] = i
    keys = sorted(best, key=lambda k: (want.index(k[0]), -float(obs.box_size[best[k]][0])))
    rows_i = np.array([best[k] for k in keys])
    partials, sizes = obs.partial[rows_i], obs.box_size[rows_i]
    classes = [obs.cls[i] for i in rows_i]
    names = a.names or a.checkpoint
    comps = []
    for ck in a.checkpoint:
        c = load_completer(ck, device="cpu")
        inside: list = []
        done = complete_in_boxes(c, partials, sizes, classes=classes, inside=inside)
        comps.append((done, inside))
    if a.projections:
        draw_projections(a.out, obs, rows_i, classes, sizes, names, comps, a.dpi)
        print(f"{len(rows_i)} objects -> {a.out}")
        return
    panels = []
    for j, i in enumerate(rows_i):
        half = grown_half_extents(sizes[j])
        frame = (box_dots(half), "#999999", 0.6)
        ls = " x ".join(f"{v:.1f}" for v in sizes[j])
        panels.append(
            (
                f"{classes[j]} {obs.track_id[i][:6]}\n{ls} m, {obs.n_points_raw[i]} pts",
                [frame, (obs.partial[i], "#7b2cbf", 2.0)],
            )
        )
        for name, (done, inside) in zip(names, comps):
            panels.append((f"{name}: {100 * inside[j]:.0f}% inside", [frame, (done[j], "#1f77b4", 0.4)]))
    per = 1 + len(a.checkpoint)
    rows = [panels[k : k + per * a.per_row] for k in range(0, len(panels), per * a.per_row)]
    render_cloud_grid(
        a.out,
        rows,
        f"{a.observations.split('/')[-1]}: every {', '.join(want)} (unit frame, box + 0.15 m dotted)",
        limit=1.0,
        dpi=a.dpi,
    )
    print(f"{len(rows_i)} objects -> {a.out}")


if __name__ == "__main__":
    main()
