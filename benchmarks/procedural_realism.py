"""How realistic are the procedural cars? Train on them, score on real cars, and the reverse.

Two datasets at the same small scale (the same rig, LiDAR and views per sample), two runs of the
default configuration (the dense hit-aware SA-Net: ``--model sanet-hit`` with
``configs/variants/sanet-hit-dense.yaml``) with the same schedule (``--schedule budget``: Adam 1e-3,
cosine to 5%, batch 32, seed 0; ``--epochs`` x ``--steps`` steps, one validation per epoch, one
torch thread), then both checkpoints scored by ``spotlights evaluate`` on both test splits:

* ``apollo``: the 79 ApolloScape cars, split 64/8/7, ``--apollo-views`` views each;
* ``procedural``: ``--procedural`` cars per class of ``car`` without pickups (ApolloScape holds
  none: sedan, hatchback, SUV, coupe, estate), split 0.8/0.1/0.1, as many training samples as
  ``apollo`` (``--apollo-views`` x 64 / the training cars' count views each).

The realism ratio is the procedural-trained model's accuracy on the ApolloScape test cars over the
ApolloScape-trained model's (the bar: <= 1.3). Every stage is skipped when its output exists, and
training resumes from its last epoch (checkpointed every epoch), so the script can be stopped and
run again. Datasets and weights go under ``--work`` (outside the repository); the numbers to
``--json``.

    nice -n 10 env OMP_NUM_THREADS=1 python benchmarks/procedural_realism.py --work ../runs-procedural \\
        --json docs/results/procedural/realism.json
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
APOLLO = ROOT.parent / "shared" / "data" / "meshes" / "apolloscape-cars"
CONFIG = ROOT / "src" / "spotlights" / "learning" / "configs" / "variants" / "sanet-hit-dense.yaml"
RIG = "box-128x128-ellipsoid-s1"


def cli(*args, log: Path, stage: str) -> None:
    """Run ``python -m spotlights ARGS`` (one thread); add its CPU seconds to ``stage`` in the work
    folder's cpu.json (summed over invocations: a resumed training adds its part)."""
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT / "src"))
    before = os.times()
    with open(log, "a") as fh:
        subprocess.run([sys.executable, "-m", "spotlights", *map(str, args)], check=True, env=env, stdout=fh, stderr=fh)
    after = os.times()
    cpu_file = log.parent / "cpu.json"
    cpu = json.loads(cpu_file.read_text()) if cpu_file.exists() else {}
    cpu[stage] = cpu.get(stage, 0.0) + (after.children_user - before.children_user)
    cpu[stage] += after.children_system - before.children_system
    cpu_file.write_text(json.dumps(cpu, indent=1))


def curve(run: Path) -> list[dict]:
    """The run's log.csv rows: epoch, global step, validation CD-L1 and accuracy, epoch seconds."""
    with open(run / "log.csv") as fh:
        return [
            {
                "epoch": int(r["epoch"]),
                "step": int(r["global_step"]),
                "val_chamfer_l1": float(r["val_chamfer_l1"]),
                "val_accuracy": float(r["val_accuracy"]),
                "seconds": float(r["epoch_seconds"]),
            }
            for r in csv.DictReader(fh)
        ]


def flattened(rows: list[dict], tail: int = 4) -> dict:
    """Whether the validation CD-L1 curve flattened: its best over the last ``tail`` epochs against
    the best before them (relative gain < 2%: flat)."""
    vals = [r["val_chamfer_l1"] for r in rows]
    if len(vals) <= tail:
        return {"flat": False, "gain_last_epochs": None}
    before, last = min(vals[:-tail]), min(vals[-tail:])
    gain = (before - last) / before
    return {"flat": bool(gain < 0.02), "gain_last_epochs": round(gain, 4), "epochs_compared": tail}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, required=True, help="folder for datasets and runs (outside the repository)")
    ap.add_argument("--json", type=Path, default=ROOT / "docs" / "results" / "procedural" / "realism.json")
    ap.add_argument("--procedural", type=int, default=384, help="procedural cars per class before pickups leave")
    ap.add_argument("--apollo-views", type=int, default=100)
    ap.add_argument("--epochs", type=int, default=18)
    ap.add_argument("--steps", type=int, default=100, help="optimizer steps per epoch (batch 32)")
    ap.add_argument(
        "--eval-views", type=int, default=100, help="views per test car scored (apollo; procedural: a quarter)"
    )
    args = ap.parse_args()
    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    log = work / "realism.log"
    n_train_proc = round(args.procedural * 5 / 6 * 0.8)
    proc_views = max(1, round(args.apollo_views * 64 / n_train_proc))
    data = {"apollo": work / "apollo.h5", "procedural": work / "proc_cars.h5"}
    common = ["--default-rig", RIG, "--workers", 1, "--seed", 0, "--quiet"]
    if not data["apollo"].exists():
        cli(
            "dataset", "build", "--meshes", APOLLO, "--views", args.apollo_views, "--out", data["apollo"], *common,
            log=log, stage="build_apollo",
        )  # fmt: skip
    if not data["procedural"].exists():
        cli(
            "dataset", "build", "--procedural", args.procedural, "--classes", "car", "--exclude-category", "pickup",
            "--procedural-split", "0.8/0.1/0.1", "--views", proc_views, "--out", data["procedural"], *common, log=log,
            stage="build_procedural",
        )  # fmt: skip
    views = {"apollo": args.apollo_views, "procedural": proc_views}
    runs = {}
    for name, path in data.items():
        run = work / f"train-{name}"
        runs[name] = run
        done = (run / "log.csv").exists() and len(curve(run)) >= args.epochs
        if not done:
            resume = ["--resume"] if (run / "last.pt").exists() else []
            cli(
                "train", "--model", "sanet-hit", "--schedule", "budget", "--config", CONFIG, "--data", path,
                "--epochs", args.epochs, "--steps-per-epoch", args.steps, "--max-views", views[name],
                "--val-max-views", 10 if name == "apollo" else 3, "--threads", 1, "--seed", 0, "--out", run,
                "--quiet", *resume, log=log, stage=f"train_{name}",
            )  # fmt: skip
    scores = {}
    for name, path in data.items():
        out = work / f"eval-{name}"
        if not out.with_suffix(".json").exists():
            mv = args.eval_views if name == "apollo" else max(1, args.eval_views // 4)
            cli(
                "evaluate", "--data", path, "--checkpoint", runs["apollo"] / "best.pt", runs["procedural"] / "best.pt",
                "--max-views", mv, "--threads", 1, "--examples", 0, "--out", out, "--quiet", log=log,
                stage=f"eval_{name}",
            )  # fmt: skip
        scores[name] = json.loads(out.with_suffix(".json").read_text())
    last = work / "eval-apollo-last"  # the same scoring of both runs' last.pt (equal steps, no selection)
    if not last.with_suffix(".json").exists():
        cli(
            "evaluate", "--data", data["apollo"], "--checkpoint", runs["apollo"] / "last.pt",
            runs["procedural"] / "last.pt", "--max-views", args.eval_views, "--threads", 1, "--examples", 0,
            "--out", last, "--quiet", log=log, stage="eval_apollo_last",
        )  # fmt: skip
    scores["apollo_last"] = json.loads(last.with_suffix(".json").read_text())
    cpu_file = work / "cpu.json"
    cpu = json.loads(cpu_file.read_text()) if cpu_file.exists() else {}
    write(args, scores, runs, cpu, views)


def write(args, scores: dict, runs: dict, cpu: dict, views: dict) -> None:
    """The results JSON: accuracy/completeness of both models on both test splits (means over the
    scans and per category), the ratios, each run's curve, training time and whether it flattened."""
    table = {}
    for split, report in scores.items():
        for trained, res in zip(("apollo", "procedural"), report["results"]):
            summ = res["rows"][0]["summary"]
            m = summ["mean_over_samples"]
            table[f"{trained}_on_{split}"] = {
                "accuracy": m["accuracy"],
                "completeness": m["completeness"],
                "chamfer_l1": m["chamfer_l1"],
                "scans": res["n_samples"],
                "accuracy_per_category": {c: v["accuracy"] for c, v in summ["per_category"].items()},
            }
    train = {}
    for name, run in runs.items():
        rows = curve(run)
        best = min(rows, key=lambda r: r["val_chamfer_l1"])  # best.pt: the project's selection by validation CD-L1
        train[name] = {
            "steps": rows[-1]["step"],
            "best_epoch": best["epoch"],
            "best_step": best["step"],
            "train_seconds_wall": round(sum(r["seconds"] for r in rows), 1),
            "views_per_car": views[name],
            "curve": rows,
            **flattened(rows),
        }
    acc = {k: v["accuracy"] for k, v in table.items()}
    r_last = acc["procedural_on_apollo_last"] / acc["apollo_on_apollo_last"]
    result = {
        "command": "nice -n 10 env OMP_NUM_THREADS=1 python benchmarks/procedural_realism.py --work WORK",
        "settings": {k: v for k, v in vars(args).items() if k not in ("work", "json")},
        "scores": table,
        "ratio_procedural_over_apollo_on_apollo_test": acc["procedural_on_apollo"] / acc["apollo_on_apollo"],
        "ratio_apollo_over_procedural_on_procedural_test": acc["apollo_on_procedural"]
        / acc["procedural_on_procedural"],
        "ratio_last_checkpoints_on_apollo_test": r_last,
        "bar": 1.3,
        "training": train,
        "cpu_seconds": {k: round(v, 1) for k, v in cpu.items()},
        "cpu_minutes_total": round(sum(cpu.values()) / 60, 1),
        "generated": time.strftime("%Y-%m-%d"),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1) + "\n")
    args.json.with_suffix(".md").write_text(markdown(result))
    print(args.json)


def markdown(result: dict) -> str:
    """The study's table: accuracy (completeness) of both models on both test splits, the ratios."""
    sc, tr = result["scores"], result["training"]
    lines = [
        "| trained on | steps (best.pt at) | curve flat (gain over the last 4 epochs) | ApolloScape test cars: accuracy"
        " / completeness | held-out procedural cars: accuracy / completeness |",
        "|---|---|---|---|---|",
    ]
    for name in ("apollo", "procedural"):
        a, p, t = sc[f"{name}_on_apollo"], sc[f"{name}_on_procedural"], tr[name]
        flat = f"{'yes' if t['flat'] else 'no'} ({100 * t['gain_last_epochs']:.1f}%)"
        lines.append(
            f"| {name} | {t['steps']} ({t['best_step']}) | {flat} | {a['accuracy']:.5f} / {a['completeness']:.5f} ({a['scans']} scans)"
            f" | {p['accuracy']:.5f} / {p['completeness']:.5f} ({p['scans']} scans) |"
        )
    r1 = result["ratio_procedural_over_apollo_on_apollo_test"]
    r2 = result["ratio_apollo_over_procedural_on_procedural_test"]
    la, lp = sc["apollo_on_apollo_last"], sc["procedural_on_apollo_last"]
    lines += ["", f"Ratio on the ApolloScape test cars (procedural-trained / ApolloScape-trained accuracy): **{r1:.2f}x** "
              f"(bar {result['bar']}x); on the held-out procedural cars (ApolloScape-trained / procedural-trained): {r2:.2f}x. "
              f"The last checkpoints (step {tr['apollo']['steps']} both) on the ApolloScape test cars: {la['accuracy']:.5f} / "
              f"{la['completeness']:.5f} (ApolloScape-trained) and {lp['accuracy']:.5f} / {lp['completeness']:.5f} "
              f"(procedural-trained): **{result['ratio_last_checkpoints_on_apollo_test']:.2f}x**."]  # fmt: skip
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
