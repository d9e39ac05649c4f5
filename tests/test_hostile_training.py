"""Hostile training inputs: learning-rate schedules, NaN losses, all-NaN curves, run folders shared or kept."""

from __future__ import annotations

import pytest

from spotlights.errors import ParameterError, SpotlightsError
from spotlights.learning.config import check_schedule


@pytest.mark.parametrize(
    "schedule, message",
    [
        ({"kind": "step", "every": 1, "gamma": -0.5}, "gamma must be a number in \\(0, 1\\]"),
        ({"kind": "step", "every": 1, "gamma": 1.5}, "gamma"),
        ({"kind": "step", "every": 0}, "every must be a number in \\[1, "),
        ({"kind": "step", "every": 2.5}, "every"),
        ({"kind": "step", "every": "abc"}, "every"),
        ({"kind": "step", "gamma": float("nan")}, "gamma"),
        ({"kind": "cosine", "min_factor": 5}, "min_factor must be a number in \\[0, 1\\]"),
        ({"kind": "cosine", "min_factor": "abc"}, "min_factor"),
        ({"kind": "cosine", "min_factor": True}, "min_factor"),
    ],
)
def test_schedules_that_grow_or_turn_negative_are_refused(schedule, message):
    with pytest.raises(ParameterError, match=message):
        check_schedule(schedule)


def test_valid_schedules_pass():
    for schedule in (
        {"kind": "step", "every": 30, "gamma": 0.5},
        {"kind": "step", "every": 1, "gamma": 1.0},
        {"kind": "cosine", "min_factor": 0.0},
        {"kind": "cosine", "min_factor": 0.05},
        {"type": "constant"},
        None,
    ):
        check_schedule(schedule)


def test_learning_curves_of_all_nan_metrics_are_drawn(tmp_path):
    """A short run's validation metrics can all be NaN: the page is drawn (empty panels), no legend to fail."""
    from spotlights.viz.curves import render_learning_curves

    nan = float("nan")
    curves = {"run": {"epoch": [1, 2], "val_accuracy": [nan, nan]}}
    out = render_learning_curves(tmp_path / "c.png", curves, [("val_accuracy", "accuracy")], "epoch", "epoch", "t")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.timeout(300)
@pytest.mark.parametrize("bad_data", [False, True])
def test_a_run_stopped_by_a_nan_loss_leaves_nothing_and_names_the_cause(tmp_path, monkeypatch, capsys, bad_data):
    """A NaN loss on the first epoch left ``run/config.yaml`` behind and always advised a lower learning rate,
    also when the batch itself held NaN (the dataset's fault)."""
    import json

    import torch

    from spotlights.learning.models.sanet import SANet

    from learning_fixtures import cli, tiny_dataset_path, tiny_overrides

    real_loss = SANet.loss

    def nan_loss(self, outputs, batch, progress=1.0):
        loss, parts = real_loss(self, outputs, batch, progress)
        if bad_data:
            batch["partial"][0, 0, 0] = float("nan")
        return loss * torch.tensor(float("nan")), parts

    monkeypatch.setattr(SANet, "loss", nan_loss)
    data = tiny_dataset_path(tmp_path / "data")
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(json.dumps(tiny_overrides("sanet", epochs=1, batch_size=4)))
    proc = cli(capsys, "train", "--model", "sanet", "--data", data, "--config", cfg, "--out", tmp_path / "run", "-q")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert "the training loss became nan" in proc.stderr
    if bad_data:
        assert "partial hold NaN or infinite values: check the dataset" in proc.stderr and "lower" not in proc.stderr
    else:
        assert "lower train.lr" in proc.stderr
    assert not (tmp_path / "run").exists(), sorted(p.name for p in (tmp_path / "run").rglob("*"))
    # a folder that holds a kept best model and its config (no last.pt): the NaN stop puts the config back
    run = tmp_path / "kept"
    run.mkdir()
    (run / "config.yaml").write_text("model: {name: sanet}\n")
    (run / "best.pt").write_bytes(b"a kept best model")
    proc = cli(capsys, "train", "--model", "sanet", "--data", data, "--config", cfg, "--out", run, "-q")
    assert proc.returncode == 2 and "the training loss became nan" in proc.stderr, proc.stderr
    assert sorted(p.name for p in run.iterdir()) == ["best.pt", "config.yaml"]
    assert (run / "config.yaml").read_text() == "model: {name: sanet}\n"


@pytest.mark.timeout(120)
def test_a_failed_call_keeps_the_files_of_a_run_it_did_not_write(tmp_path, capsys):
    """The cleanup of a failed run removed ``config.yaml``, ``best.pt`` and ``log.csv`` of an existing run folder
    (one without ``last.pt``: a kept best model) on any input error: a wrong ``--data`` or "nothing to resume"."""
    from learning_fixtures import cli

    run = tmp_path / "run"
    run.mkdir()
    kept = {"config.yaml": b"model: {name: sanet}\n", "best.pt": b"a kept best model", "log.csv": b"epoch\n1\n"}
    for name, data in kept.items():
        (run / name).write_bytes(data)
    missing = tmp_path / "missing.h5"
    for extra in ([], ["--resume"]):
        proc = cli(capsys, "train", "--model", "sanet", "--data", missing, "--out", run, "-q", *extra)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert {p.name: p.read_bytes() for p in run.iterdir()} == kept, extra
    # --overwrite with a mistyped --data: the old run (here with its last.pt) goes only once the data is found
    kept["last.pt"] = b"a run to continue"
    (run / "last.pt").write_bytes(kept["last.pt"])
    proc = cli(capsys, "train", "--model", "sanet", "--data", missing, "--out", run, "-q", "--overwrite")
    assert proc.returncode == 2 and "missing.h5" in proc.stderr, proc.stderr
    assert {p.name: p.read_bytes() for p in run.iterdir()} == kept


@pytest.mark.timeout(120)
def test_two_trainings_into_one_run_folder_are_refused(tmp_path):
    """Two ``train`` runs into one ``--out`` both exited 0 and both reported their checkpoints; the folder held one
    model's files (or a mix). The second is now refused while the first holds the folder's lock."""
    from spotlights.learning.train import train
    from spotlights.locks import exclusive_lock

    from learning_fixtures import tiny_dataset_path, tiny_overrides

    data = tiny_dataset_path(tmp_path / "data")
    run = tmp_path / "run"
    run.mkdir()
    with exclusive_lock(run / ".train.lock", "held by the test"):  # what a running 'spotlights train' holds
        with pytest.raises(SpotlightsError, match="another 'spotlights train' is writing this run folder"):
            train("pcn", data, run, overrides=tiny_overrides("pcn", epochs=1), progress=False, log=lambda *a: None)
    assert sorted(p.name for p in run.iterdir()) == [".train.lock"]  # the refused run wrote nothing
    res = train("pcn", data, run, overrides=tiny_overrides("pcn", epochs=1), progress=False, log=lambda *a: None)
    assert res["epochs"] == 1 and not (run / ".train.lock").exists()  # the lock goes with the run
    assert sorted(p.name for p in run.iterdir()) == [
        "best.pt",
        "config.yaml",
        "last.pt",
        "log.csv",
    ]
