"""Synthetic completion dataset: ground truth, partial scans, determinism, resume, splits, CLI, bad input."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh

from spotlights.cli import main
from spotlights.data import synthetic
from spotlights.data.lidar import hdl64e
from spotlights.data.store import open_dataset
from spotlights.data.synthetic import BuildConfig, assign_splits, build_dataset, parse_rig, parse_split
from spotlights.errors import ParameterError, SpotlightsError
from spotlights.geometry.encode import encode_mesh
from spotlights.geometry.io import load_mesh

from builders import BOXES, build_reference, small_cfg, write_box_meshes
from helpers import CARS, need, src_pythonpath

ROOT = Path(__file__).resolve().parents[1]


def box_distance(p, center, half):
    """Exact distance of points to the surface of an axis-aligned box."""
    q = np.abs(p - center) - half
    return np.abs(np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(np.max(q, axis=1), 0.0))


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    """Three small models in two categories (sub-folders)."""
    return write_box_meshes(tmp_path_factory.mktemp("meshes"))


def read_all(path):
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda n, o: out.__setitem__(n, o[()]) if isinstance(o, h5py.Dataset) else None)
        out["attrs"] = {k: f.attrs[k] for k in f.attrs}
    return out


def sha(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def reference(meshes, tmp_path_factory):
    return build_reference(meshes, tmp_path_factory.mktemp("ref") / "ref.h5")


def test_schema_and_ground_truth_match_core_and_closed_form(reference, meshes):
    with h5py.File(reference, "r") as f:
        assert f.attrs["format"] == "spotlights-completion" and f.attrs["format_version"] == 1
        assert f.attrs["default_rig"] == "cap-32x64-60" and f.attrs["seed"] == 3
        cfg = json.loads(f.attrs["config_json"])
        assert cfg["views"] == 6 and json.loads(f.attrs["sensor_json"])["n_beams"] == 64
        names = [x.decode() for x in f["models/name"][()]]
        assert names == ["blobs/ellipsoid", "boxes/box_a", "boxes/box_b"]
        assert f["models/gt_points"].shape == (3, 2048, 3) and f["models/gt_points"].dtype == np.float32
        assert f["models/gt_dense"].shape == (3, 16384, 3)
        assert f["samples/partial"].shape == (18, 256, 3) and f["samples/partial"].chunks == (1, 256, 3)
        assert f["samples/sensor_to_unit"].shape == (18, 4, 4) and f["samples/sensor_to_unit"].dtype == np.float64
        assert list(f["samples/model"][()]) == [0] * 6 + [1] * 6 + [2] * 6
        assert list(f["samples/view"][()]) == list(range(6)) * 3
        assert json.loads(f["rigs/cap-64x32-60"].attrs["rig_json"])["n_primary"] == 64
        with open_dataset(reference) as ds:
            rig = ds.rig()
        for m in range(len(names)):
            file = f["models/file"][m].decode()
            mesh = load_mesh(meshes / file)
            # Ground-truth depths = the core's encoding of the mesh, normalised by its box.
            assert np.array_equal(f["rigs/cap-32x64-60/depths"][m], encode_mesh(mesh, rig))
            lo, hi = mesh.bounds
            assert np.allclose(f["models/center"][m], (lo + hi) / 2)
            assert f["models/radius"][m] == pytest.approx(np.linalg.norm(hi - lo) / 2)
            if file in BOXES:
                ext, c = BOXES[file]
                r = np.linalg.norm(ext) / 2
                half = np.array(ext) / 2 / r
                # Closed form: slab intersection of every rig ray with the box in the unit frame.
                o, d = rig.origins, rig.directions
                with np.errstate(divide="ignore"):
                    t1, t2 = (-half - o) / d, (half - o) / d
                tmin = np.max(np.minimum(t1, t2), axis=1)
                tmax = np.min(np.maximum(t1, t2), axis=1)
                expect = np.where(tmax >= tmin, tmin / 2, 0.0)
                assert np.allclose(f["rigs/cap-32x64-60/depths"][m], expect, atol=2e-6)
                # Surface samples lie on the box surface.
                for key in ("gt_points", "gt_dense"):
                    assert box_distance(f[f"models/{key}"][m], 0.0, half).max() < 1e-5


def test_partials_lie_on_the_surface_facing_the_sensor(meshes, tmp_path):
    # Noise-free build: strict checks of surface and visibility.
    out = tmp_path / "clean.h5"
    cfg = small_cfg(meshes, sensor=hdl64e(range_noise=0.0).to_dict(), views=8)
    build_dataset(cfg, out, workers=1, progress=False, log=lambda m: None)
    with open_dataset(out) as ds:
        for i in range(ds.n_samples):
            s = ds.sample(i)
            p = s["partial"].astype(np.float64)
            assert p.shape == (256, 3) and np.linalg.norm(p, axis=1).max() <= 1.0
            file = s["model"] + (".ply" if "box_a" in s["model"] else ".obj")
            if not s["model"].startswith("boxes/"):
                continue
            ext, _ = BOXES[file]
            r = np.linalg.norm(ext) / 2
            half = np.array(ext) / 2 / r
            assert box_distance(p, 0.0, half).max() < 1e-5
            sensor = s["sensor_to_unit"][:3, 3]  # sensor origin in the unit frame
            q = p / half
            axis = np.argmax(np.abs(q), axis=1)
            normal = np.zeros_like(p)
            normal[np.arange(256), axis] = np.sign(q[np.arange(256), axis])
            assert np.all(np.einsum("ij,ij->i", normal, sensor - p) > 0), "a point on a face turned away"
            # The sensor sits at mount height above the ground, which is the box bottom.
            assert (sensor[2] + half[2]) * r == pytest.approx(1.73, abs=1e-6)
            assert np.hypot(*(sensor[:2] * r)) == pytest.approx(s["distance"], rel=1e-5)


def test_partials_within_noise_of_the_surface(reference):
    with open_dataset(reference) as ds:
        for i in np.flatnonzero(np.char.startswith(ds.names[ds.sample_model], "boxes/")):
            s = ds.sample(int(i))
            file = s["model"] + (".ply" if "box_a" in s["model"] else ".obj")
            ext, _ = BOXES[file]
            r = np.linalg.norm(ext) / 2
            d = box_distance(s["partial"].astype(np.float64) * r, 0.0, np.array(ext) / 2)  # metres
            assert d.max() < 5 * 0.02 and s["n_raw"] >= 50


def test_same_arrays_and_bytes_whatever_the_workers(meshes, reference, tmp_path):
    out = tmp_path / "w2.h5"
    build_dataset(small_cfg(meshes), out, workers=2, block=2, progress=False, log=lambda m: None)
    a, b = read_all(reference), read_all(out)
    assert a.keys() == b.keys()
    for k in a:
        if k != "attrs":
            assert np.array_equal(a[k], b[k]), k
    assert a["attrs"] == b["attrs"]
    assert sha(reference) == sha(out)


def test_resume_after_an_interruption(meshes, reference, tmp_path, monkeypatch):
    out = tmp_path / "int.h5"
    parts = Path(str(out) + ".parts")
    real = synthetic.runner.compute_unit  # the public per-unit computation the build calls
    calls = {"n": 0}

    def dying(*args, **kwargs):
        if calls["n"] == 7:
            raise KeyboardInterrupt
        calls["n"] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr(synthetic.runner, "compute_unit", dying)
    with pytest.raises(KeyboardInterrupt):
        build_dataset(small_cfg(meshes), out, workers=1, block=1, progress=False, log=lambda m: None)
    monkeypatch.setattr(synthetic.runner, "compute_unit", real)
    assert not out.exists() and len(list(parts.glob("*.npz"))) == 7
    (parts / ".obs-00001-0000003-0000004.npz.abc.part.npz").write_bytes(b"half a shard")  # a killed write
    rep = build_dataset(small_cfg(meshes), out, workers=1, block=1, progress=False, log=lambda m: None)
    assert rep.units_done_before == 7 and rep.units_computed == rep.units_total - 7
    assert not parts.exists()
    a, b = read_all(reference), read_all(out)
    for k in a:
        if k != "attrs":
            assert np.array_equal(a[k], b[k]), k


@pytest.mark.slow
def test_resume_after_sigkill(meshes, tmp_path):
    """Kill a real build process mid-way, start it again: it finishes, equal to an uninterrupted build."""
    out = tmp_path / "kill.h5"
    parts = Path(str(out) + ".parts")
    cmd = [
        sys.executable,
        "-m",
        "spotlights",
        "dataset",
        "build",
        "--meshes",
        str(meshes),
        "--out",
        str(out),
        "--views",
        "40",
        "--split",
        "1/1/1",
        "--seed",
        "5",
        "--block",
        "1",
        "--workers",
        "2",
        "--quiet",
        "--gt-dense",
        "4096",
    ]
    env = {**os.environ, "PYTHONPATH": src_pythonpath()}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 60
    killed = False
    while time.time() < deadline and proc.poll() is None:
        if parts.exists() and len(list(parts.glob("obs-*.npz"))) >= 6:
            os.killpg(proc.pid, signal.SIGKILL)
            killed = True
            break
        time.sleep(0.005)
    proc.wait()
    if killed:
        assert not out.exists()
        done = len([p for p in parts.glob("*.npz") if not p.name.startswith(".")])
        r = subprocess.run(cmd, env=env, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        assert "resuming" in r.stderr and f"{done} of" in r.stderr
    assert out.exists() and not parts.exists()
    ref = tmp_path / "ref.h5"
    cfg = BuildConfig(meshes=str(meshes), views=40, split="1/1/1", seed=5, gt_dense=4096)
    build_dataset(cfg, ref, workers=1, progress=False, log=lambda m: None)
    assert sha(ref) == sha(out)


def test_splits_are_disjoint_by_model(reference):
    with open_dataset(reference) as ds:
        sets = {s: set(ds.names[ds.split_models(s)]) for s in ("train", "val", "test")}
        assert sets["train"].isdisjoint(sets["val"]) and sets["train"].isdisjoint(sets["test"])
        assert sets["val"].isdisjoint(sets["test"])
        assert set().union(*sets.values()) == set(ds.names)
        for s in sets:
            idx = ds.split_indices(s)
            assert set(ds.names[ds.sample_model[idx]]) == sets[s] and len(idx) == 6 * len(sets[s])


def test_split_assignment_is_exact_stratified_and_seeded():
    cats = ["hatchback"] * 15 + ["sedan"] * 30 + ["suv"] * 34
    for spec in ("64/8/7", "0.81/0.1/0.09"):
        a = assign_splits(cats, spec, seed=0)
        assert [a.count(s) for s in ("train", "val", "test")] == [64, 8, 7]
        for c, n in (("hatchback", 15), ("sedan", 30), ("suv", 34)):
            got = [sum(1 for x, y in zip(a, cats) if x == s and y == c) for s in ("train", "val", "test")]
            assert all(abs(g - n * k / 79) <= 1 for g, k in zip(got, (64, 8, 7))), (c, got)
    assert assign_splits(cats, "64/8/7", 0) == assign_splits(cats, "64/8/7", 0)
    assert assign_splits(cats, "64/8/7", 0) != assign_splits(cats, "64/8/7", 1)
    assert [assign_splits(cats, "0.8/0.1/0.1", 0).count(s) for s in ("train", "val", "test")] == [63, 8, 8]
    with pytest.raises(ParameterError, match="adds up to 80"):
        assign_splits(cats, "64/8/8", 0)
    with pytest.raises(ParameterError):
        parse_split("0.5/0.2/0.2")
    assert parse_split("64/8/7") == ("counts", [64, 8, 7])
    assert parse_rig("64x32@60").name == "cap-64x32-60" and parse_rig("256x64").name == "cap-256x64-60"
    assert parse_rig("cap-32x64-45").angle == 45
    with pytest.raises(ParameterError):
        parse_rig("32*64")


def test_cli_info_export_show(reference, tmp_path, capsys):
    assert main(["dataset", "info", str(reference), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["n_models"] == 3 and info["n_samples"] == 18 and info["views_per_model"] == 6
    assert sum(d["models"] for d in info["splits"].values()) == 3
    assert info["datasets"]["/samples/partial"]["shape"] == [18, 256, 3]
    assert set(info["rigs"]) == {"cap-32x64-60", "cap-64x32-60"}
    assert main(["dataset", "info", str(reference)]) == 0
    assert "train" in capsys.readouterr().out
    out = tmp_path / "s.npz"
    assert main(["dataset", "export", str(reference), "--split", "val", "--index", "2", "--out", str(out)]) == 0
    with np.load(out) as z:
        assert z["partial"].shape == (256, 3) and z["partial"].dtype == np.float32
        assert z["gt_points"].shape == (2048, 3) and z["gt_dense"].shape == (16384, 3)
        assert z["gt_depths"].shape == (2048,) and z["gt_depths"].dtype == np.float32
        assert str(z["split"]) == "val" and int(z["view"]) == 2
        with open_dataset(reference) as ds:
            m = ds.split_models("val")[0]
            assert str(z["model"]) == ds.names[m] and str(z["category"]) == ds.categories[m]
    png = tmp_path / "s.png"
    assert main(["dataset", "show", str(reference), "--split", "train", "--index", "0", "--out", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["dataset", "export", str(reference), "--split", "test", "--index", "6", "--out", str(out)]) == 2
    assert "out of range" in capsys.readouterr().err


def test_bad_input(meshes, reference, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["dataset", "build", "--meshes", str(empty), "--out", str(tmp_path / "x.h5"), "-q"]) == 2
    assert "no mesh files" in capsys.readouterr().err
    assert main(["dataset", "build", "--meshes", str(tmp_path / "nope"), "--out", str(tmp_path / "x.h5"), "-q"]) == 2
    assert "no such folder" in capsys.readouterr().err
    # An unreadable mesh among good ones is skipped, reported, and listed in the file.
    mixed = tmp_path / "mixed"
    for rel in BOXES:
        (mixed / rel).parent.mkdir(parents=True, exist_ok=True)
        (mixed / rel).write_bytes((meshes / rel).read_bytes())
    (mixed / "boxes" / "broken.ply").write_text("ply\nthis is not a mesh\n")
    out = tmp_path / "mixed.h5"
    args = ["dataset", "build", "--meshes", str(mixed), "--out", str(out), "--views", "2", "--split", "1/1/1", "-q"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "broken.ply" in err and "adds up to 3 models but there are 2 usable meshes" in err
    assert main(args[:-3] + ["--split", "1/1/0", "-q"]) == 0
    cap = capsys.readouterr()
    assert "warning: skipping" in cap.err and "broken.ply" in cap.err and cap.out == ""  # -q: no summary lines
    with open_dataset(out) as ds:
        assert [s["file"] for s in ds.info()["skipped"]] == ["boxes/broken.ply"]
    # An existing output is never replaced silently.
    before = sha(out)
    assert main(args[:-3] + ["--split", "1/1/0", "-q"]) == 2
    assert "--overwrite" in capsys.readouterr().err and sha(out) == before
    assert main(args[:-3] + ["--split", "1/1/0", "--resume"]) == 0  # (without -q: -q silences this line too)
    assert "nothing to do" in capsys.readouterr().out
    assert main(args[:-3] + ["--split", "1/0/1", "-q", "--overwrite"]) == 0
    # Unfinished parts of another configuration are not mixed in.
    parts = tmp_path / "other.h5.parts"
    parts.mkdir()
    (parts / "plan.json").write_text(
        json.dumps({"plan_version": 1, "config": {"views": 99}, "models": [], "skipped": []})
    )
    assert (
        main(
            [
                "dataset",
                "build",
                "--meshes",
                str(meshes),
                "--out",
                str(tmp_path / "other.h5"),
                "--split",
                "1/1/1",
                "--views",
                "2",
                "-q",
            ]
        )
        == 2
    )
    assert "another plan" in capsys.readouterr().err
    with pytest.raises(SpotlightsError):
        open_dataset(tmp_path / "s-missing.h5")
    (tmp_path / "not.h5").write_text("hello")
    assert main(["dataset", "info", str(tmp_path / "not.h5")]) == 2
    assert "not a readable HDF5" in capsys.readouterr().err
    with pytest.raises(ParameterError):
        small_cfg(meshes, views=0).validate()


def test_up_and_forward_axes_from_a_manifest(tmp_path):
    """A Y-up, Z-forward glTF file is brought into the object frame (x forward, y left, z up)."""
    root = tmp_path / "gl"
    root.mkdir()
    m = trimesh.creation.box(extents=(1.8, 1.5, 4.5))  # source: x left-right, y up, z forward
    m.export(root / "car.glb")
    m2 = trimesh.creation.box(extents=(4.5, 1.8, 1.5))
    m2.export(root / "plain.ply")
    (root / "manifest.csv").write_text("file,category,up,forward\ncar.glb,van,y,z\nplain.ply,van,,\n")
    out = tmp_path / "gl.h5"
    build_dataset(
        BuildConfig(meshes=str(root), views=2, split="2/0/0", gt_dense=1024),
        out,
        workers=1,
        progress=False,
        log=lambda m: None,
    )
    with h5py.File(out, "r") as f:
        assert np.allclose(f["models/size"][()], [[4.5, 1.8, 1.5], [4.5, 1.8, 1.5]])
        assert [c.decode() for c in f["models/category"][()]] == ["van", "van"]
        assert np.allclose(f["rigs/cap-32x64-60/depths"][0], f["rigs/cap-32x64-60/depths"][1], atol=1e-6)


def test_real_cars(tmp_path):
    need(CARS)
    root = tmp_path / "cars"
    for rel in ("sedan/037-CAR02.ply", "suv/019-SUV.ply"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).symlink_to((CARS / rel).resolve())
    out = tmp_path / "cars.h5"
    build_dataset(
        BuildConfig(meshes=str(root), views=8, split="1/1/0"), out, workers=2, progress=False, log=lambda m: None
    )
    with open_dataset(out) as ds:
        assert sorted(set(ds.categories)) == ["sedan", "suv"]
        for m in range(2):
            mesh = load_mesh(root / (ds.names[m] + ".ply"))
            assert np.array_equal(ds.ground_truth(m)["gt_depths"], encode_mesh(mesh, ds.rig()))
        for i in range(ds.n_samples):
            s = ds.sample(i)
            assert s["n_raw"] >= 50 and np.linalg.norm(s["partial"], axis=1).max() < 1.0
            assert 4.0 <= s["distance"] <= 40.0


def test_completion_goes_back_to_the_sensor_frame(reference):
    """to_sensor inverts sensor_to_unit: the box's centre maps to the stored distance and bearing,
    and its bottom onto the ground plane z = -1.73 m."""
    with open_dataset(reference) as ds:
        for i in (0, 7, 17):
            s = ds.sample(i)
            c = ds.to_sensor(i, np.zeros((1, 3)))[0]
            assert np.hypot(c[0], c[1]) == pytest.approx(s["distance"], rel=1e-5)
            assert np.arctan2(c[1], c[0]) == pytest.approx(s["azimuth"], abs=1e-5)
            gt = ds.to_sensor(i, s["gt_dense"])
            assert gt[:, 2].min() == pytest.approx(-1.73, abs=0.02)
            back = (s["sensor_to_unit"] @ np.c_[gt, np.ones(len(gt))].T).T[:, :3]
            assert np.allclose(back, s["gt_dense"], atol=1e-5)


def test_sensor_origin_round_trips_to_the_training_batches(reference):
    """The LiDAR's origin in each sample's unit frame, by hand from the pose (box centre at distance and bearing
    on the ground z = -1.73 m, yaw heading) equals the reader's sensor_origins and the torch items' sensor_origin."""
    import torch

    from spotlights.learning.data import TorchCompletionDataset

    with open_dataset(reference) as ds:
        meta = ds.metadata()
        got = ds.sensor_origins()
        assert got.shape == (ds.n_samples, 3)
        for i in range(ds.n_samples):
            m = int(ds.sample_model[i])
            dist, az, yaw = (float(meta[k][i]) for k in ("distance", "azimuth", "heading"))
            centre = np.array([dist * np.cos(az), dist * np.sin(az), -1.73 + ds.size[m][2] / 2])
            rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
            want = (np.zeros(3) - centre) @ rot / ds.radius[m]
            assert np.allclose(got[i], want, atol=1e-5)
    train = TorchCompletionDataset(reference, "train", rig=False)
    assert train.has_sensor_origin
    with open_dataset(reference) as ds:
        want = ds.sensor_origins(train.indices)
    for j in (0, len(train) - 1):
        item = train[j]
        assert item["sensor_origin"].dtype == torch.float32
        assert np.allclose(item["sensor_origin"].numpy(), want[j], atol=1e-6)
