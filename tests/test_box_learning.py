"""Box-targeted rigs in the dataset and in SA-Net.

Independent truths: a solid box mesh is hit by every box-rig ray at the slab
distance (closed form); CAD vehicles' depths equal a brute-force Moller-Trumbore
ray/triangle test in float64; a SA-Net whose output is forced to known depths
puts its points at ``P = o + 2 t d`` with the rays of each sample's own box (on a
box's surface when t are that box's slab distances).
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh

torch = pytest.importorskip("torch")

from spotlights.data.store import open_dataset  # noqa: E402
from spotlights.data.synthetic import BuildConfig, add_rig, build_dataset  # noqa: E402
from spotlights.errors import ParameterError  # noqa: E402
from spotlights.geometry.encode import decode  # noqa: E402
from spotlights.geometry.io import load_mesh  # noqa: E402
from spotlights.geometry.rig import RigSpec  # noqa: E402

from helpers import KENNEY, need, slab_interval  # noqa: E402
from learning_fixtures import TINY_MODEL_ARGS, cli, one_torch_thread  # noqa: E402

BOX = "box-32x64-ellipsoid-s1"
SPEC = RigSpec.from_name(BOX)
BOX_SIZE = (4.4, 1.8, 1.5)  # the solid box model, metres
VEHICLES = ("sedan.glb", "suv.glb")

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)


# ------------------------------------------------------------------------------------------
# independent geometry
# ------------------------------------------------------------------------------------------
def slab(origins, directions, half):
    """Entry distance of rays into the box [-half, half] (closed form; inf when missed)."""
    t0, t1 = slab_interval(origins, directions, -half, half)
    return np.where(t1 >= np.maximum(t0, 0), t0, np.inf)


def brute_force_depths(vertices, faces, origins, directions):
    """Depths by Moller-Trumbore over every (ray, triangle) pair in float64: first hit / 2, 0 = miss."""
    tri = vertices[faces]
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    best = np.full(len(origins), np.inf)
    for s in range(0, len(origins), 256):
        o, d = origins[s : s + 256, None], directions[s : s + 256, None]
        p = np.cross(d, e2)
        det = np.einsum("rfk,fk->rf", p, e1)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            inv = 1.0 / det
            tv = o - v0
            u = np.einsum("rfk,rfk->rf", tv, p) * inv
            q = np.cross(tv, e1)
            v = np.einsum("rfk,rfk->rf", np.broadcast_to(d, q.shape), q) * inv
            t = np.einsum("fk,rfk->rf", e2, q) * inv
            ok = (np.abs(det) > 1e-15) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        best[s : s + 256] = np.where(ok, t, np.inf).min(axis=1)
    chord = np.clip(-2.0 * np.einsum("ij,ij->i", origins, directions), 0, 2)
    return np.where(best <= chord + 1e-6, best / 2.0, 0.0)


# ------------------------------------------------------------------------------------------
# a small dataset: a solid box and two CC0 vehicles
# ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    need(KENNEY)
    root = tmp_path_factory.mktemp("boxmeshes")
    (root / "boxes").mkdir()
    trimesh.creation.box(extents=BOX_SIZE).export(root / "boxes" / "block.ply")
    (root / "cars").mkdir()
    for v in VEHICLES:
        shutil.copy(KENNEY / v, root / "cars" / v)
    rows = ["file,category,up,split", "boxes/block.ply,boxes,z,train"]
    rows += [f"cars/{v},cars,y,{s}" for v, s in zip(VEHICLES, ("val", "test"))]
    (root / "manifest.csv").write_text("\n".join(rows) + "\n")
    return root


def cfg(meshes, rigs):
    return BuildConfig(meshes=str(meshes), views=6, seed=1, extra_rigs=list(rigs))


@pytest.fixture(scope="module")
def built(meshes, tmp_path_factory):
    """The dataset built with the box rig from the start, and the same built without it."""
    d = tmp_path_factory.mktemp("boxds")
    with_box = d / "with_box.h5"
    build_dataset(cfg(meshes, ["16x16@45", BOX]), with_box, workers=1, progress=False, log=lambda m: None)
    without = d / "without.h5"
    build_dataset(cfg(meshes, ["16x16@45"]), without, workers=2, progress=False, log=lambda m: None)
    return with_box, without


def test_box_rig_depths_equal_independent_truth(built, meshes):
    path, _ = built
    with h5py.File(path, "r") as f:  # the file as written (docs/dataset.md: the group attr rig_json of /rigs/NAME)
        stored = json.loads(f[f"rigs/{BOX}"].attrs["rig_json"])
    with open_dataset(path) as ds:
        assert BOX in ds.rig_names
        assert stored == SPEC.to_dict() and "box" not in stored  # the spec: each model has its own box
        e = ds.extents
        np.testing.assert_allclose(np.linalg.norm(e, axis=1), 1.0, atol=1e-12)
        for m, name in enumerate(ds.names):
            depths = ds.ground_truth(m, BOX)["gt_depths"]
            rig = ds.rig(BOX, m)
            if name == "boxes/block":
                half = np.asarray(BOX_SIZE) / np.linalg.norm(BOX_SIZE)  # e = size / |size|, independent of the file
                np.testing.assert_allclose(e[m], half, atol=1e-12)
                t = slab(rig.origins, rig.directions, half)
                assert np.all(np.isfinite(t)) and np.all(depths > 0)  # every ray hits the box
                np.testing.assert_allclose(depths, t / 2, atol=2e-6)
            else:
                mesh = load_mesh(meshes / f"{name}.glb", up="y")
                v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
                used = v[np.unique(f)]
                lo, hi = used.min(0), used.max(0)
                c, r = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
                np.testing.assert_allclose(e[m], (hi - lo) / (2 * r), atol=1e-9)
                want = brute_force_depths((v - c) / r, f, rig.origins, rig.directions)
                agree = np.abs(depths - want) < 1e-4
                assert agree.mean() > 0.995, f"{name}: {agree.mean():.4f} of the rays agree"
                assert (depths > 0).mean() > 0.85  # the box rig hits the vehicle with most rays
        # per-sample decoding (spec + extents) equals decoding with each model's own rig
        rows = np.arange(ds.n_models)
        all_depths = np.stack([ds.ground_truth(m, BOX)["gt_depths"] for m in rows])
        pts, mask = decode(all_depths, SPEC, extents=e)
        for m in rows:
            p1, m1 = decode(all_depths[m], SPEC.for_box(e[m]))
            np.testing.assert_array_equal(mask[m], m1)
            np.testing.assert_allclose(pts[m], p1, atol=1e-6)
        np.testing.assert_array_equal(ds.directions(BOX, rows)[1], SPEC.for_box(e[1]).directions)
        s = ds.sample(0, rig=BOX)
        np.testing.assert_array_equal(s["extents"], e[s["model_index"]])
        with pytest.raises(ParameterError, match="model row"):
            ds.rig(BOX)
        assert ds.rig("cap-16x16-45").n_rays == 256  # cap rigs need no model


def test_add_rig_matches_a_build_and_is_atomic(built, meshes, tmp_path, capsys):
    with_box, without = built
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    shutil.copy(without, a)
    shutil.copy(without, b)
    rep = add_rig(a, BOX, workers=1, progress=False)
    assert rep.rig == BOX and rep.n_models == 3 and 0.9 < rep.hit_ratio <= 1.0
    r = cli(
        capsys, "dataset", "add-rig", b, "--rig", BOX, "--workers", "2"
    )  # (no -q: it silences the summary line too)
    assert r.returncode == 0 and f"added rig {BOX}" in r.stdout
    assert hashlib.sha256(a.read_bytes()).digest() == hashlib.sha256(b.read_bytes()).digest()  # workers never matter
    with h5py.File(a) as fa, h5py.File(with_box) as fw:
        np.testing.assert_array_equal(fa[f"rigs/{BOX}/depths"][()], fw[f"rigs/{BOX}/depths"][()])
        assert fa[f"rigs/{BOX}"].attrs["rig_json"] == fw[f"rigs/{BOX}"].attrs["rig_json"]
        for k in ("samples/partial", "models/gt_points", "rigs/cap-32x64-60/depths"):
            np.testing.assert_array_equal(fa[k][()], fw[k][()])
        assert json.loads(fa.attrs["config_json"])["extra_rigs"] == ["cap-16x16-45", BOX]
    r = cli(capsys, "dataset", "add-rig", a, "--rig", BOX)
    assert r.returncode == 0 and "nothing to do" in r.stdout
    # a mesh that changed since the build: an error naming it, the file untouched
    bad = tmp_path / "meshes"
    shutil.copytree(meshes, bad)
    trimesh.creation.box(extents=(1, 1, 1)).export(bad / "boxes" / "block.ply")
    before = hashlib.sha256(without.read_bytes()).hexdigest()
    c = tmp_path / "c.h5"
    shutil.copy(without, c)
    r = cli(capsys, "dataset", "add-rig", c, "--rig", BOX, "--meshes", bad, "-q", "-j", "1")
    assert r.returncode == 2 and "block.ply" in r.stderr and "differs" in r.stderr
    assert hashlib.sha256(c.read_bytes()).hexdigest() == before
    assert [p.name for p in tmp_path.glob(".c.h5.*")] == []  # no temporary copy left, nor the lock file
    r = cli(capsys, "dataset", "add-rig", c, "--rig", "box-32x64-bogus-s1")
    assert r.returncode == 2


def test_add_rig_refuses_a_file_another_add_rig_is_rewriting(built, tmp_path, capsys):
    import fcntl

    _, without = built
    a = tmp_path / "a.h5"
    shutil.copy(without, a)
    before = hashlib.sha256(a.read_bytes()).hexdigest()
    with open(tmp_path / ".a.h5.lock", "w") as held:  # what a running add-rig holds
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        r = cli(capsys, "dataset", "add-rig", a, "--rig", BOX, "-q", "-j", "1")
    assert r.returncode == 2 and "another 'dataset add-rig' is rewriting this file" in r.stderr and str(a) in r.stderr
    assert hashlib.sha256(a.read_bytes()).hexdigest() == before
    r = cli(capsys, "dataset", "add-rig", tmp_path / "none.h5", "--rig", BOX)
    assert r.returncode == 2 and not (tmp_path / ".none.h5.lock").exists()  # no lock file beside a missing file


# ------------------------------------------------------------------------------------------
# SA-Net on a box rig
# ------------------------------------------------------------------------------------------
def force_depths(model, depths):
    """Make SA-Net's output the constant ``depths`` (N*M,) whatever the input (zero last weights)."""
    last = model.decoder.linears[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.copy_(torch.as_tensor(depths, dtype=torch.float32))


@pytest.fixture(scope="module")
def box_run(built, tmp_path_factory):
    from spotlights.learning.train import train

    path, _ = built
    out = tmp_path_factory.mktemp("boxrun")
    ov = {
        "model": {"args": dict(TINY_MODEL_ARGS["sanet"])},
        "data": {"rig": BOX, "num_workers": 0},
        "train": {"epochs": 1, "batch_size": 4, "lr": 1e-3},
    }
    res = train("sanet", path, out, overrides=ov, progress=False, log=lambda m: None)
    return path, Path(res["best"]), res


def test_box_sanet_trains_and_records_its_spec(box_run):
    from spotlights.learning.checkpoint import load_checkpoint

    path, best, res = box_run
    assert res["epochs"] == 1 and np.isfinite(res["history"][0]["train_loss"])
    assert np.isfinite(res["history"][0]["val_accuracy"])
    ck = load_checkpoint(best)
    assert ck["rig"] == SPEC.to_dict() and ck["dataset"]["rig"] == BOX


def test_checkpoint_records_the_train_splits_domain_and_the_completer_warns_outside_it(box_run, tmp_path):
    from spotlights.learning.checkpoint import export_weights, load_checkpoint
    from spotlights.learning.domain import LearnedDomain
    from spotlights.learning.inference import load_completer

    _, best, _ = box_run
    d = load_checkpoint(best)["domain"]
    # the train split is the solid box alone: its class is its category, its sizes the mesh's extents
    assert d["classes"] == ["boxes"]
    np.testing.assert_allclose(d["size_min"], BOX_SIZE, rtol=1e-6)
    np.testing.assert_allclose(d["size_max"], BOX_SIZE, rtol=1e-6)
    assert "train split (1 models)" in d["source"]
    half = export_weights(best, tmp_path / "half.pt", half=True)  # shipping keeps it
    for comp in (load_completer(best, device="cpu"), load_completer(half, device="cpu")):
        assert comp.domain == LearnedDomain.from_checkpoint({"domain": d})
        assert comp.domain.warnings("boxes", BOX_SIZE) == []
        assert comp.domain.warnings("boxes", (4.4 * 1.09, 1.8, 1.5)) == []  # inside the 10% tolerance
        (w,) = comp.domain.warnings("boxes", (4.4 * 1.12, 1.8, 1.5))
        assert "length 4.93 m" in w and "width" not in w
        assert any("class car" in m for m in comp.domain.warnings("car", BOX_SIZE))


def test_learned_domain_maps_body_types_to_detector_classes():
    from spotlights.learning.domain import CARS_DOMAIN, LearnedDomain

    sizes = np.array([[4.0, 1.8, 1.5], [3.5, 1.7, 1.6], [6.0, 2.2, 2.5], [5.2, 2.0, 2.1]])
    dom = LearnedDomain.from_training_set(["sedan", "Hatchback", "van", "tractor"], sizes, source="hand")
    assert dom.classes == ("car", "caravan", "tractor")  # first-seen order; unknown categories kept
    assert dom.size_min == (3.5, 1.7, 1.5) and dom.size_max == (6.0, 2.2, 2.5)
    assert LearnedDomain.from_checkpoint({"domain": dom.to_dict()}) == dom
    assert LearnedDomain.from_checkpoint({}) == CARS_DOMAIN  # checkpoints from before the record
    with pytest.raises(ParameterError, match="one size per category"):
        LearnedDomain.from_training_set(["sedan"], sizes, source="hand")


def test_validation_decodes_each_sample_with_its_box(box_run):
    from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint
    from spotlights.learning.data import TorchCompletionDataset
    from spotlights.learning.train import validate

    path, best, _ = box_run
    model = model_from_checkpoint(load_checkpoint(best))
    assert model.needs_box
    with open_dataset(path) as ds:
        e = ds.extents
        val_model = int(ds.split_models("val")[0])
        rig = ds.rig(BOX, val_model)
        dense = ds.ground_truth(val_model)["gt_dense"].astype(np.float64)
        t = ds.ground_truth(val_model, BOX)["gt_depths"].astype(np.float64)
    force_depths(model, t)  # the model "predicts" the val car's ground truth
    val_set = TorchCompletionDataset(path, "val", rig=BOX)
    res = validate(model, val_set, 4, torch.device("cpu"), val_set.gt_dense())
    # independent: the hits of the val car's own rig, at its stored depths, clip 0.2
    keep = t >= 0.2
    pts = rig.origins[keep] + 2 * t[keep, None] * rig.directions[keep]
    from scipy.spatial import cKDTree

    want = cKDTree(dense).query(pts)[0].mean()
    assert res["val_accuracy"] == pytest.approx(want, rel=1e-4)
    assert res["val_accuracy"] < 0.02  # the stored depths lie on that car's surface
    # with another model's box the same depths would not: the box matters
    other = SPEC.for_box(e[int(np.argmax(np.linalg.norm(e - e[val_model], axis=1)))])
    wrong = cKDTree(dense).query(other.origins[keep] + 2 * t[keep, None] * other.directions[keep])[0].mean()
    assert wrong > 2 * want


def test_box_completer_uses_each_scans_box(box_run):
    from spotlights.geometry.boxes import Box, unit_extents
    from spotlights.learning.inference import complete_scan, load_completer

    _, best, _ = box_run
    comp = load_completer(best, device="cpu")
    assert comp.needs_box and comp.rig == SPEC
    size = np.array([4.6, 1.9, 1.6])
    e = unit_extents(size)
    rig = SPEC.for_box(e)
    t = slab(rig.origins, rig.directions, e) / 2  # depths that put every point on this box's surface
    force_depths(comp.model, t)
    partial = np.random.default_rng(0).normal(size=(2, 256, 3)).astype(np.float32) * 0.3
    with pytest.raises(ParameterError, match="box"):
        comp.complete(partial)
    e2 = unit_extents([3.0, 2.0, 2.0])
    out = comp.complete(partial, clip=None, extents=np.stack([e, e2]))
    assert len(out[0]) == SPEC.n_rays
    np.testing.assert_allclose(np.abs(out[0] / e).max(1), 1.0, atol=2e-5)  # on the surface of its box
    np.testing.assert_allclose(out[1], SPEC.origins + 2 * t[:, None] * SPEC.for_box(e2).directions, atol=2e-6)
    # a scan with its detector box: the completion lies on that box, in the scan's frame
    box = Box(center=(10.0, -3.0, 0.8), size=tuple(size), yaw=0.7)
    res = complete_scan(np.random.default_rng(1).normal(size=(300, 3)) + box.center, box, comp, clip=None)
    n = box.normalization()
    local = (res["completed"] - n.center) @ n.rotation
    np.testing.assert_allclose(np.abs(local / (size / 2)).max(1), 1.0, atol=5e-5)


def test_box_checkpoint_in_evaluate_and_real_consistency(box_run, tmp_path, monkeypatch):
    from spotlights.experiments import real_evaluation as real_eval
    from spotlights.learning.evaluate import evaluate_checkpoint
    from spotlights.learning.inference import load_completer

    path, best, _ = box_run
    res = evaluate_checkpoint(best, path, "test", max_views=2, latency=True, latency_repeats=1, progress=False)
    assert res["n_samples"] == 2 and all(
        np.isfinite(r["summary"]["mean_over_samples"]["accuracy"]) for r in res["rows"]
    )
    # the real-data path hands every observation's box to a box-rig completer: e = size / |size|
    comp = load_completer(best, device="cpu")
    seen = []

    class Recorder:
        model_name, n_params, needs_box = "rec", 0, True

        def complete(self, partials, extents=None):
            seen.append(np.array(extents))
            return comp.complete(partials, extents=extents)

    sizes = np.array([[4.2, 1.8, 1.5], [5.0, 2.0, 2.0], [4.0, 1.7, 1.4]])
    partials = np.random.default_rng(2).normal(size=(3, 256, 3)).astype(np.float32) * 0.3
    out = real_eval.complete_all(Recorder(), partials, batch_size=2, progress=False, box_sizes=sizes)
    assert len(out) == 3
    np.testing.assert_allclose(np.concatenate(seen), sizes / np.linalg.norm(sizes, axis=1, keepdims=True), atol=1e-12)
    with pytest.raises(Exception, match="box"):
        real_eval.complete_all(Recorder(), partials, progress=False)


def test_cap_checkpoints_and_datasets_unchanged(built):
    """The shipped paper (cap-rig) SA-Net needs no box and ignores one; the default (box-rig) model needs one;
    cap rigs of a file need no model row."""
    from spotlights.learning.inference import load_completer, pretrained_checkpoint

    try:
        pretrained_checkpoint("paper")
    except Exception:
        pytest.skip("no pretrained checkpoint shipped in this checkout")
    comp = load_completer("paper", device="cpu")
    assert not comp.needs_box and comp.rig.kind == "cap"
    assert load_completer(device="cpu").needs_box  # the default: hit-aware SA-Net on a box-targeted rig
    x = np.random.default_rng(3).normal(size=(2, 256, 3)).astype(np.float32) * 0.3
    a = comp.complete(x)
    b = comp.complete(x, extents=np.ones((2, 3)) / np.sqrt(3))
    assert all(np.array_equal(p, q) for p, q in zip(a, b))
    with open_dataset(built[1]) as ds:
        assert ds.rig().kind == "cap" and ds.rig("cap-16x16-45") == ds.rig("cap-16x16-45", 0)


def test_bench_models_times_a_box_rig_sanet():
    """The latency benchmark decodes a box-rig SA-Net with the rays of one box (it needs them)."""
    from spotlights.learning.bench import bench_models

    rep = bench_models(["sanet"], batches=(2,), rig=SPEC, repeats=1, warmup=0, progress=False)
    lat = rep["models"][0]["latency_ms"][2]
    assert lat["forward_ms"] > 0 and lat["complete_ms"] > 0


def test_hit_aware_sanet_on_a_box_rig(built, tmp_path):
    """sanet-hit trains on a box rig, stores its threshold, and decodes each scan's kept rays on that scan's box."""
    from spotlights.geometry.boxes import unit_extents
    from spotlights.learning.checkpoint import load_checkpoint
    from spotlights.learning.inference import load_completer
    from spotlights.learning.train import train

    path, _ = built
    ov = {
        "model": {"args": dict(TINY_MODEL_ARGS["sanet-hit"])},
        "data": {"rig": BOX, "num_workers": 0},
        "train": {"epochs": 1, "batch_size": 4, "lr": 1e-3, "precision": "fp32"},
    }
    res = train("sanet-hit", path, tmp_path / "hit", overrides=ov, progress=False, log=lambda m: None)
    assert np.isfinite(res["history"][0]["train_loss"]) and np.isfinite(res["history"][0]["val_chamfer_l1"])
    ck = load_checkpoint(res["best"])
    assert ck["rig"] == SPEC.to_dict() and 0 < ck["hit_threshold"]["value"] < 1
    comp = load_completer(res["best"], device="cpu")
    assert comp.needs_box and comp.model.threshold == ck["hit_threshold"]["value"]
    e = unit_extents([4.6, 1.9, 1.6])
    rig = SPEC.for_box(e)
    t = slab(rig.origins, rig.directions, e) / 2
    hit = np.isfinite(t) & (t > 0)
    logits = np.where(hit, 8.0, -8.0)  # p(hit) = 0.9997 on the box's rays, 0.0003 elsewhere
    force_depths(comp.model, np.concatenate([logits, np.where(hit, t, 5.0)]))
    out = comp.complete(np.random.default_rng(0).normal(size=(1, 256, 3)).astype(np.float32) * 0.3, extents=e[None])[0]
    assert len(out) == hit.sum()
    np.testing.assert_allclose(np.abs(out / e).max(1), 1.0, atol=2e-5)  # every kept ray on the box's surface


def test_box_term_trains_on_a_box_rig_with_each_samples_grown_box(built, tmp_path):
    """sanet-hit with ``box_weight``: the batch carries each model's rays and its box grown by 0.15 m
    (in its unit frame, by hand), the run trains and its checkpoint keeps the weight."""
    from spotlights.learning.checkpoint import load_checkpoint
    from spotlights.learning.data import TorchCompletionDataset
    from spotlights.learning.rays import DirectionTable
    from spotlights.learning.train import train
    from spotlights.learning.validation import collate, with_boxes

    path, _ = built
    ds = TorchCompletionDataset(path, "train", rig=BOX)
    batch = collate([ds[0], ds[1]])
    rays = DirectionTable(SPEC, ds.extents)

    class Boxed:
        box_weight = 0.5

    got = with_boxes(batch, Boxed(), rays, ds.sizes)
    r = np.linalg.norm(BOX_SIZE) / 2  # the block's unit frame: metres / half its diagonal
    want = (np.array(BOX_SIZE) / 2 + 0.15) / r
    np.testing.assert_allclose(got["box_half"].numpy(), np.stack([want, want]), rtol=1e-6)
    assert got["directions"].shape == (2, SPEC.n_rays, 3)
    assert with_boxes(batch, object(), rays, ds.sizes) is batch  # any other model: the batch as it is

    ov = {
        "model": {"args": {**TINY_MODEL_ARGS["sanet-hit"], "box_weight": 2.0}},
        "data": {"rig": BOX, "num_workers": 0},
        "train": {"epochs": 1, "batch_size": 4, "lr": 1e-3, "precision": "fp32"},
    }
    res = train("sanet-hit", path, tmp_path / "boxed", overrides=ov, progress=False, log=lambda m: None)
    h = res["history"][0]
    assert np.isfinite(h["train_loss"]) and np.isfinite(h["val_loss"]) and np.isfinite(h["val_chamfer_l1"])
    assert load_checkpoint(res["best"])["config"]["model"]["args"]["box_weight"] == 2.0
