"""Scale-out: the Ray backend (byte-identical to local, resume after a killed driver, failures),
sharded datasets (read back equal to one file, merge, add-rig), metrics on Ray, Ray missing."""

from __future__ import annotations

import hashlib
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
from spotlights.data.store import open_dataset, write_rig_group
from spotlights.data.synthetic import BuildConfig, add_rig, build_dataset, parse_rig
from spotlights.data.synthetic.consolidate import merge_shards
from spotlights.errors import SpotlightsError

pytestmark = pytest.mark.timeout(300)
ROOT = Path(__file__).resolve().parents[1]
MESHES = {"suv/a.ply": (4.8, 2.0, 1.8), "sedan/b.ply": (4.5, 1.8, 1.45), "sedan/c.ply": (4.1, 1.75, 1.5)}


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


def cfg(root, **kw):
    base = dict(
        meshes=str(root),
        views=12,
        split="1/1/1",
        seed=4,
        gt_dense=1024,
        gt_points=512,
        default_rig="8x16@60",
        extra_rigs=["box-8x8-ellipsoid-s1"],
    )
    base.update(kw)
    return BuildConfig(**base)


def build_argv(root, out) -> list[str]:
    """The ``spotlights dataset build`` arguments of the build :func:`cfg` describes, writing ``out``."""
    c = cfg(root)
    argv = ["dataset", "build", "--meshes", str(root), "--out", str(out), "--views", str(c.views)]
    argv += ["--split", c.split, "--seed", str(c.seed), "--gt-dense", str(c.gt_dense), "--gt-points", str(c.gt_points)]
    argv += ["--default-rig", c.default_rig]
    for rig in c.extra_rigs:
        argv += ["--rig", rig]
    return argv


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
def ray_cluster():
    """One local Ray instance of 2 CPUs for the module (the backends join it)."""
    ray = pytest.importorskip("ray")
    if not ray.is_initialized():
        ray.init(
            num_cpus=2,
            include_dashboard=False,
            log_to_driver=False,
            logging_level="ERROR",
            object_store_memory=256 << 20,
        )
    yield ray
    ray.shutdown()


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
def test_ray_build_is_byte_identical_to_local(meshes, local_ref, tmp_path, ray_cluster):
    one = tmp_path / "ray1.h5"
    build_dataset(cfg(meshes), one, backend="ray", workers=1, block=4, progress=False, log=quiet)
    assert sha(one) == sha(local_ref)
    # sharded on Ray (shards written by Ray tasks), then merged: the same bytes again
    index = tmp_path / "ray.json"
    assert main(build_argv(meshes, index) + ["--backend", "ray", "--shard-size", "24", "-q"]) == 0
    assert sha(merge_shards(index, tmp_path / "m.h5", progress=False)["out"]) == sha(local_ref)
    # add-rig on Ray = add-rig locally
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    a.write_bytes(local_ref.read_bytes())
    b.write_bytes(local_ref.read_bytes())
    add_rig(a, "4x4@30", workers=1, progress=False)
    add_rig(b, "4x4@30", backend="ray", progress=False)
    assert sha(a) == sha(b)


@pytest.mark.slow  # a local Ray instance (seconds to start)
def test_ray_metrics_equal_local(ray_cluster):
    from spotlights.learning.ray_metrics import RayMetrics
    from spotlights.metrics.completion import evaluate_completions

    rng = np.random.default_rng(0)
    gt = [rng.normal(size=(500, 3)) for _ in range(3)]
    models = np.array([2, 0, 0, 1, 2, 2, 0])
    preds = [rng.normal(size=(int(rng.integers(0, 80)), 3)) for _ in models]
    preds[3] = np.zeros((0, 3))
    want = evaluate_completions(preds, models, gt, 0.3, True)
    got = RayMetrics(ray_cluster, chunk=2)(preds, models, gt, 0.3, True)
    assert want.keys() == got.keys()
    for k in want:
        np.testing.assert_array_equal(want[k], got[k])


@pytest.mark.slow  # a local Ray instance (seconds to start)
def test_a_failing_mesh_stops_a_ray_build_with_one_line(meshes, tmp_path, capsys, ray_cluster):
    bad = tmp_path / "bad"
    for rel in MESHES:
        (bad / rel).parent.mkdir(parents=True, exist_ok=True)
        (bad / rel).write_bytes((meshes / rel).read_bytes())
    trimesh.creation.box(extents=(0.01, 0.01, 0.01)).export(bad / "sedan" / "tiny.ply")  # loads, never gives 50 returns
    out = tmp_path / "bad.h5"
    rc = main(
        [
            "dataset",
            "build",
            "--meshes",
            str(bad),
            "--out",
            str(out),
            "--views",
            "4",
            "--split",
            "2/1/1",
            "--gt-dense",
            "256",
            "--backend",
            "ray",
            "-q",
        ]
    )
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and "Traceback" not in err, err
    assert "tiny.ply" in err and "no pose" in err
    assert not out.exists()
    # the input error crossed from the Ray task as itself: the build removed its parts (a corrected mesh is another plan)
    assert not (tmp_path / "bad.h5.parts").exists()


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
@pytest.mark.parametrize("crash", [False, True])
def test_a_task_is_retried_a_bounded_number_of_times(tmp_path, ray_cluster, crash):
    from spotlights.data.synthetic.ray_backend import RayBuild

    def _flaky(counter: str, crash: bool):  # a local function: Ray ships it by value to the workers
        """Fails on every attempt (an exception, or a dead worker process), counting attempts in a file."""
        with open(counter, "a") as fh:
            fh.write("x")
        if crash:
            os._exit(1)
        raise RuntimeError("disk on fire")

    runner = RayBuild(ray_cluster, retries=1)
    task = ray_cluster.remote(num_cpus=1, max_retries=1, retry_exceptions=True)(_flaky)
    counter = tmp_path / "attempts"
    with pytest.raises(SpotlightsError) as err:
        runner.stream(
            lambda i: task.remote(str(counter), crash),
            [0],
            lambda i: "cars/x.ply: views 0-9 of model x",
            lambda i, r: None,
        )
    msg = str(err.value)
    assert err.value.exit_code == 1  # a task that failed every attempt: not the input's fault (ProcessFailure)
    assert "\n" not in msg and msg.startswith(
        "cars/x.ply: views 0-9 of model x failed on the Ray cluster after 2 attempts"
    )
    assert ("disk on fire" in msg) if not crash else ("Worker" in msg or "died" in msg or "crash" in msg.lower()), msg
    assert counter.read_text() == "xx"  # 1 + 1 retry, no more
