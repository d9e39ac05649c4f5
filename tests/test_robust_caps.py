"""Stated caps on what a user can make huge: boxes per frame, procedural vehicles; each checked before any heavy
work, one line (exit 2) or a ParameterError naming the parameter, and said in --help."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spotlights.errors import InputFileError, ParameterError
from spotlights.geometry.boxes import MAX_BOXES_PER_FRAME, Box

from helpers import assert_user_error, run_cli, write_box_scan

BOX = {"center": [10.0, 0.0, 0.75], "size": [4.0, 1.8, 1.5], "yaw": 0.0, "label": "car"}


def test_the_cap_on_boxes_per_frame_is_two_thousand():
    assert MAX_BOXES_PER_FRAME == 2_000


def test_a_box_file_beyond_the_cap_is_one_line_before_any_work(tmp_path):
    paths = write_box_scan(tmp_path)
    many = tmp_path / "many.json"
    many.write_text(json.dumps([BOX] * (MAX_BOXES_PER_FRAME + 1)))
    proc = run_cli("complete", paths["scan"], "--boxes", many, "--out", tmp_path / "c.ply")
    assert_user_error(proc, "many.json", "2,001 boxes in one frame", "at most 2,000")
    assert not (tmp_path / "c.ply").exists()


def test_a_box_file_at_the_cap_is_read(tmp_path):
    from spotlights.data.real.boxfiles import read_json_boxes

    (tmp_path / "b.json").write_text(json.dumps({"boxes": [BOX] * MAX_BOXES_PER_FRAME}))
    assert len(read_json_boxes(tmp_path / "b.json").boxes) == MAX_BOXES_PER_FRAME


def test_a_kitti_label_file_beyond_the_cap_is_refused(tmp_path):
    from spotlights.data.real.kitti import read_labels

    line = "Car 0.00 0 0.0 0 0 10 10 1.5 1.8 4.0 1.0 1.5 10.0 0.0\n"
    (tmp_path / "l.txt").write_text(line * (MAX_BOXES_PER_FRAME + 1))
    with pytest.raises(InputFileError, match=r"l\.txt: more than 2,000 boxes in one frame"):
        read_labels(tmp_path / "l.txt", np.eye(4))


def test_scene_completion_refuses_too_many_boxes_before_anything():
    from spotlights.completion.frame import complete_scene

    boxes = [Box([10.0, 0.0, 0.75], [4.0, 1.8, 1.5], cls="car")] * (MAX_BOXES_PER_FRAME + 1)
    # the completer is not even looked at: the count is refused first
    with pytest.raises(ParameterError, match=r"boxes holds 2,001 boxes; a frame takes at most 2,000"):
        complete_scene(np.zeros((100, 3)), boxes, object())


def test_complete_help_states_the_box_cap():
    assert "at most 2000 boxes a frame" in " ".join(run_cli("complete", "--help").stdout.split())


def test_procedural_count_beyond_its_cap_is_one_line(tmp_path):
    out = tmp_path / "x.h5"
    proc = run_cli("dataset", "build", "--procedural", "1000000", "--out", out)
    assert_user_error(proc, "--procedural", "at most 10,000")
    assert not out.exists() and not (tmp_path / "x.h5.parts").exists()
    assert "at most 10000" in " ".join(run_cli("dataset", "build", "--help").stdout.split())


@pytest.mark.parametrize("classes", ["", ",", " , "])
def test_procedural_with_no_class_named_is_refused(tmp_path, classes):
    out = tmp_path / "x.h5"
    proc = run_cli("dataset", "build", "--procedural", "1", "--classes", classes, "--out", out)
    assert_user_error(proc, "--classes", "names no class")
    assert not out.exists() and not (tmp_path / "x.h5.parts").exists()


def test_procedural_bounds_in_the_library():
    from spotlights.data.synthetic.config import MAX_PROCEDURAL, normalize_procedural

    assert normalize_procedural({"count": MAX_PROCEDURAL})["count"] == MAX_PROCEDURAL
    assert normalize_procedural({"count": 2, "classes": None})["classes"] == [
        "car",
        "caravan",
        "truck",
        "bus",
        "trailer",
    ]
    with pytest.raises(ParameterError, match="at most 10,000"):
        normalize_procedural({"count": MAX_PROCEDURAL + 1})
    with pytest.raises(ParameterError, match="names no class"):
        normalize_procedural({"count": 1, "classes": []})
