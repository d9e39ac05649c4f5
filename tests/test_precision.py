"""Mixed precision training (bf16 autocast on CPU) and step-count epochs (train.steps_per_epoch)."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from spotlights.data.store import open_dataset  # noqa: E402
from spotlights.errors import ParameterError  # noqa: E402
from spotlights.learning import train as train_module  # noqa: E402
from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint  # noqa: E402
from spotlights.learning.device import autocast, resolve_precision  # noqa: E402
from spotlights.learning.train import train  # noqa: E402

from learning_fixtures import one_torch_thread, tiny_dataset_path, tiny_overrides  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return tiny_dataset_path(tmp_path_factory.getbasetemp() / "precision-data")


def _run(name, path, out, epochs=2, **train_kw):
    resume = train_kw.pop("resume", False)
    stop_after = train_kw.pop("stop_after", None)
    ov = tiny_overrides(name, epochs=epochs, **train_kw)
    return train(
        name, path, out, overrides=ov, progress=False, log=lambda *a: None, resume=resume, stop_after=stop_after
    )


def test_resolve_precision():
    cpu = torch.device("cpu")
    assert resolve_precision("fp32", cpu) == "fp32"
    assert resolve_precision("bf16", cpu) == "bf16"
    assert resolve_precision("auto", cpu) in ("bf16", "fp32")
    with pytest.raises(ParameterError, match="unknown precision"):
        resolve_precision("fp8", cpu)
    with autocast("bf16", cpu):
        y = torch.nn.Linear(4, 4)(torch.ones(2, 4))
    assert y.dtype == torch.bfloat16
    with autocast("fp32", cpu):
        assert torch.nn.Linear(4, 4)(torch.ones(2, 4)).dtype == torch.float32


@pytest.mark.parametrize("name", ["sanet", "foldingnet"])
def test_bf16_training_decreases_the_loss_and_saves_float32_weights(data, tmp_path, name):
    res = _run(name, data, tmp_path / name, epochs=6, precision="bf16")
    ref = _run(name, data, tmp_path / f"{name}-fp32", epochs=6, precision="fp32")
    losses = [h["train_loss"] for h in res["history"]]
    ref_losses = [h["train_loss"] for h in ref["history"]]
    assert all(torch.isfinite(torch.tensor(losses))) and losses[-1] < 0.95 * losses[0], losses
    assert losses != ref_losses  # bf16 really ran
    assert abs(losses[-1] - ref_losses[-1]) < 0.05 * ref_losses[-1], (losses, ref_losses)  # and learned as fp32 does
    ckpt = load_checkpoint(tmp_path / name / "best.pt")
    assert ckpt["precision"] == "bf16" and ckpt["config"]["train"]["precision"] == "bf16"
    assert all(v.dtype == torch.float32 for v in ckpt["model_state"].values() if v.is_floating_point())
    model = model_from_checkpoint(ckpt)  # evaluation and completion run in float32
    out = model(torch.rand(2, 64, 3))
    assert all(v.dtype == torch.float32 for v in out.values())


def test_resume_continues_exactly_under_bf16_with_step_epochs(data, tmp_path, monkeypatch):
    """Step-count epochs draw the next batches of one stream of shuffled passes over the training set:
    every sample once per pass, a new order each pass, the same stream whether resumed or not."""
    drawn: dict[str, list[list[int]]] = {}  # run -> the training sample indices of each epoch, in order
    real_loader = train_module.DataLoader

    def recording_loader(dataset, *a, sampler=None, **kw):
        if isinstance(sampler, list):  # a training epoch's indices (validation draws no sampler)
            drawn.setdefault(run_name, []).append(list(sampler))
        return real_loader(dataset, *a, sampler=sampler, **kw)

    monkeypatch.setattr(train_module, "DataLoader", recording_loader)
    kw = dict(precision="bf16", steps_per_epoch=3)
    run_name = "full"
    full = _run("atlasnet", data, tmp_path / "full", epochs=3, **kw)
    run_name = "part"
    _run("atlasnet", data, tmp_path / "part", epochs=3, stop_after=1, **kw)
    resumed = train("atlasnet", data, tmp_path / "part", resume=True, progress=False, log=lambda *a: None)
    with open_dataset(data) as ds:
        n_train = len(ds.split_indices("train"))
    stream = [i for epoch in drawn["full"] for i in epoch]
    assert [len(e) for e in drawn["full"]] == [24, 24, 24] and drawn["part"] == drawn["full"]  # 3 steps of 8
    assert n_train < len(stream) < 2 * n_train, n_train  # one whole pass and the start of the next
    first, second = stream[:n_train], stream[n_train:]
    assert sorted(first) == list(range(n_train)), stream  # every sample once per pass
    assert len(set(second)) == len(second) and second != first[: len(second)]  # a new permutation
    a, b = load_checkpoint(tmp_path / "full" / "last.pt"), load_checkpoint(tmp_path / "part" / "last.pt")
    for k in a["model_state"]:
        assert torch.equal(a["model_state"][k], b["model_state"][k]), k
    assert [h["train_loss"] for h in full["history"]] == [h["train_loss"] for h in resumed["history"]]
    assert [h["global_step"] for h in full["history"]] == [3, 6, 9]
    assert [h["samples_seen"] for h in full["history"]] == [24, 48, 72]
    assert full["history"][-1]["wall_seconds"] >= full["history"][0]["wall_seconds"] > 0


def test_compile_option_wraps_the_training_forward_only(data, tmp_path, monkeypatch):
    """train.compile routes the training forward through torch.compile (recorded here with a pass-through
    stand-in: a real compile costs minutes on CPU); checkpoints hold the eager model's keys."""
    calls = []

    class Recorded(torch.nn.Module):  # what torch.compile returns: a wrapper that calls the module
        def __init__(self, mod):
            super().__init__()
            self._orig_mod = mod

        def forward(self, *a, **kw):
            calls.append(a[0].shape)
            return self._orig_mod(*a, **kw)

    monkeypatch.setattr(torch, "compile", lambda mod, **kw: Recorded(mod))
    _run("sanet", data, tmp_path / "c", epochs=1, steps_per_epoch=2, compile=True)
    assert len(calls) == 2  # one compiled forward per training step, none for validation
    ck = load_checkpoint(tmp_path / "c" / "best.pt")
    assert ck["config"]["train"]["compile"] is True
    assert not any(k.startswith("_orig_mod") for k in ck["model_state"])
    model_from_checkpoint(ck)  # loads as an eager model
    calls.clear()
    _run("sanet", data, tmp_path / "e", epochs=2, steps_per_epoch=2, stop_after=1)
    assert calls == []  # off by default
    # an execution key: a resumed run takes it from the command line (train.epochs aside, the rest is kept)
    train(
        "sanet",
        data,
        tmp_path / "e",
        resume=True,
        overrides={"train": {"compile": True}},
        progress=False,
        log=lambda *a: None,
    )
    assert len(calls) == 2 and load_checkpoint(tmp_path / "e" / "last.pt")["config"]["train"]["compile"] is True
