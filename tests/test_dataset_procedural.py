"""``dataset build --procedural``: generated vehicles as a mesh source, the class of every model."""

from __future__ import annotations

import hashlib
import shutil

import h5py
import numpy as np
import pytest
import trimesh

from spotlights.data.store import open_dataset
from spotlights.data.synthetic import BuildConfig, add_rig, build_dataset, parse_rig
from spotlights.data.synthetic.catalogue import model_key
from spotlights.data.synthetic.procedural import box_range, generate_vehicle, mesh_digest
from spotlights.geometry.encode import encode_mesh

from helpers import assert_user_error, run_cli

TINY = ["--views", "3", "--gt-points", "64", "--gt-dense", "256", "--quiet", "--seed", "4"]


def sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """The same tiny procedural build twice: by the CLI with one worker, and in this process with two
    workers and one view per work unit (the configuration the CLI stored)."""
    root = tmp_path_factory.mktemp("proc")
    out = root / "w1.h5"
    proc = run_cli(
        "dataset", "build", "--procedural", "2", "--classes", "truck,car,bus,trailer,van",
        "--out", out, "--workers", 1, *TINY,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    with open_dataset(out) as ds:
        cfg = BuildConfig.from_dict(ds.config)
    build_dataset(cfg, root / "w2.h5", workers=2, block=1, progress=False, log=lambda m: None)
    return {1: out, 2: root / "w2.h5"}


def test_procedural_build_same_bytes_whatever_the_workers(built):
    assert sha(built[1]) == sha(built[2])


def test_procedural_build_stores_the_class_of_every_sample(built):
    with h5py.File(built[1], "r") as f:
        assert "class" in f["models"]
    with open_dataset(built[1]) as ds:
        # two vehicles per class, body types taking turns through the class's bodies
        expect = {
            "car": ["sedan", "hatchback"],
            "caravan": ["van", "minibus"],  # asked for as "van"
            "truck": ["box_truck", "semi_tractor"],
            "bus": ["bus", "articulated_bus"],
            "trailer": ["trailer_box", "trailer_flatbed"],
        }
        names = [f"procedural/{c}/{b}-{i:04d}" for c, bodies in expect.items() for i, b in enumerate(bodies)]
        assert list(ds.names) == names
        assert list(ds.classes) == [n.split("/")[1] for n in names]
        assert list(ds.categories) == [n.split("/")[2][:-5] for n in names]
        assert ds.n_samples == 10 * 3
        for i in range(ds.n_samples):
            s = ds.sample(i)
            assert s["class"] == s["model"].split("/")[1]
        for m, name in enumerate(ds.names):
            body = ds.categories[m]
            for k, key in enumerate(("length", "width", "height")):
                lo, hi = box_range(body, key)
                assert lo - 1e-9 <= ds.size[m][k] <= hi + 1e-9
            # the documented seed: SeedSequence(seed, spawn_key=(model_key(name), 7)); the mesh's bytes hashed
            v, f, _ = generate_vehicle(body, np.random.SeedSequence(4, spawn_key=(model_key(str(name)), 7)))
            assert ds.models_array("sha256", [m])[0].decode() == mesh_digest(v, f)
            np.testing.assert_allclose(ds.size[m], v.max(0) - v.min(0))


def test_add_rig_regenerates_the_vehicles(built, tmp_path):
    """``dataset add-rig`` on a procedural dataset generates the meshes again (checked against their
    stored hashes) and stores the depths the core's encoder gives each regenerated vehicle."""
    path = tmp_path / "copy.h5"
    shutil.copyfile(built[1], path)
    add_rig(path, "8x8@60", workers=1, progress=False, log=lambda m: None)
    rig = parse_rig("8x8@60")
    with open_dataset(path) as ds:
        depths = ds.rig_depths(rig.name)
        for m, name in enumerate(ds.names):
            v, f, _ = generate_vehicle(ds.categories[m], np.random.SeedSequence(4, spawn_key=(model_key(str(name)), 7)))
            mesh = trimesh.Trimesh(v, f, process=False)
            np.testing.assert_array_equal(depths[m], encode_mesh(mesh, rig))
        assert ds.info()["classes"] == {"bus": 2, "car": 2, "caravan": 2, "trailer": 2, "truck": 2}


def test_procedural_mixed_with_a_mesh_folder_and_old_files(tmp_path):
    root = tmp_path / "meshes"
    for cat, ext in (("suv", (4.6, 1.9, 1.7)), ("tractor", (3.5, 1.8, 2.5))):
        (root / cat).mkdir(parents=True)
        trimesh.creation.box(extents=ext).export(root / cat / f"{cat}-a.ply")
    out = tmp_path / "mixed.h5"
    proc = run_cli(
        "dataset", "build", "--meshes", f"{root},split=train", "--procedural", "1", "--classes", "bus",
        "--procedural-split", "test", "--out", out, "--workers", "1", *TINY,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    with open_dataset(out) as ds:
        got = {str(n): (str(c), str(s), str(src)) for n, c, s, src in zip(ds.names, ds.classes, ds.splits, ds.sources)}
    assert got == {
        "meshes/suv/suv-a": ("car", "train", "meshes"),
        "meshes/tractor/tractor-a": ("other", "train", "meshes"),  # a farm tractor is none of the classes
        "procedural/bus/bus-0000": ("bus", "test", "procedural"),
    }
    # a build without --procedural writes no class column (its bytes are those of before); its
    # classes come from the categories
    old = tmp_path / "old.h5"
    cfg = BuildConfig(meshes=str(root), views=3, split="2/0/0", seed=4, gt_points=64, gt_dense=256)
    build_dataset(cfg, old, workers=1, progress=False, log=lambda m: None)
    with h5py.File(old, "r") as f:
        assert "class" not in f["models"] and '"procedural"' not in f.attrs["config_json"]
    with open_dataset(old) as ds:
        assert list(ds.classes) == ["car", "other"] and ds.stored_classes is None
        assert ds.sample(0)["class"] == "car"


def test_procedural_bad_input(tmp_path):
    out = tmp_path / "x.h5"
    assert_user_error(run_cli("dataset", "build", "--out", out), "--meshes", "--procedural")
    assert_user_error(
        run_cli("dataset", "build", "--procedural", "1", "--classes", "car,plane", "--out", out), "plane", "bus"
    )
    assert_user_error(
        run_cli("dataset", "build", "--procedural", "1", "--procedural-split", "1/2", "--out", out), "split"
    )
    assert_user_error(
        run_cli("dataset", "build", "--meshes", tmp_path, "--classes", "bus", "--out", out), "--procedural"
    )
    assert not out.exists() and not (tmp_path / "x.h5.parts").exists()
