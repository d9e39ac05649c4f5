"""The GPU recipe (scripts/gpu_train.sh) on a training set of every class: extra mesh sources and procedural
vehicles (``--source``, ``--procedural``), a class-conditioned per-viewpoint model, at a tiny scale on the CPU."""

from __future__ import annotations

import json

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("embreex")

from helpers import assert_user_error, load_script  # noqa: E402
from learning_fixtures import TINY_MODEL_ARGS, run_gpu_script, write_category_shapes  # noqa: E402


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    return write_category_shapes(tmp_path_factory.mktemp("gpu-union-meshes"))


@pytest.mark.slow  # a dataset build of 20 models and a few training steps (seconds)
@pytest.mark.timeout(300)
def test_a_union_run_trains_a_class_conditioned_viewpoint_model_on_every_source(tmp_path, meshes):
    from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint

    args = {**TINY_MODEL_ARGS["sanet-hit"], "viewpoint_code": 4, "classes": ["car", "truck", "trailer"]}
    cfg = tmp_path / "wide.yaml"
    cfg.write_text(json.dumps({"model": {"name": "sanet-hit", "args": args}, "data": {"rig": "box-4x8-ellipsoid-s1"}}))
    out = tmp_path / "out"
    proc = run_gpu_script(
        tmp_path, cfg, 60, "--cpu", "--meshes", meshes, "--split", "3/3/3", "--views", 2,
        "--source", f"{meshes},split=train,name=extra", "--procedural", 1, "--classes", "truck,trailer",
        "--procedural-split", "train", "--steps", 4, "--intervals", 2, "--batch-size", 4, "--probe-steps", 1,
        "--val-views", 1, "--workers", 1, "--out", out, "--work", tmp_path / "work",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr + proc.stdout
    plan = json.loads((out / "plan.json").read_text())
    # 9 carried meshes (3/3/3) + the same 9 again as a training source + 1 truck and 1 trailer, 2 views each
    assert plan["dataset"]["samples"] == (9 + 9 + 2) * 2 and plan["dataset"]["path"].endswith("union.h5")
    assert plan["steps_done"] == 4
    ck = load_checkpoint(out / "best.pt")
    assert ck["config"]["model"]["args"]["viewpoint_code"] == 4
    assert {"truck", "trailer", "car"} <= set(ck["domain"]["classes"])
    model = model_from_checkpoint(ck)
    assert type(model.decoder).__name__ == "ViewpointDecoder"
    assert model(torch.rand(2, 30, 3) - 0.5)["depths"].shape == (2, 4 * 8)


def test_bad_union_inputs_exit_2_with_one_line(tmp_path, meshes, capsys, monkeypatch):
    gpu = load_script("scripts/gpu_train.py")
    monkeypatch.delenv("OUT", raising=False)
    base = ["pcn", "1", "--cpu", "--meshes", str(meshes), "--out", str(tmp_path / "o")]
    for extra, message in (
        (["--procedural", "-1"], "--procedural must be 0..10000"),
        (["--procedural", "10001"], "--procedural must be 0..10000"),
        (["--source", str(tmp_path / "nothing")], "no such mesh folder (--source)"),
        (["--procedural", "2", "--classes", "car,spaceship"], "spaceship"),
    ):
        assert gpu.main(base + extra) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0] and err[0].startswith("gpu_train: error:"), err
    assert not (tmp_path / "o").exists()  # refused before any work
    proc = run_gpu_script(tmp_path, "pcn", 1, "--cpu", "--meshes", meshes, "--procedural", -1, "--out", tmp_path / "o")
    assert_user_error(proc, "--procedural must be 0..10000")


def test_a_source_may_name_a_folder_of_the_carried_meshes(tmp_path, monkeypatch):
    """``--source kenney-vehicles,...`` on the GPU machine: the folder gpu_train.sh unpacked the carried meshes into
    (``$GPU_MESH_DIR``); a folder that exists as given, or a name not carried, stays as it is."""
    gpu = load_script("scripts/gpu_train.py")
    carried = tmp_path / "carried"
    (carried / "kenney-vehicles").mkdir(parents=True)
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("GPU_MESH_DIR", str(carried))
    assert (
        gpu.carried_source("kenney-vehicles,split=train,name=k") == f"{carried / 'kenney-vehicles'},split=train,name=k"
    )
    assert gpu.carried_source("here,split=test") == "here,split=test"
    assert gpu.carried_source("nothing") == "nothing"
    monkeypatch.delenv("GPU_MESH_DIR")
    assert gpu.carried_source("kenney-vehicles") == "kenney-vehicles"
