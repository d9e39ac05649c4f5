"""Scale-out: the Ray backend (byte-identical to local, resume after a killed driver, failures),
sharded datasets (read back equal to one file, merge, add-rig), metrics on Ray, Ray missing."""

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

from ray_cases import CASES, MESHES, build_argv, cfg
from spotlights.cli import main
from spotlights.data.store import open_dataset, write_rig_group
from spotlights.data.synthetic import add_rig, build_dataset, parse_rig
from spotlights.data.synthetic.consolidate import merge_shards
from spotlights.errors import SpotlightsError

pytestmark = pytest.mark.timeout(300)
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    """Three car-sized meshes (boxes with a slanted windscreen) in two categories."""
    root = tmp_path_factory.mktemp("dmeshes")
    for rel, dims in MESHES.items():
        m = trimesh.creation.box(extents=dims)
        v = m.vertices.copy()
        v[(v[:, 0] > 0) & (v[:, 2] > 0), 0] *= 0.6
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        trimesh.Trimesh(v, m.faces, process=False).export(root / rel)
    return root


def quiet(m):
    return None


def sha(p):
    return hashlib.sha256(Path(p).read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def local_ref(meshes, tmp_path_factory):
    out = tmp_path_factory.mktemp("dref") / "local.h5"
    build_dataset(cfg(meshes), out, workers=1, progress=False, log=quiet)
    return out


@pytest.fixture(scope="module")
def ray_results(meshes, local_ref, tmp_path_factory):
    """``{case: "ok" | error text}`` of :mod:`ray_cases`, run in a child process with its own local Ray instance
    (a Ray driver inside this pytest worker could take the worker down with it)."""
    pytest.importorskip("ray")
    work = tmp_path_factory.mktemp("ray-cases")
    results = work / "results.json"
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT / "tests"), os.environ.get("PYTHONPATH", "")]),
    }
    try:
        r = subprocess.run(
            [sys.executable, str(ROOT / "tests" / "ray_cases.py"), str(meshes), str(local_ref), str(work), str(results)],
            env=env, capture_output=True, text=True, timeout=280,
        )  # fmt: skip
        tail = f"exit {r.returncode}; stderr: {r.stderr[-3000:]}"
    except subprocess.TimeoutExpired as exc:
        tail = f"timed out after 280 s; stderr: {str(exc.stderr)[-3000:]}"
    done = json.loads(results.read_text()) if results.exists() else {}
    return {case: done.get(case, f"not run: the Ray child process ended ({tail})") for case in CASES}


# ---------------------------------------------------------------- shards (no Ray)


def test_shards_read_back_equal_to_a_single_file(meshes, local_ref, tmp_path, capsys):
    index = tmp_path / "cars.json"
    # 30 samples per shard = 2 models of 12 views: shards of 2 and 1 models
    rep = build_dataset(cfg(meshes), index, workers=2, block=5, shard_size=30, progress=False, log=quiet)
    assert rep.n_models == 3 and sorted(p.name for p in tmp_path.glob("cars-*.h5")) == [
        "cars-00000-of-00002.h5",
        "cars-00001-of-00002.h5",
    ]
    with open_dataset(local_ref) as a, open_dataset(index) as b:
        assert b.sharded and len(b.shards) == 2 and list(b.model_offset) == [0, 2, 3]
        for key in ("names", "categories", "splits", "center", "radius", "size", "sample_model", "sample_view"):
            assert np.array_equal(getattr(a, key), getattr(b, key)), key
        assert a.rig_names == b.rig_names and a.config == b.config
        for k, v in a.metadata().items():
            assert np.array_equal(v, b.metadata()[k]) and v.dtype == b.metadata()[k].dtype, k
        for i in range(a.n_samples):  # the same bytes per sample
            sa, sb = a.sample(i, "box-8x8-ellipsoid-s1"), b.sample(i, "box-8x8-ellipsoid-s1")
            for k in sa:
                assert np.array_equal(sa[k], sb[k]), (i, k)
        idx = np.array([35, 0, 13, 12, 24, 11])
        assert np.array_equal(a.partials(idx), b.partials(idx))
        assert np.array_equal(a.rig_depths(), b.rig_depths()) and np.array_equal(
            a.models_array("gt_dense", [2, 0]), b.models_array("gt_dense", [2, 0])
        )
        ia, ib = a.info(), b.info()
        assert ia["datasets"] == ib["datasets"] and ib["shards"] and ia["splits"] == ib["splits"]
    # every shard is a valid dataset of its own
    with open_dataset(tmp_path / "cars-00001-of-00002.h5") as s:
        assert s.n_models == 1 and list(s.sample_model) == [0] * 12
    # the torch dataset serves the same items
    torch_data = pytest.importorskip("spotlights.learning.data")
    import torch

    for split in ("train", "test"):
        ta = torch_data.TorchCompletionDataset(local_ref, split, rig="box-8x8-ellipsoid-s1")
        tb = torch_data.TorchCompletionDataset(index, split, rig="box-8x8-ellipsoid-s1", partials_in_memory=True)
        assert len(ta) == len(tb)
        for i in range(len(ta)):
            assert all(torch.equal(ta[i][k], tb[i][k]) for k in ta[i])
        assert all(np.array_equal(ta.gt_dense()[m], tb.gt_dense()[m]) for m in ta.gt_dense())
    # merge gives the bytes of the unsharded build
    merged = tmp_path / "merged.h5"
    assert main(["dataset", "merge", str(index), "--out", str(merged), "-q"]) == 0
    assert sha(merged) == sha(local_ref)
    # the CLI readers take the index like a file
    capsys.readouterr()
    assert main(["dataset", "info", str(index)]) == 0 and "2 shards" in capsys.readouterr().out
    assert (
        main(["dataset", "export", str(index), "--split", "test", "--index", "3", "--out", str(tmp_path / "s.npz")])
        == 0
    )
    # --resume accepts the complete sharded dataset; a .h5 name for an index is refused
    assert build_dataset(cfg(meshes), index, shard_size=30, resume=True, progress=False, log=quiet).already_complete
    with pytest.raises(SpotlightsError, match="NAME.json"):
        build_dataset(cfg(meshes), tmp_path / "x.h5", shard_size=30, progress=False, log=quiet)
    # a rebuild with other shards replaces the old ones
    build_dataset(cfg(meshes), index, shard_size=1000, overwrite=True, progress=False, log=quiet)
    assert [p.name for p in tmp_path.glob("cars-*.h5")] == ["cars-00000-of-00001.h5"]
    assert sha(merge_shards(index, tmp_path / "m2.h5", progress=False)["out"]) == sha(local_ref)


def test_dataset_show_reads_a_shard_index(meshes, local_ref, tmp_path, capsys):
    """'dataset show INDEX.json' draws the same sample, and the same picture, as on the single file."""
    from PIL import Image

    index = tmp_path / "cars.json"
    build_dataset(cfg(meshes), index, shard_size=12, progress=False, log=quiet)  # one model per shard: 3 shards
    capsys.readouterr()
    said, pixels = [], []
    for src, png in ((local_ref, tmp_path / "file.png"), (index, tmp_path / "index.png")):
        args = ["dataset", "show", str(src), "--split", "test", "--index", "5", "--out", str(png)]
        assert main(args) == 0
        said.append(capsys.readouterr().out.split(": ", 1)[1].split(" -> ")[0])
        with Image.open(png) as im:
            pixels.append(np.asarray(im.convert("RGB")))
    assert said[0] == said[1] and "test[5] = sample" in said[1]
    assert pixels[0].shape == pixels[1].shape and np.array_equal(pixels[0], pixels[1])


def test_add_rig_on_shards_equals_add_rig_on_a_file(meshes, local_ref, tmp_path):
    single = tmp_path / "single.h5"
    single.write_bytes(local_ref.read_bytes())
    index = tmp_path / "sh.json"
    build_dataset(cfg(meshes), index, shard_size=12, progress=False, log=quiet)
    add_rig(single, "4x8@45", workers=1, progress=False)
    # an interrupted add-rig: one shard already has the rig (the others do not): the reader ignores it
    first = tmp_path / "sh-00000-of-00003.h5"
    with h5py.File(single, "r") as f, h5py.File(first, "r+") as g:  # what add-rig writes into one shard
        write_rig_group(g["rigs"], parse_rig("4x8@45"), f["rigs/cap-4x8-45/depths"][:1])
        g.attrs["config_json"] = f.attrs["config_json"]
    with open_dataset(index) as ds:
        assert "cap-4x8-45" not in ds.rig_names
    rep = add_rig(index, "4x8@45", workers=2, progress=False)
    assert not rep.already_present
    with open_dataset(single) as a, open_dataset(index) as b:
        assert np.array_equal(a.rig_depths("cap-4x8-45"), b.rig_depths("cap-4x8-45")) and a.config == b.config
    assert add_rig(index, "4x8@45", progress=False).already_present


# ---------------------------------------------------------------- Ray


@pytest.mark.slow  # a local Ray instance (seconds to start)
def test_ray_build_is_byte_identical_to_local(ray_results):
    """A Ray build, a sharded Ray build merged, and add-rig on Ray: the local build's bytes (ray_cases.byte_identical)."""
    assert ray_results["byte_identical"] == "ok", ray_results["byte_identical"]


@pytest.mark.slow  # a local Ray instance (seconds to start)
def test_ray_metrics_equal_local(ray_results):
    """RayMetrics gives evaluate_completions' arrays exactly (ray_cases.metrics)."""
    assert ray_results["metrics"] == "ok", ray_results["metrics"]


@pytest.mark.slow  # a local Ray instance (seconds to start)
def test_a_failing_mesh_stops_a_ray_build_with_one_line(ray_results):
    """A mesh that never gives enough returns: one line naming it, exit 2, nothing left (ray_cases.failing_mesh)."""
    assert ray_results["failing_mesh"] == "ok", ray_results["failing_mesh"]


def test_backend_ray_without_ray_says_how_to_install(meshes, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # "import ray" raises ImportError
    for args in (
        ["dataset", "build", "--meshes", str(meshes), "--out", str(tmp_path / "x.h5"), "--backend", "ray", "-q"],
        ["dataset", "add-rig", str(tmp_path / "x.h5"), "--rig", "4x4", "--backend", "ray", "-q"],
    ):
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "pip install 'spotlights[distributed]'" in err, err
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.slow
def test_ray_build_resumes_after_the_driver_is_killed(meshes, local_ref, tmp_path):
    """SIGKILL the driver (and its local Ray instance) mid-build; the rerun keeps the finished units."""
    pytest.importorskip("ray")
    out = tmp_path / "killed.h5"
    parts = Path(str(out) + ".parts")
    cmd = [sys.executable, "-m", "spotlights", *build_argv(meshes, out)]
    cmd += ["--block", "1", "--backend", "ray", "--workers", "2", "-q"]
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 240
    killed = False
    while time.time() < deadline and proc.poll() is None:
        if parts.exists() and len(list(parts.glob("obs-*.npz"))) >= 4:
            os.killpg(proc.pid, signal.SIGKILL)
            killed = True
            break
        time.sleep(0.02)
    proc.wait(timeout=60)
    if killed:
        assert not out.exists()
        done = len([p for p in parts.glob("*.npz") if not p.name.startswith(".")])
        assert done >= 4
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=240)
        assert r.returncode == 0, r.stderr
        assert "resuming" in r.stderr, r.stderr
    assert out.exists() and not parts.exists()
    assert sha(out) == sha(local_ref)


@pytest.mark.slow  # a local Ray instance (seconds to start)
@pytest.mark.parametrize("case", ["retry_exception", "retry_crash"])
def test_a_task_is_retried_a_bounded_number_of_times(ray_results, case):
    """A task failing every attempt (an exception, or a dead worker) runs 1 + 1 retry times, then one line
    (ray_cases.retry_exception, ray_cases.retry_crash)."""
    assert ray_results[case] == "ok", ray_results[case]
