"""The ray-local SA-Net (sanet-local): parameters, training (fp32 and bf16) and completion, old datasets without
the sensor origin (the old models train, the new one is refused in one line), and the mirror input option."""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from spotlights.geometry.rig import make_rig  # noqa: E402
from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint  # noqa: E402
from spotlights.learning.inference import Completer  # noqa: E402
from spotlights.learning.models import build_model, load_config  # noqa: E402
from spotlights.learning.models.base import PCNEncoder  # noqa: E402
from spotlights.learning.train import train  # noqa: E402

from helpers import assert_user_error, run_cli  # noqa: E402
from learning_fixtures import TINY_MODEL_ARGS, one_torch_thread, tiny_dataset_path  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)

TINY_LOCAL = {**TINY_MODEL_ARGS["sanet-hit"], "candidate_width": 4, "local_hidden": [8]}


def overrides(**train_args) -> dict:
    return {
        "model": {"args": dict(TINY_LOCAL)},
        "data": {"rig": None, "val_max_views": 2, "num_workers": 0},
        "train": {"epochs": 2, "batch_size": 8, "lr": 1e-3, **train_args},
    }


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return tiny_dataset_path(tmp_path_factory.getbasetemp() / "local-data")


@pytest.fixture(scope="module")
def old_data(data, tmp_path_factory):
    """The tiny dataset as a file without the per-sample sensor pose."""
    path = tmp_path_factory.mktemp("old") / "old.h5"
    shutil.copy(data, path)
    with h5py.File(path, "a") as f:
        del f["samples/sensor_to_unit"]
    return path


def test_parameters_are_the_hit_aware_sanets_plus_the_local_mlp():
    rig = make_rig(8, 16, 60.0)
    cfg = load_config("sanet-local", overrides={"model": {"args": dict(TINY_LOCAL)}})
    hit = build_model(load_config("sanet-hit", overrides={"model": {"args": TINY_MODEL_ARGS["sanet-hit"]}}), rig=rig)
    local = build_model(cfg, rig=rig)
    c, h, code = 4, 8, 64
    features = 4 * 3 + 1 + 8  # 4 candidates x (depth, distance, valid), the count, 8 carved bins
    extra = (3 * c + c) + (code + 2 + c + features) * h + h + h * 2 + 2
    assert local.param_counts()["total"] == hit.param_counts()["total"] + extra


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_trains_and_completes(data, tmp_path, precision):
    res = train(
        "sanet-local", data, tmp_path, overrides=overrides(precision=precision), progress=False, log=lambda *a: None
    )
    assert len(res["history"]) == 2 and all(np.isfinite(r["train_loss"]) for r in res["history"])
    ckpt = load_checkpoint(tmp_path / "best.pt")
    model = model_from_checkpoint(ckpt)
    assert model.name == "sanet-local" and 0 < model.threshold < 1
    comp = Completer(model, ckpt, torch.device("cpu"))
    from spotlights.learning.data import TorchCompletionDataset

    ds = TorchCompletionDataset(data, "test", rig=False)
    partials = np.stack([ds[i]["partial"].numpy() for i in range(3)])
    with_free = comp.complete(partials, sensor_origins=ds.sensor_origins[:3])
    without = comp.complete(partials)
    assert len(with_free) == len(without) == 3
    # free space only removes or moves points: never more points with it
    assert all(len(a) <= len(b) for a, b in zip(with_free, without))
    assert all(np.linalg.norm(p, axis=1).max() <= 1 + 1e-5 for p in with_free if len(p))
    if precision == "fp32":  # no ONNX graph for it (yet): refused in one line, nothing written
        pytest.importorskip("onnx")
        pytest.importorskip("onnxscript")
        from spotlights.errors import ParameterError
        from spotlights.learning.export import export_onnx

        with pytest.raises(ParameterError, match="cannot be exported"):
            export_onnx(tmp_path / "best.pt", tmp_path / "local.onnx")
        assert not (tmp_path / "local.onnx").exists()


def test_old_datasets_train_old_models_and_refuse_the_new_one(old_data, tmp_path):
    res = train(
        "sanet-hit",
        old_data,
        tmp_path / "hit",
        overrides={**overrides(), "model": {"args": TINY_MODEL_ARGS["sanet-hit"]}},
        progress=False,
        log=lambda *a: None,
    )
    assert len(res["history"]) == 2
    proc = run_cli(
        "train",
        "--model",
        "sanet-local",
        "--data",
        old_data,
        "--out",
        tmp_path / "local",
        "--epochs",
        "1",
        "--rig",
        "cap-8x16-60",
    )
    assert_user_error(proc, str(old_data), "sensor origin", "sanet-local")
    assert not (tmp_path / "local" / "last.pt").exists()


def test_mirror_encodes_the_points_and_their_mirror_image():
    torch.manual_seed(0)
    enc = PCNEncoder(16, (8, 16, 32))
    p = torch.rand(2, 40, 3) - 0.5
    flipped = p * torch.tensor([1.0, -1.0, 1.0])
    by_hand = enc(torch.cat([p, flipped], 1))  # the plain encoder on the 80 points
    enc.mirror = True
    assert torch.allclose(enc(p), by_hand)
    assert torch.allclose(enc(p), enc(flipped), atol=1e-6)  # a mirrored scan gives the same code
    # the config key reaches every model, and is off by default
    for name in ("sanet", "pcn", "foldingnet", "topnet", "atlasnet", "sanet-hit", "sanet-local"):
        args = TINY_MODEL_ARGS.get(name, TINY_LOCAL)
        cfg = load_config(name, overrides={"model": {"args": dict(args), "mirror": True}})
        on = build_model(cfg, rig=make_rig(8, 16, 60.0))
        off = build_model(load_config(name, overrides={"model": {"args": dict(args)}}), rig=make_rig(8, 16, 60.0))
        assert on.encoder.mirror and not off.encoder.mirror


def test_scene_completion_gives_models_the_sensor_in_each_box_frame():
    """complete_scene hands a model that reads free space the LiDAR in each box's unit frame (by hand: the box's
    normalisation of the sensor position), the heading check's turned copy the turned sensor, and keeps the
    observed points after the predicted ones when asked."""
    from types import SimpleNamespace

    from spotlights.completion.frame import SceneConfig, complete_scene
    from spotlights.geometry.boxes import Box

    seen = {}

    class Recorder:
        model = SimpleNamespace(uses_evidence=True)
        needs_box = False
        model_name = "recorder"
        domain = None

        def complete(self, partials, clip=None, extents=None, sensor_origins=None):
            seen["sensor"] = np.array(sensor_origins)
            return [np.array([[0.1, 0.0, 0.0]], np.float32) for _ in partials]

    rng = np.random.default_rng(0)
    centre, size, yaw = np.array([9.0, 4.0, -0.9]), np.array([4.5, 1.8, 1.5]), 0.3
    box = Box(centre, size, yaw, "car", "car")
    scan = centre + rng.uniform(-0.4, 0.4, (200, 3)) * size
    sensor = np.array([0.2, -0.1, 1.7])
    res = complete_scene(scan, [box], Recorder(), SceneConfig(heading_check=True, keep_observed=True), sensor=sensor)
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    want = (sensor - centre) @ rot / (0.5 * np.linalg.norm(size))
    assert np.allclose(seen["sensor"][0], want, atol=1e-9)
    assert np.allclose(seen["sensor"][1], want * [-1, -1, 1], atol=1e-9)  # turned by 180 degrees about z
    obj = res.objects[0]
    assert len(obj.completion_unit) == 1 + len(np.unique(obj.partial_unit, axis=0))
