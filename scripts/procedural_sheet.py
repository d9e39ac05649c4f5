"""A sheet of procedural vehicles beside real meshes of the same body (docs/dataset.md, "Procedural vehicles").

    PYTHONPATH=src python3 scripts/procedural_sheet.py --out docs/results/procedural_sheet.png
    PYTHONPATH=src python3 scripts/procedural_sheet.py --bodies box_truck,articulated_truck,trailer_box,trailer_flatbed \
        --per-body 6 --out docs/results/classes/procedural_long_short.png

Rows: the body types of spotlights.data.synthetic.procedural; columns: generated vehicles
(seeds 0..N-1) and, where the shared data holds one, a real mesh of that body (ApolloScape car
or Kenney vehicle, in metres). One scale per row (the row's largest box), so sizes compare
within a row; every panel is seen from the front left (elevation 20 deg, azimuth -60 deg).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from spotlights.data.synthetic.procedural import BODY_TYPES, generate_vehicle
from spotlights.geometry.io import load_mesh
from spotlights.viz._figure import new_figure, save_png
from spotlights.viz.raster import shade_mesh

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "meshes"
# body -> (file under MESHES, up, forward, scale): a real mesh of that body where one exists
REAL = {
    "sedan": ("apolloscape-cars/sedan/aodi-a6.ply", "z", "x", 1.0),
    "hatchback": ("apolloscape-cars/hatchback/baojun-310-2017.ply", "z", "x", 1.0),
    "suv": ("apolloscape-cars/suv/019-SUV.ply", "z", "x", 1.0),
    "coupe": ("kenney-vehicles/sedan-sports.glb", "y", "z", 1.8),
    "pickup": ("kenney-vehicles/truck.glb", "y", "z", 1.8),
    "van": ("kenney-vehicles/van.glb", "y", "z", 1.8),
    "minibus": ("kenney-vehicles/ambulance.glb", "y", "z", 1.8),
    "box_truck": ("kenney-vehicles/garbage-truck.glb", "y", "z", 1.8),
}


def real_mesh(body: str):
    """(vertices, faces, label) of the real mesh of ``body``, or None."""
    if body not in REAL:
        return None
    rel, up, fwd, scale = REAL[body]
    path = MESHES / rel
    if not path.exists():
        cands = sorted(path.parent.glob("*" + path.suffix)) if path.parent.exists() else []
        if not cands:
            return None
        path = cands[0]
    m = load_mesh(path, up=up, forward=fwd)
    v = np.asarray(m.vertices, dtype=np.float64) * scale
    used = np.unique(m.faces)
    return v[used], np.searchsorted(used, np.asarray(m.faces)), f"{path.parent.name}/{path.stem}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/results/procedural_sheet.png")
    ap.add_argument("--per-body", type=int, default=4)
    ap.add_argument("--bodies", default=",".join(BODY_TYPES), help="comma-separated body types, one row each")
    args = ap.parse_args()
    bodies = args.bodies.split(",")
    n = args.per_body
    cols = n + 1
    fig = new_figure(2.6 * cols, 1.6 * len(bodies), layout=None)
    fig.subplots_adjust(0.01, 0.01, 0.99, min(0.955, 1 - 0.5 / (1.6 * len(bodies))), 0.02, 0.25)
    elev, azim = 20.0, -60.0
    for r, body in enumerate(bodies):
        meshes = []
        for s in range(n):
            v, f, p = generate_vehicle(body, s)
            meshes.append((v, f, f"{body} {p.length:.1f}x{p.width:.2f}x{p.height:.2f}"))
        real = real_mesh(body)
        if real is not None:
            v, f, label = real
            size = v.max(0) - v.min(0)
            meshes.append((v, f, f"real: {label} {size[0]:.1f}x{size[1]:.2f}x{size[2]:.2f}"))
        half = max(float(v.max(0)[0] - v.min(0)[0]) for v, _, _ in meshes) / 2
        for c, (v, f, label) in enumerate(meshes):
            ax = fig.add_subplot(len(bodies), cols, r * cols + c + 1)
            centre = (v.min(0) + v.max(0)) / 2
            rgba, extent = shade_mesh(v - centre, f, elev, azim, size=320, center=np.zeros(3), half=half)
            ax.imshow(rgba, extent=extent, interpolation="antialiased", origin="upper")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(label, fontsize=6.5, color="#8b0000" if label.startswith("real") else "black")
            for sp in ax.spines.values():
                sp.set_visible(False)
    fig.suptitle(f"procedural vehicles (seeds 0-{n - 1} per body) and a real mesh of the body (red title)", fontsize=9)
    save_png(fig, args.out, dpi=100, deterministic=True)
    print(args.out)


if __name__ == "__main__":
    main()
