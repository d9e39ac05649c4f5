"""Config schema: unknown keys name themselves, values are checked before torch,
the optimizer and the schedule are built from ``type`` + arguments, old configs still load."""

from __future__ import annotations

import math

import pytest

torch = pytest.importorskip("torch")

from spotlights.errors import InputFileError, ParameterError  # noqa: E402
from spotlights.learning.config import build_optimizer, build_scheduler, check_keys, data_config, train_config  # noqa: E402
from spotlights.learning.models import load_config  # noqa: E402


@pytest.mark.parametrize(
    "text, key, hint",
    [
        ("train:\n  epoch: 3\n", "train.epoch", "did you mean 'epochs'"),
        ("data:\n  max_view: 3\n", "data.max_view", "did you mean 'max_views'"),
        ("model:\n  args:\n    hiden: [64]\n", "model.args.hiden", "did you mean 'hidden'"),
        ("model:\n  arg: {}\n", "model.arg", "did you mean 'args'"),
        ("trian:\n  epochs: 3\n", "trian", "did you mean 'train'"),
    ],
)
def test_an_unknown_key_is_an_error_naming_the_key_and_the_file(tmp_path, text, key, hint):
    user = tmp_path / "typo.yaml"
    user.write_text(text)
    with pytest.raises(InputFileError) as err:
        load_config("sanet", user)
    msg = str(err.value)
    assert "typo.yaml" in msg and key in msg, msg
    assert hint in msg, msg


def test_unknown_keys_in_a_schedule_and_in_overrides(tmp_path):
    sched = tmp_path / "s.yaml"
    sched.write_text("default:\n  train:\n    lr: 0.001\npcn:\n  train:\n    epohcs: 2\n")
    with pytest.raises(InputFileError, match=r"s\.yaml.*'train\.epohcs'"):
        load_config("sanet", schedule=sched)  # a typo anywhere in the file, not only in the model's section
    with pytest.raises(ParameterError, match="'data.rigg'"):
        load_config("sanet", overrides={"data": {"rigg": "x"}})


@pytest.mark.parametrize(
    "train, match",
    [
        ({"lr": -1}, "train.lr must be > 0"),
        ({"lr": float("nan")}, "train.lr must be a finite number"),
        ({"epochs": -1}, "train.epochs must be >= 0"),
        ({"batch_size": 0}, "train.batch_size must be >= 1"),
        ({"batch_size": 2.5}, "train.batch_size must be an integer"),
        ({"steps_per_epoch": 0}, "train.steps_per_epoch must be >= 1"),
        ({"precision": "fp8"}, "train.precision must be one of"),
        ({"select_by": "f1"}, "train.select_by must be one of"),
        ({"compile": "yes"}, "train.compile must be true or false"),
        ({"optimizer": "adagrad"}, "unknown type 'adagrad'"),
        (
            {"optimizer": {"type": "adam", "betas": [0.9, 0.99], "momentum": 0.9}},
            r"train.optimizer \(adam\): unknown argument 'momentum'",
        ),
        ({"optimizer": {"type": "adam", "lr": 0.1}}, "set train.lr instead"),
        (
            {"lr_schedule": {"type": "cosine", "min_fator": 0.1}},
            "unknown argument 'min_fator'.*did you mean 'min_factor'",
        ),
        ({"lr_schedule": {"type": "poly"}}, "unknown type 'poly'"),
        ({"weight_decay": -0.1}, "train.weight_decay must be >= 0"),
    ],
)
def test_values_are_checked_before_torch_sees_them(train, match):
    with pytest.raises(ParameterError, match=match):
        load_config("pcn", overrides={"train": train})


def test_optimizer_and_schedule_from_type_and_arguments():
    w = [torch.nn.Parameter(torch.zeros(3))]
    cfg = load_config(
        "pcn",
        overrides={
            "train": {
                "optimizer": {"type": "adamw", "betas": [0.8, 0.9]},
                "lr": 0.01,
                "weight_decay": 0.1,
                "epochs": 10,
                "lr_schedule": {"type": "step", "every": 3, "gamma": 0.5},
            }
        },
    )
    t = train_config(cfg)
    opt = build_optimizer(w, t)
    assert isinstance(opt, torch.optim.AdamW) and opt.defaults["betas"] == (0.8, 0.9)
    assert opt.defaults["lr"] == 0.01 and opt.defaults["weight_decay"] == 0.1
    sched = build_scheduler(opt, t)
    lrs = []
    for _ in range(7):
        lrs.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    assert lrs == pytest.approx([0.01, 0.01, 0.01, 0.005, 0.005, 0.005, 0.0025])
    # the pre-existing spellings: optimizer by name, lr_schedule with 'kind'; cosine to min_factor
    t = train_config(
        load_config(
            "pcn",
            overrides={
                "train": {
                    "optimizer": "sgd",
                    "lr": 0.1,
                    "epochs": 4,
                    "lr_schedule": {"kind": "cosine", "min_factor": 0.1},
                }
            },
        )
    )
    opt = build_optimizer([torch.nn.Parameter(torch.zeros(1))], t)
    assert isinstance(opt, torch.optim.SGD) and opt.defaults["momentum"] == 0.9
    sched = build_scheduler(opt, t)
    got = []
    for _ in range(5):
        got.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    want = [0.1 * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * e / 4))) for e in range(5)]
    assert got == pytest.approx(want)


def test_configs_of_earlier_versions_load():
    """The shipped checkpoint's config (no precision, no steps_per_epoch) and fea188b's (all keys) are valid."""
    old = {
        "model": {
            "name": "sanet",
            "args": {"code_size": 1024, "hidden": [256, 256], "output_activation": "none", "clip": 0.2},
        },
        "data": {"rig": None, "max_views": 200, "val_max_views": 10, "num_workers": 0, "partials_in_memory": True},
        "train": {
            "epochs": 24,
            "batch_size": 32,
            "optimizer": "adam",
            "lr": 0.001,
            "weight_decay": 0.0,
            "lr_schedule": {"kind": "cosine", "min_factor": 0.05},
            "grad_clip": None,
            "seed": 0,
            "select_by": "chamfer_l1",
        },
    }
    check_keys(old, "old")
    t = train_config(old)
    assert t.precision == "fp32" and t.steps_per_epoch is None and t.epochs == 24
    assert data_config(old).max_views == 200
    new = load_config("sanet", schedule="cpu", overrides={"train": {"precision": "bf16", "steps_per_epoch": 5}})
    check_keys(new, "new")
    assert train_config(new).precision == "bf16"
