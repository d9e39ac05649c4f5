"""Per class, per model: inside-box share, fidelity and consistency at equal density, from ``real evaluate`` reports.

Reads the ``PREFIX.json`` reports of ``spotlights real evaluate`` (one per real set, every model of the comparison
scored in it) and writes what the studies quote: for each set (the report's file name), model and class, the
tracked objects, the share of the network's points inside the box grown by 0.15 m before any clamp
(``inside_box``), fidelity (unit frame) and consistency at equal density (CD at voxel 0.1, unit frame). Made for
docs/studies/one-model.md::

    spotlights real extract ../shared/data/lidar/nuscenes --format nuscenes \\
        --classes car,truck,caravan,trailer,bus,construction,emergency --out nuscenes.h5   # and argoverse2 / av2
    spotlights real evaluate nuscenes.h5 --checkpoint default classes RUN1/best.pt RUN2/best.pt \\
        --names default classes first-run second-run --no-noise-floor --no-heading-check --out nuscenes
    python benchmarks/real_classes.py nuscenes.json av2.json --json docs/results/models/one_model_real.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def summary(report: dict) -> dict:
    """{model name: {class: {objects, inside_box, fidelity, consistency_voxel}}} of one ``real evaluate`` report."""
    out = {}
    for m in report["models"]:
        voxel = (m.get("equal_density") or {}).get("classes", {})
        out[m["name"]] = {
            c: {
                "objects": v["n_objects"],
                "inside_box": round(float(m["inside_box"][c]), 4),
                "fidelity": round(float(v["fidelity"]), 5),
                "consistency_voxel": round(float(voxel[c]["cd"]), 5) if c in voxel else None,
            }
            for c, v in m["classes"].items()
        }
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("reports", nargs="+", type=Path, help="real evaluate PREFIX.json files, one per set")
    p.add_argument("--json", type=Path, required=True)
    a = p.parse_args()
    result = {r.stem: summary(json.loads(r.read_text())) for r in a.reports}
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(result, indent=1) + "\n")
    for s, models in result.items():
        for name, classes in models.items():
            print(s, name, {c: (v["inside_box"], v["fidelity"], v["consistency_voxel"]) for c, v in classes.items()})


if __name__ == "__main__":
    main()
