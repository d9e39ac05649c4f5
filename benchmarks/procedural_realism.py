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


def cli(*args, log: Path) -> float:
    """Run ``python -m spotlights ARGS`` (one thread); return its CPU seconds (children included)."""
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT / "src"))
    before = os.times()
    with open(log, "a") as fh:
        subprocess.run([sys.executable, "-m", "spotlights", *map(str, args)], check=True, env=env, stdout=fh, stderr=fh)
    after = os.times()
    return (after.children_user - before.children_user) + (after.children_system - before.children_system)


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
    cpu = {}
    n_train_proc = round(args.procedural * 5 / 6 * 0.8)
    proc_views = max(1, round(args.apollo_views * 64 / n_train_proc))
    data = {"apollo": work / "apollo.h5", "procedural": work / "proc_cars.h5"}
    common = ["--default-rig", RIG, "--workers", 1, "--seed", 0, "--quiet"]
    if not data["apollo"].exists():
        cpu["build_apollo"] = cli("dataset", "build", "--meshes", APOLLO, "--views", args.apollo_views,
                                  "--out", data["apollo"], *common, log=log)  # fmt: skip
    if not data["procedural"].exists():
        cpu["build_procedural"] = cli(
            "dataset", "build", "--procedural", args.procedural, "--classes", "car", "--exclude-category", "pickup",
            "--procedural-split", "0.8/0.1/0.1", "--views", proc_views, "--out", data["procedural"], *common, log=log,
        )  # fmt: skip
    views = {"apollo": args.apollo_views, "procedural": proc_views}
    runs = {}
    for name, path in data.items():
        run = work / f"train-{name}"
        runs[name] = run
        done = (run / "log.csv").exists() and len(curve(run)) >= args.epochs
        if not done:
            resume = ["--resume"] if (run / "last.pt").exists() else []
            cpu[f"train_{name}"] = cli(
                "train", "--model", "sanet-hit", "--schedule", "budget", "--config", CONFIG, "--data", path,
                "--epochs", args.epochs, "--steps-per-epoch", args.steps, "--max-views", views[name],
                "--val-max-views", 10 if name == "apollo" else 3, "--threads", 1, "--seed", 0, "--out", run,
                "--quiet", *resume, log=log,
            )  # fmt: skip
    scores = {}
    for name, path in data.items():
        out = work / f"eval-{name}"
        if not out.with_suffix(".json").exists():
            mv = args.eval_views if name == "apollo" else max(1, args.eval_views // 4)
            cpu[f"eval_{name}"] = cli(
                "evaluate", "--data", path, "--checkpoint", runs["apollo"] / "best.pt", runs["procedural"] / "best.pt",
                "--max-views", mv, "--threads", 1, "--examples", 0, "--out", out, "--quiet", log=log,
            )  # fmt: skip
        scores[name] = json.loads(out.with_suffix(".json").read_text())
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
        train[name] = {
            "steps": rows[-1]["step"],
            "train_seconds_wall": round(sum(r["seconds"] for r in rows), 1),
            "views_per_car": views[name],
            "curve": rows,
            **flattened(rows),
        }
    acc = {k: v["accuracy"] for k, v in table.items()}
    result = {
        "command": "nice -n 10 env OMP_NUM_THREADS=1 python benchmarks/procedural_realism.py --work WORK",
        "settings": {k: v for k, v in vars(args).items() if k not in ("work", "json")},
        "scores": table,
        "ratio_procedural_over_apollo_on_apollo_test": acc["procedural_on_apollo"] / acc["apollo_on_apollo"],
        "ratio_apollo_over_procedural_on_procedural_test": acc["apollo_on_procedural"]
        / acc["procedural_on_procedural"],
        "bar": 1.3,
        "training": train,
        "cpu_seconds_this_invocation": {k: round(v, 1) for k, v in cpu.items()},
        "generated": time.strftime("%Y-%m-%d"),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1) + "\n")
    print(args.json)


if __name__ == "__main__":
    main()
