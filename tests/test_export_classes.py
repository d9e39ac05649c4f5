"""ONNX export of class-conditioned SA-Nets: the graph's ``classes`` (B,) int64 input gives the torch
model's outputs for each class, ``OnnxCompleter`` feeds it from box classes as the torch ``Completer`` does (the
learned-domain gate, the grown-box clip, ``--fallback``), bad class rows are one line, old exports stay cars."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

from spotlights.api import complete_frame  # noqa: E402
from spotlights.errors import InputFileError, ParameterError  # noqa: E402
from spotlights.geometry.boxes import Box, unit_extents  # noqa: E402
from spotlights.geometry.rig import RigSpec, make_rig  # noqa: E402
from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint, save_checkpoint  # noqa: E402
from spotlights.learning.export import export_onnx, load_onnx_completer  # noqa: E402
from spotlights.learning.inference import load_completer  # noqa: E402
from spotlights.learning.models import build_model, load_config  # noqa: E402
from spotlights.learning.rays import directions_for_extents  # noqa: E402

from learning_fixtures import TINY_MODEL_ARGS, cli, make_checkpoint, one_torch_thread  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)
VOCAB = ["car", "caravan", "truck", "bus", "trailer"]
BOX = RigSpec.from_name("box-8x16-ellipsoid-s1")
# what the tiny model "learned": cars and buses only (truck is in its vocabulary, not in its domain)
DOMAIN = {
    "classes": ["car", "bus"],
    "size_min": [3.4, 1.6, 1.3],
    "size_max": [13.7, 2.6, 3.6],
    "class_sizes": {"car": [[3.4, 1.6, 1.3], [5.6, 2.4, 1.9]], "bus": [[9.0, 2.4, 2.9], [13.7, 2.6, 3.6]]},
}


def class_checkpoint(path, name="sanet-hit", rig=BOX, templates=False):
    """A tiny class-conditioned checkpoint whose class embedding is random (zero-initialised, classes would not
    differ), with a learned domain of cars and buses and, for the hit-aware model, a p(hit) threshold;
    ``templates``: with random per-class output templates too."""
    args = {**TINY_MODEL_ARGS[name], "classes": VOCAB, **({"class_templates": True} if templates else {})}
    cfg = load_config(name, overrides={"model": {"args": args}})
    torch.manual_seed(0)
    model = build_model(cfg, rig=rig)
    torch.nn.init.normal_(model.class_embedding.weight, std=2.0)
    if templates:
        torch.nn.init.normal_(model.class_template.weight, std=0.5)
    payload = {
        "model_name": name,
        "config": cfg,
        "rig": rig.to_dict(),
        "model_state": model.state_dict(),
        "param_counts": model.param_counts(),
        "epoch": 0,
        "global_step": 0,
        "domain": DOMAIN,
    }
    if name == "sanet-hit":
        payload["hit_threshold"] = {"value": 0.5, "chosen_on": "val"}
    return save_checkpoint(path, payload)


@pytest.fixture(scope="module")
def hit_export(tmp_path_factory):
    """(checkpoint, export) of the tiny class-conditioned hit-aware SA-Net on a box rig."""
    d = tmp_path_factory.mktemp("class-export")
    ckpt = class_checkpoint(d / "cls.pt")
    return ckpt, export_onnx(ckpt, d / "cls.onnx")


def box(center, size, cls) -> Box:
    return Box(np.asarray(center, float), np.asarray(size, float), np.eye(3), cls, cls, None)


def scans(n=4, k=200, seed=0) -> np.ndarray:
    return (np.random.default_rng(seed).uniform(-0.5, 0.5, (n, k, 3)) * [0.9, 0.4, 0.3]).astype(np.float32)


@pytest.mark.parametrize(
    "name, rig, templates",
    [("sanet-hit", BOX, False), ("sanet", make_rig(8, 16, 60.0), False), ("sanet-hit", BOX, True)],
)
def test_class_input_gives_the_torch_outputs_of_each_class(tmp_path, name, rig, templates):
    ckpt = class_checkpoint(tmp_path / "m.pt", name, rig, templates)
    onx = load_onnx_completer(export_onnx(ckpt, tmp_path / "m.onnx"))
    assert onx.classes == tuple(VOCAB) and onx.inputs[-1] == "classes" and onx.domain.classes == ("car", "bus")
    assert onx.meta["spotlights_format_version"] == "2" and json.loads(onx.meta["classes"]) == VOCAB
    assert onx.domain.class_sizes["bus"] == ((9.0, 2.4, 2.9), (13.7, 2.6, 3.6))
    model = model_from_checkpoint(load_checkpoint(ckpt))
    x = scans()
    dirs = (
        directions_for_extents(onx.rig, unit_extents(np.array([4.4, 1.8, 1.5])[None].repeat(4, 0)))
        if onx.needs_box
        else None
    )
    out = {}
    for row in (0, 3):  # car, bus: the same scans through both runtimes
        rows = np.full(len(x), row, dtype=np.int64)
        with torch.no_grad():
            ref = model(torch.from_numpy(x), torch.from_numpy(rows))["depths"].numpy()
        got = onx.run(x, dirs, rows)
        np.testing.assert_allclose(got["depths"], ref, rtol=1e-5, atol=1e-5)
        out[row] = got["depths"]
    assert np.abs(out[0] - out[3]).max() > 1e-2  # two classes, two outputs
    # no class (None: -1 each) is the torch model without a class input (the code as the encoder gives it)
    with torch.no_grad():
        plain = model(torch.from_numpy(x))["depths"].numpy()
    np.testing.assert_allclose(onx.run(x, dirs)["depths"], plain, rtol=1e-5, atol=1e-5)


def test_onnx_completer_gates_clips_and_completes_like_torch(hit_export):
    """A frame with a car, a bus (both learned), a truck (in the vocabulary, not learned) and a construction
    vehicle (neither): the truck and the construction vehicle are left as observed points and counted; with
    complete_unknown every box is completed, each as the torch Completer completes it (its class row or -1);
    every point lies in its box grown by 0.15 m (by hand, axis-aligned boxes)."""
    ckpt, path = hit_export
    onx, ref = load_onnx_completer(path), load_completer(ckpt, device="cpu")
    boxes = [
        box([8.0, 3.0, 0.8], [4.4, 1.8, 1.5], "car"),
        box([14.0, -3.0, 1.6], [12.0, 2.5, 3.2], "bus"),
        box([-15.0, 4.0, 1.5], [8.0, 2.4, 3.0], "truck"),
        box([-10.0, -8.0, 1.5], [6.0, 2.4, 3.0], "construction"),
    ]
    rng = np.random.default_rng(1)
    pts = np.concatenate([rng.uniform(-0.45, 0.45, (300, 3)) * b.size + b.center for b in boxes])
    res = complete_frame(pts, boxes, onx, heading_check=False)
    assert [o.status for o in res.objects] == ["completed", "completed", "not_learned", "not_learned"]
    assert res.summary()["not_completed"] == {"truck": 1, "construction": 1}
    a = complete_frame(pts, boxes, onx, heading_check=False, complete_unknown=True)
    b = complete_frame(pts, boxes, ref, heading_check=False, complete_unknown=True)
    assert all(o.status == "completed" for o in a.objects)
    for bx, p, q in zip(boxes, a.objects, b.objects):
        assert len(p.completion) == len(q.completion) > 0
        np.testing.assert_allclose(p.completion, q.completion, atol=1e-4)
        assert np.all(np.abs(p.completion - bx.center) <= bx.size / 2 + 0.15 + 1e-5)
        assert p.inside_box == pytest.approx(q.inside_box, abs=1e-6)
    # the class decides: the same car scan completed as a bus differs
    x = scans(1)
    e = unit_extents(np.array([[4.4, 1.8, 1.5]]))
    car, bus = (onx.complete(x, extents=e, classes=[c])[0] for c in ("car", "bus"))
    assert len(car) != len(bus) or np.abs(car - bus).max() > 1e-3


def test_bad_class_rows_are_one_line_errors(hit_export, tmp_path):
    _, path = hit_export
    onx = load_onnx_completer(path)
    x = scans(2)
    dirs = directions_for_extents(BOX, unit_extents(np.array([[4.4, 1.8, 1.5]] * 2)))
    for bad, words in [
        (np.array([0.0, 3.0]), "integer array"),
        (np.array([[0], [3]]), "of shape (2, 1)"),
        (np.array([0, 1, 2]), "(2,) integer array"),
        (np.array(["car", "bus"]), "complete(classes=...)"),
        (np.array([0, 5]), "class row 5"),
        (np.array([-2, 0]), "class row -2"),
    ]:
        with pytest.raises(ParameterError) as err:
            onx.run(x, dirs, bad)
        msg = str(err.value)
        assert "\n" not in msg and words in msg and "cls.onnx" in msg and "0..4 (car, caravan" in msg, msg
    # an export without a class input says so; one whose metadata lost the vocabulary is a damaged file
    plain = load_onnx_completer(
        export_onnx(make_checkpoint(tmp_path / "p.pt", "sanet-hit", rig=BOX), tmp_path / "p.onnx")
    )
    with pytest.raises(ParameterError, match="p.onnx has no class input"):
        plain.run(x, dirs, np.array([0, 1]))
    proto = onnx.load(str(path))
    keep = [m for m in proto.metadata_props if m.key != "classes"]
    del proto.metadata_props[:]
    proto.metadata_props.extend(keep)
    onnx.save(proto, str(tmp_path / "damaged.onnx"))
    with pytest.raises(InputFileError, match="damaged.onnx.*without a 'classes' input, or the reverse"):
        load_onnx_completer(tmp_path / "damaged.onnx")


def test_old_export_without_class_input_completes_every_class_as_a_car(tmp_path):
    """An export without a class input (every export before it) ignores the boxes' classes, as its torch model
    does: a bus box's scan is completed exactly as the same scan in a car box of the same size."""
    ckpt = make_checkpoint(tmp_path / "old.pt", "sanet-hit", rig=BOX)
    onx = load_onnx_completer(export_onnx(ckpt, tmp_path / "old.onnx"))
    assert onx.classes == () and "classes" not in onx.inputs and onx.meta["spotlights_format_version"] == "1"
    x, e = scans(2), unit_extents(np.array([[4.4, 1.8, 1.5]] * 2))
    a, b = onx.complete(x, extents=e, classes=["car", "bus"]), onx.complete(x, extents=e)
    assert all(np.array_equal(p, q) for p, q in zip(a, b))


def test_complete_cli_runtime_onnx_with_a_class_export_and_an_onnx_fallback(hit_export, tmp_path, capsys):
    """`complete --runtime onnx --checkpoint CLASS.onnx` gives the torch checkpoint's points and statuses; an
    ONNX car-only model with `--fallback CLASS.onnx` leaves the car to the main model, gives the bus to the
    fallback and the truck (learned by neither) to no one."""
    ckpt, path = hit_export
    rng = np.random.default_rng(6)
    scan = np.concatenate(
        [
            rng.uniform([5.8, 2.1, 0.2], [10.2, 2.15, 1.5], (300, 3)),  # a car's side
            rng.uniform([8.0, -4.25, 0.1], [20.0, -4.2, 3.2], (600, 3)),  # a bus's side
            rng.uniform([-19.0, 2.8, 0.1], [-11.0, 2.85, 3.0], (400, 3)),  # a truck's side
        ]
    )
    np.save(tmp_path / "scan.npy", scan)
    boxes = [
        {"center": [8.0, 3.0, 0.8], "size": [4.4, 1.8, 1.5], "yaw": 0.0, "label": "car"},
        {"center": [14.0, -3.0, 1.6], "size": [12.0, 2.5, 3.2], "yaw": 0.0, "label": "bus"},
        {"center": [-15.0, 4.0, 1.5], "size": [8.0, 2.4, 3.0], "yaw": 0.0, "label": "truck"},
    ]
    (tmp_path / "boxes.json").write_text(json.dumps(boxes))
    args = ["complete", tmp_path / "scan.npy", "--boxes", tmp_path / "boxes.json", "-q"]

    def run(name, *extra):
        proc = cli(capsys, *args, "--out", tmp_path / f"{name}.npy", "--summary", tmp_path / f"{name}.json", *extra)
        assert proc.returncode == 0, proc.stderr
        summ = json.loads((tmp_path / f"{name}.json").read_text())
        return np.load(tmp_path / f"{name}.npy"), [(o["status"], o.get("completed_by")) for o in summ["objects"]]

    pa, sa = run("onnx", "--checkpoint", path, "--runtime", "onnx")
    pb, sb = run("torch", "--checkpoint", ckpt)
    assert sa == sb == [("completed", None), ("completed", None), ("not_learned", None)]
    assert pa.shape == pb.shape and len(pa) > 0 and np.abs(pa - pb).max() < 1e-4
    car_only = export_onnx(make_checkpoint(tmp_path / "car.pt", "sanet-hit", rig=BOX), tmp_path / "car.onnx")
    _, sc = run("fallback", "--checkpoint", car_only, "--runtime", "onnx", "--fallback", path)
    assert sc == [("completed", None), ("completed", str(path)), ("not_learned", None)]
