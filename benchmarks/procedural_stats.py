"""Shape statistics of the procedural vehicles against the real meshes, per class and body type.

For every procedural body type (``--per-body`` seeds each) and every real mesh (the ApolloScape
cars in metres; the Kenney vehicles at the packaged manifest's scale 1.8, toys whose absolute
sizes mean little, so compare their ratios): the box's length, width and height (m), the height
over the length, and the **roof line**: the height of the top surface (first hit of a ray straight
down at y = 0, or at y = +-W/4 where y = 0 misses) at 9 stations from 10% to 90% of the length
from the front, as a fraction of the box height; the share of side rays (at 0.8 of the height,
through the middle 30% of the length) that go more than 0.25 m into the box (open windows), and the
median height of the underside at y = 0. Per group: quantiles (min, 10%, median, 90%, max), the
mean roof line, the mean deep-ray share and how many meshes let more than half of them in, the
median underside height. Also the generation speed (process CPU time of ``generate_vehicle``,
one thread: run it with ``OMP_NUM_THREADS=1``) per body type. Writes ``--json`` and the Markdown
table of ``--markdown``.

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/procedural_stats.py --json docs/results/procedural/shape_stats.json \\
        --markdown docs/results/procedural/shape_stats.md
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np

from spotlights.data.synthetic.procedural import BODY_TYPES, CLASS_BODIES, generate_vehicle
from spotlights.data.vehicle_classes import class_of_category
from spotlights.geometry.io import load_mesh
from spotlights.geometry.raycast import RayCaster

ROOT = Path(__file__).resolve().parents[1]
MESHES = ROOT.parent / "shared" / "data" / "meshes"
KENNEY_MANIFEST = ROOT / "src" / "spotlights" / "assets" / "manifests" / "kenney-vehicles.csv"
STATIONS = np.linspace(0.1, 0.9, 9)  # fractions of the length from the front


def measure(v: np.ndarray, f: np.ndarray) -> dict:
    """Box (length, width, height, m) and roof line (fractions of the height) of a mesh in the
    object frame (x forward, y left, z up)."""
    lo, hi = v.min(0), v.max(0)
    size = hi - lo
    xs = hi[0] - STATIONS * size[0]
    caster = RayCaster(v, f)
    z_top = np.full(len(xs), np.nan)
    for y in (0.0, 0.25 * size[1], -0.25 * size[1]):
        o = np.column_stack([xs, np.full(len(xs), (lo[1] + hi[1]) / 2 + y), np.full(len(xs), hi[2] + 1.0)])
        t, face = caster.first_hit(o, np.tile([0.0, 0.0, -1.0], (len(xs), 1)))
        z = hi[2] + 1.0 - t
        fill = np.isnan(z_top) & (face >= 0)
        z_top[fill] = z[fill]
    # side rays (along -y) at 0.8 of the height through the middle 30% of the length: how many go
    # more than 0.25 m into the box (through a window with no glass, or a deep recess)
    xs = np.linspace(lo[0] + 0.35 * size[0], lo[0] + 0.65 * size[0], 20)
    o = np.column_stack([xs, np.full(20, hi[1] + 1.0), np.full(20, lo[2] + 0.8 * size[2])])
    t, face = caster.first_hit(o, np.tile([0.0, -1.0, 0.0], (20, 1)))
    deep = np.where(face >= 0, t - 1.0, np.inf) > 0.25
    # the underside at y = 0 (rays up from below over 10-90% of the length): its median height (m)
    xs = np.linspace(lo[0] + 0.1 * size[0], hi[0] - 0.1 * size[0], 30)
    o = np.column_stack([xs, np.full(30, (lo[1] + hi[1]) / 2), np.full(30, lo[2] - 1.0)])
    t, face = caster.first_hit(o, np.tile([0.0, 0.0, 1.0], (30, 1)))
    under = np.where(face >= 0, t - 1.0, np.nan)
    return {
        "length": float(size[0]),
        "width": float(size[1]),
        "height": float(size[2]),
        "roof": ((z_top - lo[2]) / size[2]).tolist(),
        "side_rays_deep": float(deep.mean()),
        "underside": float(np.nanmedian(under)) if np.isfinite(under).any() else float("nan"),
    }


def real_meshes() -> list[tuple[str, str, str, dict]]:
    """(source, class, category, measures) of every real vehicle mesh found under the shared data."""
    out = []
    apollo = MESHES / "apolloscape-cars"
    if (apollo / "manifest.csv").exists():
        for row in csv.DictReader(open(apollo / "manifest.csv")):
            m = load_mesh(apollo / row["file"], up="z", forward="x")
            out.append(("apolloscape", "car", row["category"], measure(np.asarray(m.vertices), np.asarray(m.faces))))
    kenney = MESHES / "kenney-vehicles"
    if kenney.exists():
        for row in csv.DictReader(open(KENNEY_MANIFEST)):
            cls = class_of_category(row["category"])
            if cls == "other":
                continue
            m = load_mesh(kenney / row["file"], up=row["up"], forward=row["forward"])
            v = np.asarray(m.vertices) * float(row["scale"])
            out.append(("kenney", cls, row["category"], measure(v, np.asarray(m.faces))))
    return out


def summarise(items: list[dict]) -> dict:
    """Quantiles of length, width, height, height / length and the mean roof line of ``items``."""
    res = {"n": len(items)}
    for key in ("length", "width", "height"):
        x = np.array([it[key] for it in items])
        res[key] = {
            q: round(float(np.quantile(x, p)), 3)
            for q, p in (("min", 0), ("p10", 0.1), ("median", 0.5), ("p90", 0.9), ("max", 1))
        }
    hl = np.array([it["height"] / it["length"] for it in items])
    res["height_over_length"] = {"median": round(float(np.median(hl)), 3)}
    roof = np.array([it["roof"] for it in items], dtype=np.float64)
    res["roof_line"] = [round(float(x), 3) for x in np.nanmean(roof, axis=0)]
    deep = np.array([it["side_rays_deep"] for it in items])
    res["side_rays_deeper_than_25cm"] = {
        "mean": round(float(deep.mean()), 3),
        "meshes_over_half": int((deep > 0.5).sum()),
    }
    res["underside_median_m"] = round(float(np.nanmedian([it["underside"] for it in items])), 3)
    return res


def markdown(stats: dict) -> str:
    """One table: a row per group (class / source or body), median and 10-90% of L, W, H, and
    the mean roof line at 10%, 30%, 50%, 70%, 90% of the length."""
    lines = [
        "| group | n | length m: median (10-90%) | width m | height m | H/L | roof line at 10/30/50/70/90% (x H) "
        "| side rays > 25 cm in (meshes > half) | underside m |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in stats.items():
        cells = [f"{s[k]['median']:.2f} ({s[k]['p10']:.2f}-{s[k]['p90']:.2f})" for k in ("length", "width", "height")]
        roof = " / ".join(f"{s['roof_line'][i]:.2f}" for i in (0, 2, 4, 6, 8))
        deep = s["side_rays_deeper_than_25cm"]
        lines.append(
            f"| {name} | {s['n']} | {' | '.join(cells)} | {s['height_over_length']['median']:.3f} | {roof} "
            f"| {deep['mean']:.2f} ({deep['meshes_over_half']}) | {s['underside_median_m']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-body", type=int, default=100, help="procedural seeds per body type (0..N-1)")
    ap.add_argument("--json", type=Path, default=ROOT / "docs" / "results" / "procedural" / "shape_stats.json")
    ap.add_argument("--markdown", type=Path, default=None)
    args = ap.parse_args()
    proc, speed = {}, {}
    generate_vehicle("sedan", 0)  # imports (scipy's interpolator) outside the timing
    for body in BODY_TYPES:
        t0 = time.process_time()
        meshes = [generate_vehicle(body, s)[:2] for s in range(args.per_body)]
        dt = time.process_time() - t0
        speed[body] = {
            "bodies_per_second": round(args.per_body / dt, 1),
            "vertices_median": int(np.median([len(v) for v, _ in meshes])),
            "faces_median": int(np.median([len(f) for _, f in meshes])),
        }
        proc[body] = [measure(v, f) for v, f in meshes]
    total = sum(args.per_body / s["bodies_per_second"] for s in speed.values())
    real = real_meshes()
    stats = {}
    for cls, bodies in CLASS_BODIES.items():
        stats[f"{cls} / procedural"] = summarise([it for b in bodies for it in proc[b]])
        for src in ("apolloscape", "kenney"):
            items = [m for s, c, _, m in real if s == src and c == cls]
            if items:
                stats[f"{cls} / {src}"] = summarise(items)
    for body in BODY_TYPES:
        stats[f"{body} (procedural)"] = summarise(proc[body])
        items = [m for s, _, cat, m in real if s == "apolloscape" and cat == body]
        if items:
            stats[f"{body} (apolloscape)"] = summarise(items)
    out = {
        "command": "OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/procedural_stats.py",
        "per_body": args.per_body,
        "stations": STATIONS.round(2).tolist(),
        "kenney_scale": 1.8,
        "generation_one_core": {
            "bodies_per_second_all_types": round(len(BODY_TYPES) * args.per_body / total, 1),
            "per_body": speed,
        },
        "groups": stats,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=1) + "\n")
    if args.markdown:
        args.markdown.write_text(markdown(stats))
    print(args.json)


if __name__ == "__main__":
    main()
