"""A model that knows the class (a zero-initialised class embedding), the learned-domain gate
(an unknown class is left as observed points and counted) and every SA-Net ray clipped to the box grown by
0.15 m at decoding (checked against a hand-computed ray/box intersection)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from spotlights.api import complete_frame
from spotlights.completion.frame import SceneConfig
from spotlights.completion.pictures import scene_objects
from spotlights.completion.scan import CompletionOptions, resolve_fallback
from spotlights.data.real.base import lookup_class
from spotlights.data.real.boxfiles import CLASS_MAP
from spotlights.data.vehicle_classes import VEHICLE_CLASSES, canonical_class
from spotlights.geometry.boxes import Box
from spotlights.geometry.rig import make_rig_spec
from spotlights.learning.inference import Completer, complete_in_boxes, load_completer
from spotlights.learning.models.sanet_hit import HitSANet

from helpers import assert_user_error, run_cli

VOCAB = ["car", "caravan", "truck", "bus", "trailer"]


def tiny(classes=None, seed=0, templates=False) -> HitSANet:
    torch.manual_seed(seed)
    m = HitSANet(
        make_rig_spec(8, 8, kind="box"),
        code_size=32,
        encoder_widths=(8, 16, 16),
        hidden=(16,),
        classes=classes,
        class_templates=templates,
    )
    return m.eval()


def box(center, size, label, cls) -> Box:
    return Box(np.asarray(center, float), np.asarray(size, float), np.eye(3), label, cls, None)


def bus_and_police(seed: int) -> tuple[Box, Box, np.ndarray]:
    """A 12 m bus (learned by the class model only) and a police car (class emergency: learned by neither model),
    each with points on the side facing the sensor: (bus, police, (900, 3) points)."""
    rng = np.random.default_rng(seed)
    bus = box([14.0, -3.0, 1.6], [12.0, 2.5, 3.2], "bus", "bus")
    police = box([8.0, 3.0, 0.8], [4.9, 1.9, 1.9], "police", "emergency")
    pts = np.concatenate(
        [
            rng.uniform([-6.0, -1.25, -1.5], [6.0, -1.2, 1.6], (600, 3)) + bus.center,
            rng.uniform([-2.4, -0.95, -0.8], [2.4, -0.9, 0.9], (300, 3)) + police.center,
        ]
    )
    return bus, police, pts


def test_zero_embedding_starts_as_the_model_without_classes_and_classes_then_differ():
    plain, cond = tiny(), tiny(VOCAB)
    cond.load_state_dict(plain.state_dict(), strict=False)  # the embedding keeps its zeros
    x = torch.rand(2, 40, 3) - 0.5
    with torch.no_grad():
        ref = plain(x)["depths"]
        same = cond(x, torch.tensor([0, 3]))["depths"]
        assert torch.equal(ref, same)
        torch.nn.init.normal_(cond.class_embedding.weight)
        car, bus = (cond(x, torch.tensor([k, k]))["depths"] for k in (0, 3))
        none = cond(x, torch.tensor([-1, -1]))["depths"]
    assert (car - bus).abs().max() > 1e-3  # two classes, two outputs for the same input
    assert torch.equal(none, ref)  # no class (-1): the code as the encoder gives it
    assert cond.class_indices(["van", "bus", None, "construction"]).tolist() == [1, 3, -1, -1]


def test_class_templates_start_neutral_add_their_class_row_and_learn_only_it():
    """``class_templates``: zero rows give the model without them (and a checkpoint without them loads as a
    fine-tune's start); a row is added, exactly, to the outputs of its class only (-1: nothing); the loss's
    gradient reaches only the rows of the batch's classes."""
    cond = tiny(VOCAB)
    tmpl = tiny(VOCAB, seed=0, templates=True)
    missing, unexpected = tmpl.load_state_dict(cond.state_dict(), strict=False)
    assert missing == ["class_template.weight"] and not unexpected
    x = torch.rand(3, 40, 3) - 0.5
    rows = torch.tensor([0, 4, -1])
    with torch.no_grad():
        ref = cond(x, rows)
        out = tmpl(x, rows)
        assert all(torch.equal(ref[k], out[k]) for k in ("hit_logits", "depths"))
        w = torch.randn_like(tmpl.class_template.weight)
        tmpl.class_template.weight.copy_(w)
        out = tmpl(x, rows)
    n = tmpl.rig.n_rays
    for b, r in enumerate(rows.tolist()):  # logits then depths: the row's two halves, by hand
        add = w[r] if r >= 0 else torch.zeros(2 * n)
        torch.testing.assert_close(out["hit_logits"][b], ref["hit_logits"][b] + add[:n], rtol=0, atol=1e-6)
        torch.testing.assert_close(out["depths"][b], ref["depths"][b] + add[n:], rtol=0, atol=1e-6)
    tmpl.train()
    o = tmpl(x, rows)
    (o["hit_logits"].sum() + o["depths"].sum()).backward()
    g = tmpl.class_template.weight.grad
    assert g[0].abs().sum() > 0 and g[4].abs().sum() > 0 and g[1:4].abs().sum() == 0
    with pytest.raises(ValueError, match="class vocabulary"):
        HitSANet(make_rig_spec(8, 8, kind="box"), code_size=32, hidden=(16,), class_templates=True)


def test_init_from_a_checkpoint_without_templates_starts_as_it(tmp_path):
    """``model.init`` of a run with ``class_templates`` from a checkpoint without them: the new rows start at zero
    and the model gives the checkpoint's outputs."""
    from spotlights.learning.checkpoint import save_checkpoint
    from spotlights.learning.training_run import init_from_checkpoint

    cond = tiny(VOCAB, seed=3)
    path = tmp_path / "c.pt"
    save_checkpoint(path, {"model_name": "sanet-hit", "model_state": cond.state_dict(), "config": {}})
    tmpl = tiny(VOCAB, seed=1, templates=True)
    init_from_checkpoint(tmpl, path)
    x = torch.rand(2, 40, 3) - 0.5
    with torch.no_grad():
        assert torch.equal(tmpl(x, torch.tensor([2, 3]))["depths"], cond(x, torch.tensor([2, 3]))["depths"])
    assert float(tmpl.class_template.weight.detach().abs().sum()) == 0.0


def test_depths_clipped_to_a_long_box_match_a_hand_computed_intersection():
    m = tiny()
    half = torch.tensor([[0.95, 0.15, 0.25]], dtype=torch.float64)  # a long, thin box in the unit frame
    o = m.origins.double()  # (R, 3) ray origins on the unit sphere
    r = 5
    # three rays through the centre (u = -o): p(t) = o (1 - t) is inside iff |1 - t| <= s, s = min_i h_i / |o_i|
    s = float(torch.min(half[0] / o[r].abs()))
    u = torch.zeros(1, len(o), 3, dtype=torch.float64)
    u[0] = -o  # every ray through the centre
    t_in, t_out = 1.0 - s, 1.0 + s
    depths = torch.zeros(1, len(o), dtype=torch.float64)
    depths[0, r] = 0.99  # t = 1.98 > t_out: moves back to the exit
    keep = torch.zeros(1, len(o), dtype=torch.bool)
    keep[0, r] = True
    d, k, inside = m.clip_to_boxes(depths.float(), keep, u.float(), half.float())
    assert bool(k[0, r]) and float(inside[0]) == 0.0
    assert float(d[0, r]) == pytest.approx(t_out / 2.0, abs=1e-6)
    depths[0, r] = 0.5 * (t_in + 0.5 * (t_out - t_in))  # inside: unchanged
    d, _, inside = m.clip_to_boxes(depths.float(), keep, u.float(), half.float())
    assert float(d[0, r]) == pytest.approx(float(depths[0, r]), abs=1e-7) and float(inside[0]) == 1.0
    depths[0, r] = 0.01  # t = 0.02 < t_in: moves forward to the entry
    d, _, _ = m.clip_to_boxes(depths.float(), keep, u.float(), half.float())
    assert float(d[0, r]) == pytest.approx(t_in / 2.0, abs=1e-6)
    # a ray along x from an origin above the box's top (|o_z| > 0.25) stays at that height: it never meets the box
    q = int(torch.nonzero(o[:, 2].abs() > 0.3)[0])
    u[0, q] = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    depths[0, q], keep[0, q] = 0.3, True
    depths[0, r] = 0.5 * (t_in + 0.5 * (t_out - t_in))  # inside: 1 of the 2 kept rays was inside
    _, k, inside = m.clip_to_boxes(depths.float(), keep, u.float(), half.float())
    assert not bool(k[0, q]) and bool(k[0, r]) and float(inside[0]) == 0.5


def test_every_completion_point_lies_in_the_grown_long_box():
    m = tiny()
    comp = Completer(m, {"model_name": "sanet-hit"}, torch.device("cpu"))
    sizes = np.array([[16.0, 2.5, 4.0], [4.5, 1.8, 1.5]])
    x = (np.random.default_rng(0).uniform(-0.4, 0.4, (2, 50, 3))).astype(np.float32)
    shares: list = []
    out = complete_in_boxes(comp, x, sizes, inside=shares)
    r = np.linalg.norm(sizes, axis=1) / 2
    for pts, s, rr in zip(out, sizes, r):
        h = (s / 2 + 0.15) / rr  # the grown box's half-extents in the unit frame, by hand
        assert len(pts) and np.all(np.abs(pts) <= h + 1e-6)
    assert len(shares) == 2 and all(0.0 <= v <= 1.0 for v in shares)


def test_unknown_class_is_left_as_observed_points_and_counted():
    comp = Completer(tiny(VOCAB[:1]), {"model_name": "sanet-hit"}, torch.device("cpu"))  # old domain: cars only
    rng = np.random.default_rng(1)
    boxes = [box([8, 0, 0.8], [4.4, 1.8, 1.5], "car", "car"), box([-15, 4, 1.5], [4.6, 1.9, 1.6], "Bus", "bus")]
    pts = np.concatenate([rng.uniform(-0.45, 0.45, (200, 3)) * b.size + b.center for b in boxes])
    res = complete_frame(pts, boxes, comp)
    assert [o.status for o in res.objects] == ["completed", "not_learned"]
    summ = res.summary()
    assert summ["not_completed"] == {"bus": 1} and summ["skipped"] == {"not_learned": 1}
    assert np.sum(res.source == 2) == len(res.objects[0].completion)  # only the car has completion points
    drawn = scene_objects(res)  # the picture shows the bus too: its box and its points, no completion
    assert [(d.label, d.completion is None) for d in drawn] == [("0", False), ("1", True)]
    bus = pts[200:]  # its points above the ground clearance (0.10 m over the box bottom) are the crop
    above = np.sum(bus[:, 2] >= boxes[1].center[2] - boxes[1].size[2] / 2 + 0.10)
    assert len(drawn[1].partial) == above and np.allclose(drawn[1].box.center, boxes[1].center)
    res = complete_frame(pts, boxes, comp, SceneConfig(complete_unknown=True))
    assert [o.status for o in res.objects] == ["completed", "completed"] and res.summary()["not_completed"] == {}


def test_old_checkpoint_without_classes_still_completes_cars():
    comp = load_completer("default")
    assert comp.classes == () and comp.domain.classes == ("car",)
    rng = np.random.default_rng(2)
    car = box([10, 2, 0.8], [4.5, 1.9, 1.6], "Car", "car")
    truck = box([-20, 0, 1.8], [16.7, 2.9, 3.9], "vehicle.truck", "truck")
    pts = np.concatenate([rng.uniform(-0.45, 0.45, (300, 3)) * b.size + b.center for b in (car, truck)])
    res = complete_frame(pts, [car, truck], comp)
    assert [o.status for o in res.objects] == ["completed", "not_learned"]
    assert len(res.objects[0].completion) > 1000


@pytest.mark.parametrize(
    "label, cls",
    [
        ("Van", "caravan"),  # KITTI
        ("caravan", "caravan"),  # KITTI-360
        ("LARGE_VEHICLE", "caravan"),  # Argoverse 2
        ("ARTICULATED_BUS", "bus"),
        ("VEHICULAR_TRAILER", "trailer"),
        ("vehicle.bus.rigid", "bus"),  # nuScenes
        ("vehicle.trailer", "trailer"),
        ("vehicle.truck", "truck"),
        ("Truck", "truck"),  # generic
        ("vehicle.construction", "construction"),  # a reader class no model learns
    ],
)
def test_reader_labels_map_to_the_one_vocabulary(label, cls):
    got = lookup_class(label, CLASS_MAP)
    assert got == cls
    assert (canonical_class(got) in VEHICLE_CLASSES) == (cls != "construction")


def test_learned_domain_keeps_a_size_range_per_class_and_gates_far_outside_it():
    from spotlights.learning.domain import LearnedDomain

    sizes = np.array([[4.0, 1.8, 1.5], [5.0, 2.0, 1.7], [12.0, 2.5, 3.2], [10.0, 2.5, 3.0]])
    dom = LearnedDomain.from_training_set(
        ["sedan", "suv", "bus", "bus"], sizes, "hand", classes=["car", "car", "bus", "bus"]
    )
    assert dom.class_sizes == {"car": ((4.0, 1.8, 1.5), (5.0, 2.0, 1.7)), "bus": ((10.0, 2.5, 3.0), (12.0, 2.5, 3.2))}
    assert LearnedDomain.from_checkpoint({"domain": dom.to_dict()}) == dom
    assert dom.gate("car", (5.4, 1.9, 1.6)) is None and dom.warnings("car", (5.4, 1.9, 1.6)) == []  # within 10%
    assert dom.gate("car", (7.4, 1.9, 1.6)) is None and dom.warnings("car", (7.4, 1.9, 1.6))  # 48% over: a warning
    assert dom.gate("car", (7.6, 1.9, 1.6)) == "size"  # 52% over the car range (5.0 m): not completed
    assert dom.gate("bus", (11.0, 2.5, 3.1)) is None and dom.gate("truck", (11.0, 2.5, 3.1)) == "class"
    assert dom.gate(None, (11.0, 2.5, 3.1)) is None  # no class given: the overall range decides


def test_shipped_classes_model_completes_a_bus_the_default_leaves_as_observed():
    """`--checkpoint classes` (pretrained/classes.pt, the class-conditioned fine-tune) learned buses: it
    completes a 12 x 2.5 x 3.2 m bus that the car-only default leaves as its observed points; every completion
    point lies in the box grown by 0.15 m (checked by hand in the box frame)."""
    rng = np.random.default_rng(3)
    bus = box([14.0, -3.0, 1.6], [12.0, 2.5, 3.2], "bus", "bus")
    side = rng.uniform([-6.0, -1.25, -1.5], [6.0, -1.2, 1.6], (600, 3))  # the side facing the sensor
    back = rng.uniform([-6.0, -1.25, -1.5], [-5.95, 1.25, 1.6], (200, 3))
    pts = np.concatenate([side, back]) + bus.center
    default = complete_frame(pts, [bus], load_completer("default"))
    assert default.objects[0].status == "not_learned" and default.summary()["not_completed"] == {"bus": 1}
    cls = load_completer("classes")
    assert cls.classes == VEHICLE_CLASSES and "bus" in cls.domain.class_sizes
    res = complete_frame(pts, [bus], cls)
    (o,) = res.objects
    assert o.status == "completed" and len(o.completion) > 1000
    local = o.completion - bus.center  # the box is axis-aligned: its frame is the scan's, shifted
    assert np.all(np.abs(local) <= bus.size / 2 + 0.15 + 1e-6)


def test_fallback_model_completes_what_the_main_model_did_not_learn_and_leaves_the_rest_alone():
    """`--fallback classes` beside the car-only default: the car is completed by the default exactly as without a
    fallback (same points), the bus by the fallback (named in completed_by, inside its grown box), nothing left."""
    rng = np.random.default_rng(5)
    car = box([8.0, 3.0, 0.8], [4.4, 1.8, 1.5], "car", "car")
    bus = box([14.0, -3.0, 1.6], [12.0, 2.5, 3.2], "bus", "bus")
    pts = np.concatenate(
        [
            rng.uniform([-2.2, -0.9, -0.6], [2.2, -0.85, 0.7], (300, 3)) + car.center,
            rng.uniform([-6.0, -1.25, -1.5], [6.0, -1.2, 1.6], (600, 3)) + bus.center,
        ]
    )
    default = load_completer("default")
    alone = complete_frame(pts, [car, bus], default)
    both = complete_frame(pts, [car, bus], default, fallback="classes", heading_check=False)
    assert [o.status for o in alone.objects] == ["completed", "not_learned"]
    assert [o.status for o in both.objects] == ["completed", "completed"]
    assert both.objects[0].completed_by is None and both.objects[1].completed_by == "classes"
    np.testing.assert_array_equal(both.objects[0].completion, alone.objects[0].completion)
    assert both.summary()["objects"][1]["completed_by"] == "classes" and both.summary()["not_completed"] == {}
    # the bus, completed on the fallback's thread beside the car's batch, is what the class model alone makes of it
    only = complete_frame(pts, [bus], load_completer("classes"), fallback="none", heading_check=False)
    np.testing.assert_array_equal(both.objects[1].completion, only.objects[0].completion)
    assert both.objects[1].fidelity == only.objects[0].fidelity
    local = both.objects[1].completion - bus.center
    assert len(local) > 1000 and np.all(np.abs(local) <= bus.size / 2 + 0.15 + 1e-6)
    # with the heading check both models' batches double and come back in order: the car is still the default's
    checked = complete_frame(pts, [car, bus], default, fallback="classes", heading_check=True)
    ref = complete_frame(pts, [car, bus], default, heading_check=True)
    np.testing.assert_array_equal(checked.objects[0].completion, ref.objects[0].completion)
    assert checked.objects[1].status == "completed" and checked.objects[1].inside_box is not None


def test_a_vehicle_class_the_default_did_not_learn_points_to_the_class_model():
    """A bus left as observed points by the car-only default: its warning names `--fallback classes` (the packaged
    class model learned buses); an emergency vehicle (learned by neither) and a bus with a fallback given do not."""
    bus, police, pts = bus_and_police(seed=7)
    default = load_completer("default")
    res = complete_frame(pts, [bus, police], default, heading_check=False)
    assert [o.status for o in res.objects] == ["not_learned", "not_learned"]
    assert any("--fallback classes" in w for w in res.objects[0].warnings)
    assert not any("--fallback classes" in w for w in res.objects[1].warnings)
    both = complete_frame(pts, [bus, police], default, fallback="classes", heading_check=False)
    assert [o.status for o in both.objects] == ["completed", "not_learned"]
    assert not any("--fallback classes" in w for o in both.objects for w in o.warnings)
    # the emergency vehicle's warning says the fallback did not learn it either
    assert any("nor did the fallback classes learn it" in w for w in both.objects[1].warnings)


def test_complete_cli_fallback_option(tmp_path):
    """`spotlights complete SCAN --boxes B --fallback classes`: the summary says who completed which box."""
    rng = np.random.default_rng(6)
    scan = np.concatenate(
        [
            rng.uniform([5.8, 2.1, 0.2], [10.2, 2.15, 1.5], (300, 3)),  # a car's side
            rng.uniform([8.0, -4.25, 0.1], [20.0, -4.2, 3.2], (600, 3)),  # a bus's side
        ]
    )
    np.save(tmp_path / "scan.npy", scan)
    boxes = [
        {"center": [8.0, 3.0, 0.8], "size": [4.4, 1.8, 1.5], "yaw": 0.0, "label": "car"},
        {"center": [14.0, -3.0, 1.6], "size": [12.0, 2.5, 3.2], "yaw": 0.0, "label": "bus"},
    ]
    (tmp_path / "boxes.json").write_text(json.dumps(boxes))
    args = ["complete", tmp_path / "scan.npy", "--boxes", tmp_path / "boxes.json", "--out", tmp_path / "o.ply"]
    proc = run_cli(*args, "--summary", tmp_path / "s.json", "--fallback", "classes")
    assert proc.returncode == 0, proc.stderr
    summ = json.loads((tmp_path / "s.json").read_text())
    objs = summ["objects"]
    assert [(o["status"], o.get("completed_by")) for o in objs] == [("completed", None), ("completed", "classes")]
    assert summ["checkpoint"] == "default + fallback classes"  # what real complete --resume compares
    proc = run_cli(*args[:-1], tmp_path / "none.ply", "--summary", tmp_path / "t.json", "--fallback", "none")
    summ = json.loads((tmp_path / "t.json").read_text())
    assert [o["status"] for o in summ["objects"]] == ["completed", "not_learned"]
    assert summ["checkpoint"] == "default"
    # no --fallback: 'auto', the class model beside the default, the same bytes as '--fallback classes'
    proc = run_cli(*args[:-1], tmp_path / "auto.ply", "--summary", tmp_path / "u.json")
    assert proc.returncode == 0, proc.stderr
    auto = json.loads((tmp_path / "u.json").read_text())
    assert "2 completed (1 by the fallback classes)" in proc.stdout + proc.stderr  # the one summary line says so
    assert auto["checkpoint"] == "default + fallback classes"
    assert [(o["status"], o.get("completed_by")) for o in auto["objects"]] == [
        ("completed", None),
        ("completed", "classes"),
    ]
    assert (tmp_path / "auto.ply").read_bytes() == (tmp_path / "o.ply").read_bytes()
    # a model the user chose gets no fallback unless asked for one
    proc = run_cli(*args[:-1], tmp_path / "cls.ply", "--summary", tmp_path / "v.json", "--checkpoint", "classes")
    assert json.loads((tmp_path / "v.json").read_text())["checkpoint"] == "classes"
    bad = [*args[:-1], tmp_path / "bad.ply", "--fallback", tmp_path / "nope.pt"]
    assert_user_error(run_cli(*bad), "nope.pt", "no such checkpoint file")
    assert not (tmp_path / "bad.ply").exists()


def test_resolve_fallback_auto_is_the_class_model_beside_the_default_only():
    """``--fallback auto`` (the default): the packaged class model beside the packaged default (no --checkpoint,
    or 'default') on either runtime (the class model's export ships); nothing beside a model the user chose; 'none'
    is none."""
    assert resolve_fallback("auto") == "classes" and resolve_fallback("AUTO", "default") == "classes"
    assert resolve_fallback("auto", "default", "torch") == "classes"
    assert resolve_fallback("auto", "paper") is None and resolve_fallback("auto", "runs/x/best.pt") is None
    assert resolve_fallback("auto", "classes") is None and resolve_fallback("auto", "runs/x/m.onnx", "onnx") is None
    assert resolve_fallback("auto", None, "onnx") == "classes"  # its export ships: an ONNX run stays torch-free
    assert resolve_fallback("none") is None and resolve_fallback("None", "default") is None
    assert resolve_fallback(None) is None
    assert resolve_fallback("my.pt", "paper") == "my.pt"  # an explicit model is used as given
    opts = CompletionOptions()
    assert opts.fallback_model == "classes" and opts.checkpoint_name == "default + fallback classes"
    assert CompletionOptions(fallback="none").checkpoint_name == "default"
    assert CompletionOptions(checkpoint="paper").checkpoint_name == "paper"


def test_api_complete_frame_by_name_completes_a_bus_with_the_class_model():
    """``spotlights.complete_frame(points, boxes)`` (the default model by name, fallback 'auto') completes a bus with
    the packaged class model; fallback='none', or a loaded model without a fallback, leaves it as observed points."""
    rng = np.random.default_rng(8)
    bus = box([14.0, -3.0, 1.6], [12.0, 2.5, 3.2], "bus", "bus")
    pts = rng.uniform([-6.0, -1.25, -1.5], [6.0, -1.2, 1.6], (600, 3)) + bus.center
    res = complete_frame(pts, [bus], heading_check=False)
    assert res.objects[0].status == "completed" and res.objects[0].completed_by == "classes"
    assert complete_frame(pts, [bus], "default", fallback="none").objects[0].status == "not_learned"
    assert complete_frame(pts, [bus], load_completer("default")).objects[0].status == "not_learned"


def test_complete_unknown_leaves_what_the_fallback_learned_to_the_fallback():
    """``--complete-unknown`` is for what neither model learned: a bus still goes to the class model beside the
    default (not to the car model), an emergency vehicle (learned by neither) to the main model."""
    bus, police, pts = bus_and_police(seed=9)
    res = complete_frame(pts, [bus, police], complete_unknown=True, heading_check=False)
    assert [(o.status, o.completed_by) for o in res.objects] == [("completed", "classes"), ("completed", None)]
    res = complete_frame(pts, [bus, police], heading_check=False)
    assert [(o.status, o.completed_by) for o in res.objects] == [("completed", "classes"), ("not_learned", None)]
    # with the heading check, both models' doubled batches stay in order: the same completions as each box alone
    both = complete_frame(pts, [bus, police], complete_unknown=True, heading_check=True)
    assert [(o.status, o.completed_by) for o in both.objects] == [("completed", "classes"), ("completed", None)]
    for k, b in enumerate((bus, police)):
        alone = complete_frame(pts, [b], complete_unknown=True, heading_check=True).objects[0]
        np.testing.assert_array_equal(both.objects[k].completion, alone.completion)


def test_api_complete_one_object_takes_the_fallback_option():
    """``spotlights.complete`` completes a bus with the class model by default; ``fallback="none"`` refuses it in one
    line (the car-only default did not learn it)."""
    from spotlights.api import complete
    from spotlights.errors import ParameterError

    rng = np.random.default_rng(10)
    bus = box([14.0, -3.0, 1.6], [12.0, 2.5, 3.2], "bus", "bus")
    pts = rng.uniform([-6.0, -1.25, -1.5], [6.0, -1.2, 1.6], (600, 3)) + bus.center
    o = complete(pts, bus, heading_check=False)
    assert o.status == "completed" and o.completed_by == "classes" and len(o.completion) > 1000
    with pytest.raises(ParameterError, match="did not learn this box"):
        complete(pts, bus, fallback="none")


def test_real_complete_counts_the_boxes_the_fallback_completed(tmp_path):
    """`real complete` on two nuScenes keyframes, the default with its fallback: summary.json's totals count the
    boxes the class model completed (equal to the frames' objects marked completed_by) and the line says so."""
    from helpers import LIDAR, need

    src = need(LIDAR / "nuscenes")
    out = tmp_path / "o"
    proc = run_cli("real", "complete", src, "--format", "nuscenes", "--frames", "0:2", "--no-pictures", "--out", out)
    assert proc.returncode == 0, proc.stderr
    summ = json.loads((out / "summary.json").read_text())
    by = [
        o["completed_by"]
        for p in sorted(out.glob("*/*.json"))
        for o in json.loads(p.read_text())["objects"]
        if o.get("completed_by")
    ]
    assert by and set(by) == {"classes"} and summ["totals"]["completed_by"] == {"classes": len(by)}
    assert f"({len(by)} by the fallback classes)" in proc.stdout + proc.stderr


def test_data_classes_keeps_one_class_family_and_its_learned_domain(tmp_path):
    """``data.classes`` (one model per class family): the split keeps only the models of those classes (their
    samples, model by model), the learned domain a training run records is theirs alone, a class with no model in
    the split is a one-line error naming the file, and the config key must be a list of names."""
    from spotlights.errors import InputFileError, ParameterError
    from spotlights.learning.config import data_config
    from spotlights.learning.data import TorchCompletionDataset
    from spotlights.learning.domain import LearnedDomain

    from learning_fixtures import write_tiny_dataset

    layout = (
        ("sedan", "train"),
        ("bus", "train"),
        ("suv", "train"),
        ("bus", "train"),
        ("bus", "val"),
        ("sedan", "val"),
    )
    path = write_tiny_dataset(tmp_path / "mix.h5", views=3, layout=layout)
    every = TorchCompletionDataset(path, "train", rig=False)
    buses = TorchCompletionDataset(path, "train", rig=False, only_classes=["Bus"])
    assert every.model_rows.tolist() == [0, 1, 2, 3] and buses.model_rows.tolist() == [1, 3]
    assert len(buses) == 6 and sorted(set(buses.sample_models.tolist())) == [1, 3]
    assert TorchCompletionDataset(path, "val", rig=False, only_classes=["bus"]).model_rows.tolist() == [4]
    rows = buses.model_rows  # what training records as the learned domain (train._learned_domain)
    dom = LearnedDomain.from_training_set(buses.info.categories[rows], np.ones((2, 3)) * 10, "mix.h5")
    assert dom.classes == ("bus",)
    with pytest.raises(InputFileError, match="mix.h5.*no models of class trailer"):
        TorchCompletionDataset(path, "train", rig=False, only_classes=["trailer"])
    assert data_config({"data": {"classes": ["trailer"]}}).classes == ("trailer",)
    assert data_config({"data": {}}).classes is None
    for bad in ("trailer", [], [3]):
        with pytest.raises(ParameterError, match="data.classes must be a list"):
            data_config({"data": {"classes": bad}})


def car_and_bus(seed: int):
    """A car box and a bus box with points filling each (scan frame, metres): (car, bus, (1000, 3) points)."""
    rng = np.random.default_rng(seed)
    car = box([8.0, 2.0, 0.7], [4.3, 1.8, 1.5], "car", "car")
    bus = box([14.0, -3.0, 1.6], [12.0, 2.5, 3.2], "bus", "bus")
    pts = np.concatenate(
        [
            rng.uniform(-0.5, 0.5, (400, 3)) * car.size + car.center,
            rng.uniform(-0.5, 0.5, (600, 3)) * bus.size + bus.center,
        ]
    )
    return car, bus, pts


def test_complete_frame_loads_a_named_model_once(tmp_path, monkeypatch):
    """``complete_frame`` by name loads the default and its fallback on the first call only; the next calls use the
    same models (the same completions as with models loaded by the caller); a checkpoint file that is rewritten
    is loaded again."""

    from spotlights import api
    from spotlights.learning.runtime import load_completer as real_load

    from learning_fixtures import make_checkpoint

    loads = []
    monkeypatch.setattr(
        api, "load_completer", lambda name, *a, **k: loads.append(str(name)) or real_load(name, *a, **k)
    )
    car, bus, pts = car_and_bus(seed=11)
    first = complete_frame(pts, [car, bus])
    assert set(loads) <= {"default", "classes"}  # none if an earlier test of this process loaded them by name
    n = len(loads)
    again = complete_frame(pts, [car, bus])
    assert len(loads) == n  # kept: nothing loaded again
    mine = complete_frame(pts, [car, bus], real_load("default"), fallback=real_load("classes"))
    for a, b, c in zip(first.objects, again.objects, mine.objects):
        assert a.completed_by == b.completed_by and (a.completed_by is None) == (c.completed_by is None)
        assert np.array_equal(a.completion, b.completion) and np.array_equal(a.completion, c.completion)
    path = make_checkpoint(tmp_path / "m.pt", "sanet-hit")
    complete_frame(pts, [car], str(path), fallback="none")
    complete_frame(pts, [car], str(path), fallback="none")
    assert loads.count(str(path)) == 1
    make_checkpoint(path, "sanet-hit", seed=1)  # rewritten (a new file renamed over it: same size, maybe same mtime)
    complete_frame(pts, [car], str(path), fallback="none")
    assert loads.count(str(path)) == 2


def _forked_frame(conn, pts, boxes, models):
    """In a forked child: complete the frame (the fallback's thread and the fidelity threads are this process's)."""
    try:
        res = complete_frame(pts, boxes, models[0], fallback=models[1], heading_check=False)
        conn.send([None if o.completion is None else o.completion.tobytes() for o in res.objects])
    except BaseException as exc:  # reported to the parent, never left hanging
        conn.send(repr(exc))
    finally:
        conn.close()


@pytest.mark.timeout(300)
def test_a_process_forked_after_a_frame_completes_frames_too():
    """A process forked after ``complete_frame`` ran (a multiprocessing pool of frames) completes frames as the
    parent does: the fallback's and the fidelity's thread pools are rebuilt in the child, not inherited without
    their threads (which would wait forever). A child that does not answer in time is killed."""
    import multiprocessing as mp

    car, bus, pts = car_and_bus(seed=12)
    # on the CPU: a model that ran on CUDA cannot run in a forked child at all (docs/api.md); the test is the threads
    models = (load_completer("default", device="cpu"), load_completer("classes", device="cpu"))
    ref = complete_frame(pts, [car, bus], models[0], fallback=models[1], heading_check=False)
    import threading

    names = {t.name.rsplit("_", 1)[0] for t in threading.enumerate()}
    assert {"spotlights-fallback", "spotlights-fidelity"} <= names, names  # the parent's pool threads run
    ctx = mp.get_context("fork")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_forked_frame, args=(child, pts, [car, bus], models))
    proc.start()
    child.close()
    answer = parent.recv() if parent.poll(120) else "no answer in 120 s"
    proc.join(10)
    if proc.is_alive():
        proc.kill()
        proc.join()
    assert answer == [o.completion.tobytes() for o in ref.objects], answer
