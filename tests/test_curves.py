"""Learning curves: flatness judged on curves of known shape, logs read, figures and CSVs written."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from spotlights.errors import InputFileError
from spotlights.experiments.curves import flatness, learning_curves, read_log

STEPS = np.arange(1, 26) * 100.0


def test_flatness_of_known_curves():
    # exponential decay with time constant 300 steps: its last 20% improves it by 0.3% -> flat
    f = lambda s: 0.02 + 0.05 * np.exp(-s / 300.0)  # noqa: E731
    flat = flatness(STEPS, f(STEPS))
    assert flat.flattened and flat.verdict == "flat"
    assert flat.tail_improvement == pytest.approx((f(2000.0) - f(2500.0)) / f(2000.0))  # tail = steps >= 2020
    # a straight line falling 40% over the run: its tail still improves it by ~8% -> still improving
    line = flatness(STEPS, 0.05 * (1 - 0.4 * STEPS / STEPS[-1]))
    assert not line.flattened and line.verdict == "still improving"
    best_before = 0.05 * (1 - 0.4 * 2000 / 2500)  # the last point before the tail (steps < 2020)
    assert line.tail_improvement == pytest.approx((best_before - 0.05 * 0.6) / best_before)
    assert line.tail_slope == pytest.approx(
        -0.05 * 0.4 / 2500 * 2400 * 0.2 / np.mean(0.05 * (1 - 0.4 * STEPS[-5:] / 2500))
    )
    # a curve that rises again at the end: worsening
    v = 0.03 - 0.01 * np.minimum(STEPS, 1500) / 1500 + 0.004 * np.maximum(STEPS - 1500, 0) / 1000
    assert flatness(STEPS, v).verdict == "worsening"
    assert flatness(STEPS[:2], [1.0, 0.5]).verdict == "too short to judge"


def _write_run(folder, name, values, steps_per_epoch=100, epochs=25):
    run = folder / name
    run.mkdir()
    cols = [
        "epoch",
        "lr",
        "val_accuracy",
        "val_completeness",
        "val_chamfer_l1",
        "global_step",
        "samples_seen",
        "wall_seconds",
    ]
    with open(run / "log.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for i, v in enumerate(values):
            w.writerow(
                [
                    i + 1,
                    1e-3,
                    v,
                    2 * v,
                    1.5 * v,
                    (i + 1) * steps_per_epoch,
                    (i + 1) * steps_per_epoch * 32,
                    60.0 * (i + 1),
                ]
            )
    (run / "config.yaml").write_text(f"train: {{epochs: {epochs}, steps_per_epoch: {steps_per_epoch}}}\n")
    return run


def test_learning_curves_writes_figures_csvs_and_summary(tmp_path):
    a = _write_run(tmp_path, "a", 0.02 + 0.05 * np.exp(-STEPS / 300.0))
    b = _write_run(tmp_path, "b", list(0.05 * (1 - 0.4 * STEPS[:10] / 2500)), steps_per_epoch=50, epochs=20)
    out = tmp_path / "out"
    summary = learning_curves([a, b], out=out, budget_minutes=45)
    assert summary["runs"]["a"]["flatness"]["val_chamfer_l1"]["flattened"]
    assert summary["runs"]["b"]["planned_steps"] == 1000 and summary["runs"]["b"]["steps"] == 500
    assert summary["runs"]["a"]["wall_minutes"] == pytest.approx(25.0)
    for f in ("curves_samples.png", "curves_minutes.png", "a.csv", "b.csv"):
        assert (out / f).stat().st_size > 1000 or f.endswith(".csv")
    assert (out / "a.csv").read_text() == (a / "log.csv").read_text()
    assert json.loads((out / "curves.json").read_text())["budget_minutes"] == 45
    # budget minutes: run b did 500 of its 1000 planned steps = half of the 45-minute budget
    assert read_log(b)["global_step"][-1] == 500


def test_bad_logs(tmp_path):
    with pytest.raises(InputFileError, match="no such training log"):
        read_log(tmp_path)
    (tmp_path / "log.csv").write_text("epoch,foo\n1,2\n")
    with pytest.raises(InputFileError, match="not a spotlights training log"):
        read_log(tmp_path)
