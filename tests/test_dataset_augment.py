"""Build-time augmentation and multi-source builds: mirrored and scaled copies as extra models,
splits by source mesh, per-view sensor height, several mesh folders, held-out categories."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh

from spotlights.cli import main
from spotlights.data.store import open_dataset
from spotlights.data.synthetic import BuildConfig, add_rig, build_dataset
from spotlights.data.synthetic.catalogue import augment_mesh, draw_scale_factors
from spotlights.data.synthetic.config import AUGMENT_DEFAULTS, normalize_augment
from spotlights.errors import ParameterError

from helpers import CARS, KENNEY, need

pytestmark = pytest.mark.timeout(300)
ROOT = Path(__file__).resolve().parents[1]
KENNEY_MANIFEST = ROOT / "src" / "spotlights" / "assets" / "manifests" / "kenney-vehicles.csv"


def wedge(length=4.4, width=1.8, height=1.5):
    """A closed, left-right asymmetric car-sized solid (a box with one slanted side), outward normals."""
    m = trimesh.creation.box(extents=(length, width, height))
    v = m.vertices.copy()
    v[(v[:, 1] > 0) & (v[:, 2] > 0), 0] *= 0.5  # the left roof edge is shorter: not mirror-symmetric
    return trimesh.Trimesh(v, m.faces, process=False)


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    """Two mesh folders: ``cars/`` (3 models in 2 categories) and ``toys/`` (2 half-size models,
    a manifest with a per-file scale)."""
    root = tmp_path_factory.mktemp("sources")
    cars = root / "cars"
    for rel, dims in {
        "suv/a.ply": (4.8, 2.0, 1.8),
        "suv/b.ply": (4.6, 1.9, 1.7),
        "sedan/c.ply": (4.5, 1.8, 1.45),
        "sedan/d.ply": (4.2, 1.8, 1.4),
    }.items():
        (cars / rel).parent.mkdir(parents=True, exist_ok=True)
        wedge(*dims).export(cars / rel)
    toys = root / "toys"
    toys.mkdir()
    wedge(2.4, 1.0, 0.8).export(toys / "t1.ply")
    wedge(2.2, 1.0, 0.9).export(toys / "t2.ply")
    (toys / "list.csv").write_text("file,category,scale\nt1.ply,van,2.0\nt2.ply,suv,1.9\n")
    return root


def cfg(root, **kw):
    base = dict(
        meshes=str(root / "cars"), views=3, split="2/1/1", seed=2, gt_dense=1024, gt_points=512, default_rig="8x16@60"
    )
    base.update(kw)
    return BuildConfig(**base)


def build(c, out, **kw):
    build_dataset(c, out, progress=False, log=lambda m: None, **kw)
    return out


def sha(p):
    return hashlib.sha256(Path(p).read_bytes()).hexdigest()


def strings(f, key):
    return [x.decode() for x in f[key][()]]


def test_mirror_and_scale_of_a_mesh_closed_form():
    m = wedge()
    c = (m.vertices.min(0) + m.vertices.max(0)) / 2
    v, f = augment_mesh(m.vertices, m.faces, mirror=True)
    assert np.allclose(v[:, 0], m.vertices[:, 0]) and np.allclose(v[:, 2], m.vertices[:, 2])
    assert np.allclose(v[:, 1], 2 * c[1] - m.vertices[:, 1])
    mirrored = trimesh.Trimesh(v, f, process=False)
    # the winding is fixed: a closed mesh keeps a positive volume (outward normals), same size
    assert m.volume > 0 and mirrored.volume == pytest.approx(m.volume)
    assert np.allclose(mirrored.face_normals[:, [0, 2]], m.face_normals[:, [0, 2]])
    assert np.allclose(mirrored.face_normals[:, 1], -m.face_normals[:, 1])
    # a mirror image differs from the asymmetric original
    assert not np.allclose(np.sort(v[:, 1]), np.sort(m.vertices[:, 1])) or not np.allclose(v, m.vertices)
    v2, f2 = augment_mesh(m.vertices, m.faces, scale=(0.8, 1.1, 1.2))
    assert np.array_equal(f2, m.faces)
    assert np.allclose(v2.max(0) - v2.min(0), (m.vertices.max(0) - m.vertices.min(0)) * [0.8, 1.1, 1.2])
    assert np.allclose((v2.max(0) + v2.min(0)) / 2, c)
    assert trimesh.Trimesh(v2, f2, process=False).volume == pytest.approx(m.volume * 0.8 * 1.1 * 1.2)


def test_scale_factors_stay_in_realistic_ranges():
    aug = normalize_augment({"copies": 1})
    for size in ([4.5, 2.0, 1.5], [3.45, 1.82, 1.43], [5.59, 2.41, 1.36], [4.0, 2.7, 2.3]):
        size = np.array(size)
        rng = np.random.default_rng(7)
        for _ in range(200):
            f = draw_scale_factors(size, aug, rng)
            d = size * f
            assert np.all(f >= 0.7 - 1e-12) and np.all(f <= 1.3 + 1e-12)
            for i, key in enumerate(("length", "width", "height")):
                lo, hi = aug[key]
                reach_lo, reach_hi = size[i] * 0.7, size[i] * 1.3
                if reach_hi >= lo and reach_lo <= hi:  # reachable: inside the range
                    assert lo - 1e-9 <= d[i] <= hi + 1e-9, (size, key, d)
            assert aug["length_width"][0] - 1e-9 <= d[0] / d[1] <= aug["length_width"][1] + 1e-9
            assert aug["length_height"][0] - 1e-9 <= d[0] / d[2] <= aug["length_height"][1] + 1e-9
    # seeded: the same stream gives the same factors
    a = draw_scale_factors(np.array([4.5, 2.0, 1.5]), aug, np.random.default_rng(3))
    b = draw_scale_factors(np.array([4.5, 2.0, 1.5]), aug, np.random.default_rng(3))
    assert np.array_equal(a, b)
    # a factor range reaching both ends of the length range gives small and large cars
    rng = np.random.default_rng(1)
    lengths = [4.2 * draw_scale_factors(np.array([4.2, 1.9, 1.5]), aug, rng)[0] for _ in range(400)]
    assert min(lengths) < 3.1 and max(lengths) > 5.3
    with pytest.raises(ParameterError):
        normalize_augment({"copies": 1, "factor": "1.1:1.3"})
    with pytest.raises(ParameterError):
        normalize_augment({"mirror": True, "splits": "train,holdout"})
    assert normalize_augment({"mirror": False, "copies": 0}) is None and AUGMENT_DEFAULTS["copies"] == 0


def test_augmented_copies_are_extra_models_in_their_mesh_split(sources, tmp_path):
    aug = {"mirror": True, "copies": 2, "splits": ["train", "val"]}
    out = build(cfg(sources, augment=aug), tmp_path / "aug.h5", workers=1)
    with h5py.File(out, "r") as f:
        names, origins = strings(f, "models/name"), strings(f, "models/origin")
        splits, augs = strings(f, "models/split"), strings(f, "models/augment")
        size = f["models/size"][()]
        cfgj = json.loads(f.attrs["config_json"])
        assert "source" not in f["models"]  # one source
    originals = [n for n, a in zip(names, augs) if not a]
    assert len(originals) == 4 and cfgj["augment"]["copies"] == 2
    split_of = {n: s for n, s in zip(names, splits)}
    for n, o, s, a, sz in zip(names, origins, splits, augs, size):
        assert split_of[o] == s  # a copy is always in its mesh's split
        if a:
            t = json.loads(a)
            assert n.startswith(o + "~") and s in ("train", "val")
            assert np.allclose(sz, size[names.index(o)] * np.array(t["scale"]), rtol=1e-12)
            assert t["mirror"] == n.endswith("mirror")
    per_origin = {o: origins.count(o) for o in originals}
    for o in originals:  # 1 + mirror + 2 scaled + 2 scaled-mirrored, only for train and val meshes
        assert per_origin[o] == (6 if split_of[o] in ("train", "val") else 1)
    # the same bytes whatever the workers and blocks
    out2 = build(cfg(sources, augment=aug), tmp_path / "aug2.h5", workers=2, block=1)
    assert sha(out) == sha(out2)
    # an original's samples do not depend on augmentation (its streams are named by the model)
    plain = build(cfg(sources), tmp_path / "plain.h5", workers=1)
    with h5py.File(plain, "r") as f, h5py.File(out, "r") as g:
        assert "origin" not in f["models"] and "augment" not in f["models"]
        assert "augment" not in json.loads(f.attrs["config_json"])
        pn = strings(f, "models/name")
        for i, n in enumerate(pn):
            j = names.index(n)
            assert np.array_equal(f["samples/partial"][i * 3 : (i + 1) * 3], g["samples/partial"][j * 3 : (j + 1) * 3])
            assert np.array_equal(f["rigs/cap-8x16-60/depths"][i], g["rigs/cap-8x16-60/depths"][j])


def test_sensor_height_range_changes_only_the_height(sources, tmp_path):
    base = build(cfg(sources, views=8), tmp_path / "h0.h5", workers=1)
    ranged = build(cfg(sources, views=8, mount_height_range=(1.4, 2.2)), tmp_path / "h1.h5", workers=1)

    def heights(path):
        with h5py.File(path, "r") as f:
            m = f["samples/model"][()]
            t = f["samples/sensor_to_unit"][()][:, :3, 3]  # the sensor's origin in the unit frame
            r, h = f["models/radius"][()][m], f["models/size"][()][m, 2]
            # unit z of the sensor = (mount height - box height / 2) / R
            return t[:, 2] * r + h / 2, {k: f[f"samples/{k}"][()] for k in ("distance", "azimuth", "heading")}

    h0, p0 = heights(base)
    h1, p1 = heights(ranged)
    assert np.allclose(h0, 1.73)
    assert h1.min() >= 1.4 - 1e-9 and h1.max() <= 2.2 + 1e-9 and h1.std() > 0.1
    for k in p0:  # the poses are those of the build without the range
        assert np.array_equal(p0[k], p1[k])


def test_two_sources_augmentation_and_add_rig(sources, tmp_path):
    srcs = [
        f"{sources / 'cars'},split=2/1/1",
        f"{sources / 'toys'},manifest={sources / 'toys' / 'list.csv'},split=train",
    ]
    c = cfg(sources, sources=srcs, augment={"copies": 1})
    out = build(c, tmp_path / "multi.h5", workers=2)
    with h5py.File(out, "r") as f:
        names, src, splits = strings(f, "models/name"), strings(f, "models/source"), strings(f, "models/split")
        size = f["models/size"][()]
    assert {n.split("/")[0] for n in names} == {"cars", "toys"} and set(src) == {"cars", "toys"}
    assert [s for n, s in zip(names, splits) if n.startswith("toys/")] == ["train"] * 4  # 2 toys + 2 copies
    assert splits[: len([n for n in names if n.startswith("cars/")])].count("test") == 1
    t1 = names.index("toys/t1")
    assert np.allclose(size[t1], [4.8, 2.0, 1.6])  # the manifest's per-file scale 2.0
    # add-rig rebuilds every model (copies from /models/origin + /models/augment) exactly
    ref = build(
        cfg(sources, sources=srcs, augment={"copies": 1}, extra_rigs=["box-8x16-ellipsoid-s1"]),
        tmp_path / "ref.h5",
        workers=1,
    )
    add_rig(out, "box-8x16-ellipsoid-s1", workers=2, progress=False)
    with h5py.File(out, "r") as f, h5py.File(ref, "r") as g:
        assert np.array_equal(f["rigs/box-8x16-ellipsoid-s1/depths"][()], g["rigs/box-8x16-ellipsoid-s1/depths"][()])
    with pytest.raises(ParameterError, match="once for each"):
        add_rig(out, "4x4@60", meshes=[sources / "cars"], progress=False)


def test_category_split_and_exclusion(sources, tmp_path, capsys):
    out = tmp_path / "heldout.h5"
    args = [
        "dataset",
        "build",
        "--meshes",
        str(sources / "cars"),
        "--out",
        str(out),
        "--views",
        "2",
        "--gt-dense",
        "512",
        "--default-rig",
        "4x8@60",
        "--category-split",
        "suv=test",
        "--split",
        "1/1/0",
        "--mirror",
        "-q",
    ]
    assert main(args) == 0
    with open_dataset(out) as ds:
        by_split = {
            s: sorted({str(o) for o, sp in zip(ds.origins, ds.splits) if sp == s}) for s in ("train", "val", "test")
        }
        assert by_split["test"] == ["suv/a", "suv/b"] and len(by_split["train"]) == 1 and len(by_split["val"]) == 1
        assert len(ds.names) == 5  # 4 meshes + the mirror of the one train mesh
    capsys.readouterr()
    out2 = tmp_path / "nosuv.h5"
    assert (
        main(
            args[:3]
            + [
                str(sources / "cars"),
                "--out",
                str(out2),
                "--views",
                "2",
                "--gt-dense",
                "512",
                "--default-rig",
                "4x8@60",
                "--exclude-category",
                "suv",
                "--split",
                "1/1/0",
                "-q",
            ]
        )
        == 0
    )
    with open_dataset(out2) as ds:
        assert sorted(ds.categories) == ["sedan", "sedan"]
    capsys.readouterr()
    # one line, exit 2, for options that cannot work
    bad = [
        ["--category-split", "suv"],
        ["--category-split", "suv=holdout"],
        ["--scale-copies", "1", "--scale-factor-range", "1.2:1.5"],
        ["--mount-height", "2:1"],
        ["--meshes", f"{sources / 'toys'},colour=red"],
    ]
    for extra in bad:
        assert (
            main(
                [
                    "dataset",
                    "build",
                    "--meshes",
                    str(sources / "cars"),
                    "--out",
                    str(tmp_path / "bad.h5"),
                    "--split",
                    "1/1/2",
                    "-q",
                    *extra,
                ]
            )
            == 2
        ), extra
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "Traceback" not in err, err
    assert not (tmp_path / "bad.h5").exists()


def test_real_product_sources_resolve(tmp_path):
    """The documented product build's catalogue: ApolloScape's paper split plus every Kenney vehicle in train."""
    need(CARS)
    need(KENNEY)
    from spotlights.data.synthetic.catalogue import assign_model_splits, discover_sources

    c = BuildConfig(sources=[f"{CARS},split=64/8/7", f"{KENNEY},manifest={KENNEY_MANIFEST},split=train"]).validate()
    entries, problems = discover_sources(c)
    splits = assign_model_splits(entries, c)
    assert not problems and len(entries) == 99
    kenney = [s for e, s in zip(entries, splits) if e.source == "kenney-vehicles"]
    apollo = [s for e, s in zip(entries, splits) if e.source == "apolloscape-cars"]
    assert kenney == ["train"] * 20 and [apollo.count(s) for s in ("train", "val", "test")] == [64, 8, 7]
    # the same ApolloScape split as a single-folder build (the paper's 64/8/7)
    from spotlights.data.synthetic import assign_splits

    single = BuildConfig(meshes=str(CARS), split="64/8/7").validate()
    ents1, _ = discover_sources(single)
    assert assign_splits([e.category for e in ents1], "64/8/7", 0) == apollo
