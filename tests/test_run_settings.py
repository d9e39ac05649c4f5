"""The library behind the run-side commands: settings dataclasses and one function per command,
called from Python (no argparse), checked against hand counts and brute force."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from spotlights.completion.frame_selection import (
    FramesSettings,
    ReaderOptions,
    parse_frames,
    parse_frames_range,
    select_frames,
)
from spotlights.completion.frames import complete_frames
from spotlights.completion.scan import CompletionOptions, ScanSettings
from spotlights.errors import ParameterError, SpotlightsError
from spotlights.experiments.real_evaluation import RealEvaluationSettings, evaluate_consistency
from spotlights.experiments.real_runs import EvaluateSettings, report_names
from spotlights.files import EncodeSettings, RigOptions
from spotlights.geometry.io import load_ply_fields
from spotlights.options import settings_from_namespace
from spotlights.outputs import check_suffix

from builders import Identity, tracked_scene


def test_frame_specs_parse_and_select_by_hand():
    assert parse_frames_range("2:7:2") == (2, 7, 2)
    assert parse_frames_range(":3") == (0, 3, 1) and parse_frames_range("5:") == (5, None, 1)
    for bad in ("3", "a:b", "1:2:0", "1:2:3:4"):
        with pytest.raises(ParameterError, match="expected START:STOP"):
            parse_frames_range(bad)
    assert parse_frames(" 000123, 7 ,") == ("ids", ["000123", "7"])
    keys = [("", f"{i:03d}") for i in range(6)]
    assert select_frames(keys, parse_frames("1:6:2")) == [("", "001"), ("", "003"), ("", "005")]
    assert select_frames(keys, parse_frames("004,000")) == [("", "000"), ("", "004")]  # dataset order
    assert select_frames(keys, None) == keys
    with pytest.raises(ParameterError, match=r"frame\(s\) 9 not in the dataset"):
        select_frames(keys, ("ids", ["9"]))


def test_reader_options_refuse_another_formats_option():
    with pytest.raises(ParameterError, match="`boxes` applies to `format` generic only"):
        ReaderOptions(source=["nowhere"], format="kitti", boxes="b.json").open()
    with pytest.raises(ParameterError, match="`frames` applies to `format` kitti360 only"):
        ReaderOptions(source=["nowhere"], format="nuscenes").open(frames=(0, 2, 1))


def test_completion_options_give_the_scene_config():
    c = CompletionOptions().scene_config()
    assert (c.margin, c.ground_clearance, c.min_points, c.clip, c.keep_observed) == (0.15, 0.10, 10, "default", True)
    c = CompletionOptions(classes="Car, truck", clip=0.3, heading_check=True, heading_margin=0.2).scene_config()
    assert c.classes == ("car", "truck") and c.clip == 0.3 and c.heading_margin == 0.2
    assert CompletionOptions(no_clip=True).scene_config().clip is None
    with pytest.raises(ParameterError, match="`heading_margin` goes with `heading_check`"):
        CompletionOptions(heading_margin=0.2).scene_config()


def test_scan_settings_check_the_box_options():
    def scan(**kw):
        return ScanSettings(input="s.pcd", out="o.ply", **kw)

    with pytest.raises(ParameterError, match="the boxes are missing"):
        scan().check_boxes()
    with pytest.raises(ParameterError, match="not both"):
        scan(boxes="b.json", box="one.json").check_boxes()
    with pytest.raises(ParameterError, match="needs both `center`"):
        scan(center=[0, 0, 0]).check_boxes()
    with pytest.raises(ParameterError, match="needs both `center`"):  # the missing centre first, not the yaw
        scan(size=[4, 2, 1.5], yaw=0.3).check_boxes()
    with pytest.raises(ParameterError, match="`yaw` goes with `center`/`size`"):
        scan(box="one.json", yaw=0.0).check_boxes()
    scan(center=[0, 0, 0], size=[4, 2, 1.5], yaw=0.0).check_boxes()  # given with its box: fine
    with pytest.raises(ParameterError, match="give the crop margin once"):
        scan(box="one.json", margin=0.1, crop=0.2).scan_config()
    config = scan(box="one.json", crop=0.3).scan_config()
    assert config.margin == 0.3 and config.any_label  # one object: completed whatever its label
    assert scan(box="one.json", no_crop=True).scan_config().crop is False
    assert scan(boxes="b.json", crop=0.3).scan_config().margin == 0.15  # --crop is the single object's


def test_settings_from_a_namespace_and_suffix_checks(tmp_path):
    ns = argparse.Namespace(input="s.pcd", out="o.ply", box="b.json", func=print, command="complete")
    s = settings_from_namespace(ScanSettings, ns)  # options that are no field (func, command) are ignored
    assert (s.input, s.box, s.margin, s.min_points) == ("s.pcd", "b.json", None, 10)
    check_suffix(None, (".png",), "the picture")
    check_suffix(tmp_path / "a.PNG", (".png",), "the picture")
    with pytest.raises(ParameterError, match=r"--show x\.jpg: the picture is written as \.png; name it x\.png"):
        check_suffix("x.jpg", (".png",), "the picture", "--show")


class Ring:
    """A stand-in model: every object completed as the same 64-point ring (unit frame)."""

    model_name = "ring"
    calls = 0

    def complete(self, partials, clip=None):
        Ring.calls += 1
        t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
        ring = np.c_[0.8 * np.cos(t), 0.3 * np.sin(t), np.zeros_like(t)].astype(np.float32)
        return [ring for _ in partials]


def generic_scene(tmp_path: Path) -> Path:
    """Two frames, two cars each (300 points per car), and a pedestrian box that is not completed."""
    rng = np.random.default_rng(4)
    frames = []
    for f in range(2):
        pts, boxes = [rng.uniform(-30, 30, (500, 3)) * [1, 1, 0.01] - [0, 0, 1.6]], []
        for tid, c in (("1", [10.0 + f, 2.0, -0.8]), ("2", [-6.0, -5.0, -0.8])):
            obj = rng.uniform(-0.45, 0.45, (300, 3)) * [4.2, 1.8, 1.5]
            pts.append(obj + c)
            boxes.append({"center": c, "size": [4.2, 1.8, 1.5], "yaw": 0.0, "label": "car", "track_id": tid})
        boxes.append({"center": [0, 20, -0.8], "size": [0.6, 0.6, 1.7], "yaw": 0.0, "label": "pedestrian"})
        np.save(tmp_path / f"scan{f}.npy", np.concatenate(pts).astype(np.float32))
        frames.append({"scan": f"scan{f}.npy", "frame_id": f"f{f}", "timestamp": f, "boxes": boxes})
    (tmp_path / "scene.json").write_text(json.dumps({"frames": frames}))
    return tmp_path / "scene.json"


def test_complete_frames_from_python_writes_every_frame_and_resumes(tmp_path):
    src = generic_scene(tmp_path)
    out = tmp_path / "out"
    s = FramesSettings(source=[str(src)], format="generic", out=str(out), no_pictures=True, quiet=True)
    said = []
    Ring.calls = 0
    summary = complete_frames(s, say=said.append, completer=Ring())
    assert Ring.calls == 2  # one batch per frame
    # by hand: 2 frames x (2 cars + 1 pedestrian); every car completed as the 64-point ring
    assert summary["n_frames"] == 2
    assert summary["totals"]["boxes"] == 6 and summary["totals"]["completed"] == 4
    assert summary["totals"]["skipped"] == {"class_excluded": 2}
    assert summary["totals"]["completion_points"] == 4 * 64 + 4 * 256  # ring + the kept observed input
    fields = load_ply_fields(out / "f0.ply")
    assert len(fields["x"]) == 1100 + 2 * (64 + 256)  # every scan point once, then the completions
    assert (fields["source"] == 2).sum() == 2 * (64 + 256)
    assert json.loads((out / "summary.json").read_text())["totals"] == summary["totals"]
    assert summary["snap"] == 0.0 and summary["snap_mirror"] is False  # the run-level record of --snap
    with pytest.raises(ParameterError, match="ring has no rays to snap"):  # refused before any output
        complete_frames(FramesSettings(source=[str(src)], format="generic", out=str(tmp_path / "o2"), snap=0.05,
                                       no_pictures=True, quiet=True), completer=Ring())  # fmt: skip
    assert not (tmp_path / "o2").exists()
    (line,) = said
    assert line.startswith("2 frame(s), 6 boxes: 4 completed, skipped class_excluded 2 (ring, ")
    assert line.endswith(f" s of completion) -> {out}/")
    again = complete_frames(
        FramesSettings(source=[str(src)], format="generic", out=str(out), no_pictures=True, quiet=True, resume=True),
        completer=Ring(),
    )
    assert again["totals"]["resumed"] == 2 and Ring.calls == 2  # nothing completed again
    assert again["totals"]["completed"] == 4
    assert "precision" not in json.loads((out / "f0.json").read_text())  # fp32: as frames of older runs

    class RingBf16(Ring):
        precision = "bf16"

    third = complete_frames(
        FramesSettings(source=[str(src)], format="generic", out=str(out), no_pictures=True, quiet=True, resume=True),
        completer=RingBf16(),
    )
    assert third["totals"]["resumed"] == 0 and Ring.calls == 4  # frames made at fp32 are made again at bf16
    assert json.loads((out / "f0.json").read_text())["precision"] == "bf16"


def test_real_evaluation_settings_are_strict_and_scored_as_given(tmp_path):
    with pytest.raises(ParameterError, match="did you mean 'equal_points'"):
        RealEvaluationSettings.from_dict({"equal_point": 64})
    obs = tracked_scene(tmp_path)
    with pytest.raises(ParameterError, match="not both"):
        evaluate_consistency(obs, [Identity()], RealEvaluationSettings(), equal_points=64, progress=False)
    with pytest.raises(ParameterError, match="unknown setting 'noise'"):
        evaluate_consistency(obs, [Identity()], noise=False, progress=False)
    lean = RealEvaluationSettings(equal_points=None, equal_density=None, noise_floor=False, heading_check=False)
    (m,) = evaluate_consistency(obs, [Identity()], lean, progress=False)["models"]
    assert not {"equal_points", "equal_density", "heading"} & set(m)
    # Identity: consistency is the Chamfer distance between the two stored partials of the car (brute force)
    rows = [i for i, t in enumerate(obs.track_id) if t == "a"]
    d = cdist(obs.partial[rows[0]].astype(np.float64), obs.partial[rows[1]].astype(np.float64))
    assert m["classes"]["car"]["cd"] == pytest.approx(d.min(axis=1).mean() + d.min(axis=0).mean(), rel=1e-6)


def test_evaluate_settings_check_and_name_like_the_command():
    s = EvaluateSettings(file="runs/av2.h5", equal_points=0, no_heading_check=True)
    scoring = s.scoring()
    assert scoring.equal_points is None and scoring.heading_check is False and scoring.equal_density == 0.1
    assert s.prefix == "runs/av2_consistency" and s.checkpoints == ["default"]
    with pytest.raises(ParameterError, match="`names`: give 2 distinct names"):
        EvaluateSettings(file="a.h5", checkpoint=["a.pt", "b.pt"], names=["x", "x"]).scoring()
    with pytest.raises(ParameterError, match=r"`heading_margin` must be in \[0, 1\)"):
        EvaluateSettings(file="a.h5", heading_margin=1.0).scoring()
    names = report_names(["sanet", "sanet", "pcn"], ["runs/r1/best.pt", "other/sanet_b.pt", "pcn.pt"])
    assert names == ["sanet (r1)", "sanet (sanet_b)", "pcn"]


def test_rig_options_and_encode_targets(tmp_path):
    with pytest.raises(ParameterError, match="`box_scale` only apply with `rig_kind` box"):
        RigOptions(box_scale=0.5).spec()
    spec = RigOptions(primary=8, secondary=16, angle=45.0).spec()
    assert spec.for_box(None).n_rays == 8 * 16
    (tmp_path / "out").mkdir()
    several = EncodeSettings(meshes=["a/car.obj", "b/van.glb"], out=str(tmp_path / "out"))
    assert several.targets() == [tmp_path / "out" / "car.npz", tmp_path / "out" / "van.npz"]
    assert EncodeSettings(meshes=["car.obj"], out="enc/car").targets() == [Path("enc/car.npz")]
    with pytest.raises(SpotlightsError, match="several meshes need a folder"):
        EncodeSettings(meshes=["a.obj", "b.obj"], out="x.npz").targets()
