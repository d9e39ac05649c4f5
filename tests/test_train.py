"""Dataset reader, training (loss decreases, determinism, exact resume, DDP with gloo), evaluation, bench."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import h5py
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from spotlights.errors import InputFileError, SpotlightsError  # noqa: E402
from spotlights.learning.checkpoint import load_checkpoint  # noqa: E402
from spotlights.learning.data import TorchCompletionDataset, read_info  # noqa: E402
from spotlights.learning.train import train  # noqa: E402

from helpers import assert_user_error, src_pythonpath  # noqa: E402
from learning_fixtures import TINY_MODEL_ARGS, cli, one_torch_thread, tiny_dataset_path, tiny_overrides  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return tiny_dataset_path(tmp_path_factory.getbasetemp() / "learning-data")


def _run(name, path, out, data_cfg=None, **kw):
    ov = tiny_overrides(name, epochs=kw.pop("epochs", 2), **kw.pop("train", {}))
    ov["data"].update(data_cfg or {})
    return train(name, path, out, overrides=ov, progress=False, log=lambda *a: None, **kw)


# ---------------------------------------------------------------- dataset


def test_dataset_reads_the_contract_schema(data):
    info = read_info(data)
    assert info.n_models == 12 and info.category_order() == ["hatchback", "sedan", "suv"]
    assert info.default_rig == "cap-8x16-60" and info.rigs["cap-8x16-60"].n_primary == 8
    tr = TorchCompletionDataset(data, "train")
    assert len(tr) == 6 * 8 and len(TorchCompletionDataset(data, "test", rig=False)) == 3 * 8
    item = tr[9]
    assert item["partial"].shape == (256, 3) and item["partial"].dtype == torch.float32
    assert item["gt_points"].shape == (2048, 3) and item["depths"].shape == (128,)
    assert int(item["model"]) == 1 and int(item["view"]) == 1
    # ground truth is per model, shared by its views; depths are the file's
    assert torch.equal(tr[8]["gt_points"], tr[15]["gt_points"])
    with h5py.File(data, "r") as f:
        np.testing.assert_array_equal(item["depths"].numpy(), f["rigs/cap-8x16-60/depths"][1])
        np.testing.assert_array_equal(item["partial"].numpy(), f["samples/partial"][9])
    few = TorchCompletionDataset(data, "train", max_views=3)
    assert len(few) == 18 and set(few.info.sample_view[few.indices].tolist()) == {0, 1, 2}
    dense = TorchCompletionDataset(data, "test", rig=False).gt_dense()
    assert sorted(dense) == [9, 10, 11] and dense[9].shape == (16384, 3)
    assert "depths" not in TorchCompletionDataset(data, "val", rig=False)[0]


def test_lazy_reading_with_worker_processes_gives_the_same_bytes(data):
    from torch.utils.data import DataLoader

    lazy = TorchCompletionDataset(data, "train", partials_in_memory=False)
    mem = TorchCompletionDataset(data, "train", partials_in_memory=True)
    a = torch.cat([b["partial"] for b in DataLoader(lazy, batch_size=7, num_workers=2)])
    b = torch.cat([b["partial"] for b in DataLoader(mem, batch_size=7, num_workers=0)])
    assert torch.equal(a, b) and a.shape == (48, 256, 3)
    assert not lazy.store.is_open()  # the parent holds no open handle: each worker opened its own


def test_dataset_errors(data, tmp_path):
    with pytest.raises(InputFileError, match="no such file"):
        TorchCompletionDataset(tmp_path / "missing.h5")
    txt = tmp_path / "a.h5"
    txt.write_text("hello")
    with pytest.raises(InputFileError, match="not a readable HDF5"):
        TorchCompletionDataset(txt)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.attrs["format"] = "something-else"
    with pytest.raises(InputFileError, match="not a spotlights completion dataset"):
        TorchCompletionDataset(other)
    with pytest.raises(InputFileError, match="has no rig 'cap-32x64-60'"):
        TorchCompletionDataset(data, "train", rig="cap-32x64-60")
    with pytest.raises(SpotlightsError, match="split must be"):
        TorchCompletionDataset(data, "holdout")


# ---------------------------------------------------------------- training


@pytest.mark.parametrize("name", ["sanet", "foldingnet"])
def test_a_few_epochs_lower_the_loss(data, tmp_path, name):
    res = _run(name, data, tmp_path / name, epochs=10, train={"lr": 3e-3})
    losses = [h["train_loss"] for h in res["history"]]
    assert losses[-1] < 0.85 * losses[0], losses
    assert (tmp_path / name / "best.pt").exists() and (tmp_path / name / "config.yaml").exists()
    rows = (tmp_path / name / "log.csv").read_text().splitlines()
    assert rows[0].startswith("epoch,lr,train_loss,val_loss,val_accuracy") and len(rows) == 11


def test_resume_continues_exactly(data, tmp_path):
    # AtlasNet: random patch samples in training and batch norm: the strictest case.
    full = _run("atlasnet", data, tmp_path / "full", epochs=3)
    _run("atlasnet", data, tmp_path / "part", epochs=3, stop_after=1)  # interrupted after epoch 1 of 3
    assert load_checkpoint(tmp_path / "part" / "last.pt")["epoch"] == 1
    resumed = train("atlasnet", data, tmp_path / "part", resume=True, progress=False, log=lambda *a: None)
    a = load_checkpoint(tmp_path / "full" / "last.pt")
    b = load_checkpoint(tmp_path / "part" / "last.pt")
    assert a["model_state"].keys() == b["model_state"].keys()
    for k in a["model_state"]:
        assert torch.equal(a["model_state"][k], b["model_state"][k]), k
    assert [h["train_loss"] for h in full["history"]] == [h["train_loss"] for h in resumed["history"]]
    assert b["epoch"] == 3 and len((tmp_path / "part" / "log.csv").read_text().splitlines()) == 4
    # raising the number of epochs of a finished run continues it
    more = train(
        "atlasnet",
        data,
        tmp_path / "part",
        overrides={"train": {"epochs": 4}},
        resume=True,
        progress=False,
        log=lambda *a: None,
    )
    assert more["epochs"] == 4 and more["history"][-1]["lr"] > 0


def test_same_seed_same_weights_whatever_the_number_of_workers(data, tmp_path):
    a = _run("sanet", data, tmp_path / "w0", epochs=1)
    b = _run("sanet", data, tmp_path / "w2", epochs=1, data_cfg={"num_workers": 2, "partials_in_memory": False})
    sa = load_checkpoint(tmp_path / "w0" / "last.pt")["model_state"]
    sb = load_checkpoint(tmp_path / "w2" / "last.pt")["model_state"]
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert a["history"][0]["train_loss"] == b["history"][0]["train_loss"]


def test_run_folder_protection_and_wrong_model_resume(data, tmp_path):
    _run("sanet", data, tmp_path / "run", epochs=1)
    with pytest.raises(SpotlightsError, match="holds a run already"):
        _run("sanet", data, tmp_path / "run", epochs=1)
    with pytest.raises(InputFileError, match="holds a 'sanet' model, expected 'pcn'"):
        _run("pcn", data, tmp_path / "run", epochs=1, resume=True)
    with pytest.raises(SpotlightsError, match="nothing to resume"):
        _run("sanet", data, tmp_path / "empty", epochs=1, resume=True)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_ddp_with_torchrun_gloo_two_processes(data, tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(json.dumps(tiny_overrides("sanet", epochs=1, batch_size=4)))  # JSON is YAML
    env = dict(os.environ, PYTHONPATH=src_pythonpath(), OMP_NUM_THREADS="1")
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--nproc-per-node",
        "2",
        "--master-addr",
        "127.0.0.1",
        "--master-port",
        str(_free_port()),
        "-m",
        "spotlights",
        "train",
        "--model",
        "sanet",
        "--data",
        str(data),
        "--config",
        str(cfg),
        "--out",
        str(tmp_path / "ddp"),
        "--threads",
        "1",
        "--device",
        "cpu",  # gloo on CPU processes, also where a GPU is (2 processes would need 2 GPUs)
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=240)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert "2 process(es)" in proc.stdout
    ck = load_checkpoint(tmp_path / "ddp" / "last.pt")
    assert ck["epoch"] == 1 and ck["history"][0]["val_n"] == 3 * 2  # validation shards summed over both ranks
    # each rank trained on half of the 48 samples per step: 24 / 4 = 6 steps
    assert ck["global_step"] == 6


# ---------------------------------------------------------------- evaluation and bench


def test_evaluate_writes_table1_report(data, tmp_path):
    from spotlights.learning.evaluate import evaluate_checkpoints, write_report
    from spotlights.learning.inference import load_completer

    _run("sanet", data, tmp_path / "sanet", epochs=1)
    _run("topnet", data, tmp_path / "topnet", epochs=1)
    ckpts = [tmp_path / "sanet" / "last.pt", tmp_path / "topnet" / "last.pt"]
    report = evaluate_checkpoints(ckpts, data, "test", progress=False, latency=True, latency_repeats=1)
    md, js = write_report(report, tmp_path / "report")
    text = md.read_text()
    assert "| Method | Hatchback | Sedan | SUV | Average (samples) | Average (categories) |" in text
    assert "SA-Net (no clip)" in text and "SA-Net (clip 0.2)" in text and "TopNet" in text
    rep = json.loads(js.read_text())
    sanet = rep["results"][0]
    assert [r["variant"] for r in sanet["rows"]] == ["no clip", "clip 0.2"]
    # Independent check of the no-clip accuracy: brute force over every test sample.
    completer = load_completer(ckpts[0])
    ds = TorchCompletionDataset(data, "test", rig=False)
    dense = ds.gt_dense()
    preds = completer.complete(np.stack([ds[i]["partial"].numpy() for i in range(len(ds))]), clip=None)
    accs = []
    for p, m in zip(preds, ds.sample_models):
        d = np.sqrt(((p[:, None].astype(np.float64) - dense[int(m)][None]) ** 2).sum(-1)).min(1)
        accs.append(d.mean())
    summary = sanet["rows"][0]["summary"]
    assert summary["mean_over_samples"]["accuracy"] == pytest.approx(np.mean(accs), rel=1e-5)
    cats = ds.sample_categories
    by_cat = [np.mean([a for a, c in zip(accs, cats) if c == k]) for k in ("hatchback", "sedan", "suv")]
    assert summary["mean_over_categories"]["accuracy"] == pytest.approx(np.mean(by_cat), rel=1e-5)
    assert summary["per_category"]["sedan"]["accuracy"] == pytest.approx(by_cat[1], rel=1e-5)
    assert 0 < summary["mean_over_samples"]["hit_ratio"] <= 1
    assert rep["results"][1]["params"]["total"] > 0 and "1" in rep["results"][1]["latency_ms"]


def test_cli_train_evaluate_and_errors(data, tmp_path, capsys):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(json.dumps({"model": {"args": TINY_MODEL_ARGS["pcn"]}}))
    proc = cli(
        capsys,
        "train",
        "--model",
        "pcn",
        "--data",
        data,
        "--config",
        cfg,
        "--epochs",
        "1",
        "--batch-size",
        "16",
        "--val-max-views",
        "1",
        "--out",
        tmp_path / "pcn",
        "--no-progress",
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "pcn" / "best.pt").exists()
    proc = cli(
        capsys,
        "evaluate",
        "--data",
        data,
        "--checkpoint",
        tmp_path / "pcn" / "best.pt",
        "--out",
        tmp_path / "rep",
        "--max-views",
        "2",
        "--no-latency",
    )
    assert proc.returncode == 0, proc.stderr
    assert "| PCN |" in proc.stdout and (tmp_path / "rep.json").exists()
    # the prediction-vs-ground-truth figure, written by default (--examples 2)
    from PIL import Image

    assert f"figure -> {tmp_path / 'rep.png'}" in proc.stdout
    with Image.open(tmp_path / "rep.png") as im:
        assert im.format == "PNG" and min(im.size) > 100
    proc = cli(capsys, "evaluate", "--data", data, "--checkpoint", cfg)
    assert_user_error(proc, "tiny.yaml", "not a readable checkpoint")
    proc = cli(
        capsys, "train", "--model", "pcn", "--data", data, "--config", cfg, "--out", tmp_path / "pcn", "--epochs", "1"
    )
    assert_user_error(proc, "holds a run already")


def test_bench_models_cli_json(capsys):
    proc = cli(capsys, "bench", "models", "--batch", "1", "--repeats", "1", "--warmup", "0", "--json", "--threads", "1")
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    assert [r["model"] for r in res["models"]] == [
        "sanet",
        "sanet-hit",
        "sanet-local",
        "pcn",
        "foldingnet",
        "topnet",
        "atlasnet",
        "snowflakenet",
    ]
    sanet = res["models"][0]
    assert sanet["params"]["encoder"] == 821_504 and sanet["latency_ms"]["1"]["forward_ms"] > 0
    assert res["threads"] == 1


def test_reads_and_trains_on_a_file_built_by_the_dataset_builder(tmp_path):
    """Integration with the dataset builder: its file is read, trained on and evaluated."""
    synthetic = pytest.importorskip("spotlights.data.synthetic")
    from learning_fixtures import make_shape

    rng = np.random.default_rng(0)
    for cat in ("hatchback", "sedan", "suv"):
        (tmp_path / "meshes" / cat).mkdir(parents=True)
        for j in range(3):
            make_shape(cat, rng).export(tmp_path / "meshes" / cat / f"{cat}{j}.ply")
    cfg = synthetic.BuildConfig(
        meshes=str(tmp_path / "meshes"), views=4, split="3/3/3", gt_dense=2048, default_rig="8x16@60"
    )
    synthetic.build_dataset(cfg, tmp_path / "built.h5", workers=1, progress=False, log=lambda *a: None)
    ds = TorchCompletionDataset(tmp_path / "built.h5", "train")
    assert len(ds) == 12 and ds.rig_name == "cap-8x16-60" and ds[0]["depths"].shape == (128,)
    res = _run("sanet", tmp_path / "built.h5", tmp_path / "run", epochs=1, train={"batch_size": 4})
    assert res["history"][0]["val_n"] == 6 and np.isfinite(res["history"][0]["val_loss"])
    assert (tmp_path / "run" / "best.pt").exists()  # even when every ray of the untrained model is clipped


def test_validation_metrics_match_brute_force(data):
    from spotlights.learning.checkpoint import model_from_checkpoint
    from spotlights.learning.train import validate

    val = TorchCompletionDataset(data, "val", max_views=2)
    ckpt = load_checkpoint(make_checkpoint_cached(data))
    model = model_from_checkpoint(ckpt)
    dense = val.gt_dense()
    res = validate(model, val, 4, torch.device("cpu"), dict(dense))
    accs, comps = [], []
    with torch.no_grad():
        for i in range(len(val)):
            item = val[i]
            p = model.complete(item["partial"][None])[0].numpy().astype(np.float64)
            g = dense[int(item["model"])].astype(np.float64)
            d = np.sqrt(((p[:, None] - g[None]) ** 2).sum(-1))
            accs.append(d.min(1).mean())
            comps.append(d.min(0).mean())
    assert res["val_n"] == 6 and res["val_empty"] == 0
    assert res["val_accuracy"] == pytest.approx(np.mean(accs), rel=1e-5)
    assert res["val_completeness"] == pytest.approx(np.mean(comps), rel=1e-5)
    assert res["val_chamfer_l1"] == pytest.approx((np.mean(accs) + np.mean(comps)) / 2, rel=1e-5)


def make_checkpoint_cached(data):
    from learning_fixtures import make_checkpoint

    path = data.parent / "pcn_untrained.pt"
    return path if path.exists() else make_checkpoint(path, "pcn")


def test_two_checkpoints_of_one_model_are_told_apart_in_the_report():
    """Rows of the same model get their run folder's name (or the file's stem); a lone model keeps its plain name."""
    from spotlights.learning.evaluate import model_label, tag_repeated_models

    results = [
        {"model": "sanet", "checkpoint": "runs/fair/sanet/best.pt"},
        {"model": "sanet", "checkpoint": "pretrained/paper.pt"},
        {"model": "pcn", "checkpoint": "runs/pcn/best.pt"},
    ]
    tag_repeated_models(results)
    row = {"variant": "clip 0.2"}
    assert [model_label(r, row) for r in results] == [
        "SA-Net [sanet] (clip 0.2)",
        "SA-Net [paper] (clip 0.2)",
        "PCN (clip 0.2)",
    ]


def test_overwrite_removes_the_old_runs_state_before_starting(data, tmp_path):
    """A fresh start with --overwrite that stops before its first save must not leave the old run's
    last.pt beside the new config (a later --resume would continue the old run); the old state goes once the
    data and the model are found sound (a mistyped --data keeps it: tests/test_hostile_training.py)."""
    from spotlights.learning.training_run import RUN_STATE_FILES

    run = tmp_path / "run"
    run.mkdir()
    for name in RUN_STATE_FILES + ("config.yaml", "notes.txt"):
        (run / name).write_bytes(b"old")
    with pytest.raises(SpotlightsError, match="--overwrite"):  # without it the old run is kept and refused
        _run("pcn", data, run, epochs=1)
    assert (run / "last.pt").read_bytes() == b"old"

    def stop(*args):  # the first log line comes when the run is prepared, before the first epoch
        raise KeyboardInterrupt

    ov = tiny_overrides("pcn", epochs=1)
    with pytest.raises(KeyboardInterrupt):
        train("pcn", data, run, overrides=ov, overwrite=True, progress=False, log=stop)
    assert not any((run / name).exists() for name in RUN_STATE_FILES)
    assert (run / "config.yaml").read_bytes() != b"old" and (run / "notes.txt").exists()  # only the run's state goes


def test_process_group_backend_follows_the_run_device_and_refuses_missing_gpus():
    from spotlights.errors import ParameterError
    from spotlights.learning.process_group import group_backend

    assert group_backend(torch.device("cpu"), 1, 1) == ("gloo", None)  # --device cpu on a GPU node: gloo
    assert group_backend(torch.device("cuda"), 1, 2) == ("nccl", 1)  # one GPU per local rank
    assert group_backend(torch.device("cuda", 0), 0, 2) == ("nccl", 0)  # an explicit index: one process per node
    with pytest.raises(ParameterError, match="would share one GPU"):  # NCCL cannot run two ranks on one GPU
        group_backend(torch.device("cuda", 0), 1, 2, local_world=2)
    with pytest.raises(ParameterError, match="`nproc_per_node` 1"):  # 2 processes on a 1-GPU node (seen on an H100)
        group_backend(torch.device("cuda"), 1, 1)
