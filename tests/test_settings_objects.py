"""Settings objects: one strict policy for every config reader (an unknown key is one line
naming its file, with the closest key suggested; exit code 2 through the CLI), known keys round-trip,
and the options a command declares on its settings object are the object's defaults."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import h5py
import pytest
import trimesh

from spotlights.cli import build_parser
from spotlights.data.lidar import SensorModel, hdl64e, sensor_preset
from spotlights.data.synthetic import BuildConfig, BuildRequest, BuildSettings, build_dataset, config
from spotlights.errors import InputFileError, ParameterError
from spotlights.experiments.rig_study import RigStudySettings
from spotlights.learning.bench import BenchSettings
from spotlights.learning.evaluate import EvaluateSettings
from spotlights.learning.train import TrainSettings

from helpers import assert_user_error, run_cli

TINY = dict(views=2, split="1/1/1", seed=3, gt_points=64, gt_dense=256, default_rig="4x8@60", no_stratify=True)


@pytest.fixture(scope="module")
def meshes(tmp_path_factory) -> Path:
    """Three boxes (one per split) in one category folder, metres."""
    root = tmp_path_factory.mktemp("settings-meshes")
    (root / "cars").mkdir()
    for i, ext in enumerate([(4.5, 1.8, 1.5), (4.0, 1.7, 1.6), (3.6, 1.6, 1.4)]):
        trimesh.creation.box(extents=ext).export(root / "cars" / f"box{i}.ply")
    return root


def _yaml(path: Path, values: dict) -> Path:
    path.write_text(json.dumps(values))  # JSON is YAML
    return path


@pytest.fixture(scope="module")
def built(meshes, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("settings-built") / "tiny.h5"
    req = BuildRequest(meshes=[str(meshes)], out=str(out), **TINY)
    build_dataset(req.build_config(), out, req.settings(), progress=False, log=lambda m: None)
    return out


def test_build_yaml_unknown_key_is_one_line_with_a_suggestion(tmp_path):
    bad = _yaml(tmp_path / "build.yaml", {"view": 3})
    proc = run_cli("dataset", "build", "--config", bad, "--out", tmp_path / "x.h5")
    assert_user_error(proc, "build.yaml", "unknown setting 'view'", "(did you mean 'views'?)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["build.yaml"]  # nothing written
    proc = run_cli("dataset", "build", "--config", _yaml(tmp_path / "list.yaml", [1, 2]), "--out", tmp_path / "x.h5")
    assert_user_error(proc, "list.yaml", "expected a mapping")


def test_build_yaml_gives_the_options_bytes_and_the_command_line_wins(meshes, tmp_path):
    opts = ["--views", "2", "--split", "1/1/1", "--seed", "3", "--gt-points", "64", "--gt-dense", "256"]
    opts += ["--default-rig", "4x8@60", "--no-stratify", "--workers", "1", "-q"]
    assert run_cli("dataset", "build", "--meshes", meshes, "--out", tmp_path / "a.h5", *opts).returncode == 0
    y = _yaml(tmp_path / "b.yaml", {**TINY, "meshes": [str(meshes)], "workers": 1, "quiet": True})
    assert run_cli("dataset", "build", "--config", y, "--out", tmp_path / "b.h5").returncode == 0
    assert (tmp_path / "a.h5").read_bytes() == (tmp_path / "b.h5").read_bytes()
    assert run_cli("dataset", "build", "--config", y, "--seed", "4", "--out", tmp_path / "c.h5").returncode == 0
    with h5py.File(tmp_path / "c.h5", "r") as f:
        cfg = json.loads(f.attrs["config_json"])
    assert (cfg["seed"], cfg["views"], cfg["gt_dense"]) == (4, 2, 256)  # the command line's seed, the file's rest


def _with_config(src: Path, dst: Path, change) -> Path:
    dst.write_bytes(src.read_bytes())
    with h5py.File(dst, "r+") as f:
        cfg = json.loads(f.attrs["config_json"])
        change(cfg)
        f.attrs["config_json"] = json.dumps(cfg)
    return dst


def test_unknown_keys_in_a_datasets_config_and_sensor_through_the_cli(built, meshes, tmp_path):
    typo = _with_config(built, tmp_path / "typo.h5", lambda c: c.update(gt_dens=c.pop("gt_dense")))
    proc = run_cli("dataset", "add-rig", typo, "--rig", "8x4@60", "--meshes", meshes, "-q")
    assert_user_error(proc, "typo.h5", "unknown setting 'gt_dens'", "(did you mean 'gt_dense'?)")
    sensor = _with_config(built, tmp_path / "sensor.h5", lambda c: c["sensor"].update(mount_heigth=1.7))
    proc = run_cli("dataset", "add-rig", sensor, "--rig", "8x4@60", "--meshes", meshes, "-q")
    assert_user_error(proc, "sensor.h5 (sensor)", "unknown setting 'mount_heigth'", "(did you mean 'mount_height'?)")
    for path in (typo, sensor):  # the files are untouched
        with h5py.File(path, "r") as f:
            assert "rigs/cap-8x4-60" not in f


def test_known_keys_round_trip_and_unknown_ones_are_refused():
    cfg = BuildConfig(meshes="m", views=5, split="2/1/1", mount_height_range=(1.5, 2.1), exclude_categories=["suv"])
    assert BuildConfig.from_dict(cfg.to_dict()).to_dict() == cfg.validate().to_dict()
    sensor = sensor_preset("vlp16", mount_height=1.9)
    assert SensorModel.from_dict(sensor.to_dict()) == sensor
    assert SensorModel.from_dict({"n_beams": 16}).n_beams == 16
    with pytest.raises(ParameterError, match=r"^sensor: unknown setting 'beams' \(did you mean 'n_beams'\?\)"):
        SensorModel.from_dict({"beams": 16})
    with pytest.raises(InputFileError, match=r"unknown setting 'view' \(did you mean 'views'\?\)"):
        BuildConfig.from_dict({"meshes": "m", "view": 3}, "cars.h5")
    assert BuildSettings.from_dict({"workers": 3, "shard_size": 10}) == BuildSettings(workers=3, shard_size=10)
    with pytest.raises(ParameterError, match="did you mean 'workers'"):
        BuildSettings.from_dict({"worker": 3}, "build")
    ts = TrainSettings.from_dict({"model": "pcn", "data": "d.h5", "epochs": 3})
    assert (ts.epochs, ts.run_dir) == (3, Path("runs/pcn"))
    with pytest.raises(ParameterError, match="did you mean 'epochs'"):
        TrainSettings.from_dict({"model": "pcn", "data": "d.h5", "epoch": 3}, "train")
    assert EvaluateSettings.from_dict({"checkpoint": ["a.pt"], "data": "d.h5"}).batch_size == 32


def test_an_older_files_config_reads_and_retired_keys_are_dropped_by_name(monkeypatch):
    """A config written before the options after ``stratify`` existed reads with their defaults; a key
    listed in RETIRED_KEYS (none so far) is dropped, any other unknown key stays an error."""
    old = {"meshes": "m", "manifest": None, "views": 4, "split": "1/1/1", "seed": 0, "n_points": 256, "gt_points": 2048}
    old |= {"gt_dense": 16384, "default_rig": "cap-32x64-60", "extra_rigs": [], "sensor": hdl64e().to_dict()}
    old |= {"distance": [4.0, 40.0], "min_points": 50, "max_draws": 100, "downsample": "random"}
    old |= {"up": "z", "forward": "x", "scale": 1.0, "stratify": True}
    assert BuildConfig.from_dict(old).to_dict() == old
    monkeypatch.setitem(config.RETIRED_KEYS, "jitter", "an option of an older version")
    assert BuildConfig.from_dict({**old, "jitter": 0.1}).to_dict() == old
    with pytest.raises(ParameterError, match="unknown setting 'jiter'"):
        BuildConfig.from_dict({**old, "jiter": 0.1})


def test_train_settings_merge_the_single_key_options_by_hand():
    ts = TrainSettings("pcn", "d.h5", epochs=3, workers=0, compile=False)
    assert ts.config_overrides() == {"train": {"epochs": 3, "compile": False}, "data": {"num_workers": 0}}
    base = {"model": {"args": {"code_size": 8}}, "train": {"lr": 0.5, "epochs": 9}}
    merged = TrainSettings("pcn", "d.h5", overrides=base, epochs=3).config_overrides()
    assert merged == {"model": {"args": {"code_size": 8}}, "train": {"lr": 0.5, "epochs": 3}, "data": {}}
    assert TrainSettings("pcn", "d.h5", overrides=base).config_overrides() is base
    assert TrainSettings("pcn", "d.h5", out="r/x").run_dir == Path("r/x")


@pytest.mark.parametrize(
    "argv, cls, given",
    [
        (["dataset", "build", "--out", "x.h5"], BuildRequest, {"out": "x.h5"}),
        (
            ["evaluate", "--data", "d.h5", "--checkpoint", "a.pt"],
            EvaluateSettings,
            {"data": "d.h5", "checkpoint": ["a.pt"]},
        ),
        (["bench", "models"], BenchSettings, {}),
        (["train", "--model", "pcn", "--data", "d.h5"], TrainSettings, {"model": "pcn", "data": "d.h5"}),
        (["study", "rigs", "--out", "s"], RigStudySettings, {"out": "s"}),
    ],
)
def test_a_commands_defaults_are_its_settings_objects(argv, cls, given):
    args = build_parser().parse_args(argv)
    parsed = cls(**{f.name: getattr(args, f.name) for f in dataclasses.fields(cls) if hasattr(args, f.name)})
    assert parsed == cls(**given)
