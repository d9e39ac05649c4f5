"""The class models' result tables: per class, synthetic (``benchmarks/class_eval.py`` JSONs) and real (``real evaluate``
JSONs: inside the grown box before any clamp, fidelity, consistency at equal density), side by side per model.

    PYTHONPATH=src python3 scripts/class_tables.py --synthetic default.json classes.json \\
        --real nuscenes=default-nuscenes.json,classes-nuscenes.json av2=default-av2.json,classes-av2.json \\
        --out docs/results/classes/classes
"""

from __future__ import annotations

import argparse
import json


def fmt(x, d: int = 4) -> str:
    return "-" if x is None else f"{x:.{d}f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--synthetic", nargs="+", default=[])
    ap.add_argument("--real", nargs="+", default=[], metavar="NAME=A.json,B.json")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    out: dict = {"synthetic": {}, "real": {}}
    lines = ["# Per class results", ""]
    if a.synthetic:
        lines += [
            "## Synthetic (test split, unit frame, model output as it is)",
            "",
            "| group | scans (models) | "
            + " | ".join(
                f"{json.load(open(p))['results'][0]['checkpoint'].split('/')[-1]} acc / comp / inside"
                for p in a.synthetic
            )
            + " |",
            "|---|---|" + "---|" * len(a.synthetic),
        ]
        res = [json.load(open(p))["results"][0] for p in a.synthetic]
        for g in res[0]["groups"]:
            v0 = res[0]["groups"][g]
            cells = []
            for r in res:
                v = r["groups"].get(g)
                cells.append(
                    "-"
                    if v is None
                    else f"{fmt(v['accuracy'], 5)} / {fmt(v['completeness'], 5)} / {100 * v['inside']:.1f}%"
                )
            lines.append(f"| {g} | {v0['n']} ({v0['models']}) | " + " | ".join(cells) + " |")
            out["synthetic"][g] = {r["checkpoint"]: r["groups"].get(g) for r in res}
        lines.append("")
    for spec in a.real:
        name, files = spec.split("=", 1)
        reps = [json.load(open(p)) for p in files.split(",")]
        models = [m for rep in reps for m in rep["models"]]
        classes = list(models[0]["classes"])
        lines += [
            f"## Real: {name} (per class; inside = share of raw completion points inside box + 0.15 m, before any "
            "clamp; fidelity unit frame; consistency CD at equal density, voxel 0.1)",
            "",
            "| class | objects | " + " | ".join(f"{m['name']} inside / fidelity / CD@voxel" for m in models) + " |",
            "|---|---|" + "---|" * len(models),
        ]
        out["real"][name] = {}
        for c in classes:
            cells = []
            for m in models:
                cc = m["classes"].get(c) or {}
                ed = (m.get("equal_density") or {}).get("classes", {}).get(c) or {}
                ins = (m.get("inside_box") or {}).get(c)
                cells.append(
                    f"{'-' if ins is None else f'{100 * ins:.1f}%'} / {fmt(cc.get('fidelity'))} / {fmt(ed.get('cd'))}"
                )
                out["real"][name].setdefault(c, {})[m["name"]] = {
                    "inside_box": ins,
                    "fidelity": cc.get("fidelity"),
                    "cd_equal_density": ed.get("cd"),
                    "n_objects": cc.get("n_objects"),
                }
            n = (models[0]["classes"].get(c) or {}).get("n_objects")
            lines.append(f"| {c} | {n} | " + " | ".join(cells) + " |")
        lines.append("")
    with open(a.out + ".md", "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    with open(a.out + ".json", "w", encoding="utf-8") as f:
        json.dump(out, f, indent=1)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
