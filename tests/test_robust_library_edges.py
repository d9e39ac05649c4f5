"""What a Python user passes by mistake to the library's public names: each is a one-line ParameterError (or, for a
box file, an InputFileError naming the file), never a raw numpy error, a silent wrong answer or a construction."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from spotlights.errors import InputFileError, ParameterError
from spotlights.geometry.box_json import box_from_dict
from spotlights.geometry.boxes import Box
from spotlights.geometry.encode import decode
from spotlights.geometry.rig import make_rig
from spotlights.geometry.rotations import quaternion_to_matrix

BOX = Box([10.0, 0.0, 0.75], [4.0, 1.8, 1.5])


@pytest.mark.parametrize("points", [None, np.zeros((5, 2)), "abc", 3.0, np.zeros((2, 3, 3))])
def test_box_contains_refuses_what_is_not_n_by_3(points):
    with pytest.raises(ParameterError, match=r"points must be an \(N, 3\) array") as info:
        BOX.contains(points)
    assert "\n" not in str(info.value)
    with pytest.raises(ParameterError, match="points must be"):
        BOX.crop(points)


def test_box_contains_still_answers_by_hand():
    pts = np.array([[10.0, 0.0, 0.75], [12.1, 0.0, 0.75], [10.0, 0.0, 0.0]])  # centre, beyond the front, bottom face
    assert BOX.contains(pts).tolist() == [True, False, True]
    assert BOX.crop(pts).tolist() == [0, 2]


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(center=[math.nan, 0, 0], size=[4, 2, 1.5]), "center"),
        (dict(center=[0, math.inf, 0], size=[4, 2, 1.5]), "center"),
        (dict(center=[0, 0, 0], size=[4, math.nan, 1.5]), "size"),
        (dict(center=[0, 0, 0], size=[4, 2, 1.5], rotation=np.full((3, 3), math.nan)), "rotation"),
        (dict(center=[True, 0, 0], size=[4, 2, 1.5]), "centre"),
        (dict(center=["1", 0, 0], size=[4, 2, 1.5]), "centre"),
        (dict(center=[0, 0, 0], size=[4, 2, 1.5], yaw="0.5"), "yaw"),
        (dict(center=[0, 0, 0], size=[4, 2, 1.5], yaw=True), "yaw"),
    ],
)
def test_box_refuses_non_finite_and_non_numbers(kwargs, name):
    with pytest.raises(ParameterError, match=name) as info:
        Box(**kwargs)
    assert "\n" not in str(info.value)


def test_a_degenerate_box_is_still_made_and_invalid():
    """Annotations hold zero-width boxes: made, and skipped later as invalid (only non-finite numbers are refused)."""
    assert not Box([0, 0, 0], [4.0, 0.0, 1.5]).is_valid()


@pytest.mark.parametrize(
    "change, fragment",
    [
        ({"center": [True, 0, 0]}, "center must be three finite numbers"),
        ({"size": ["4", 1.8, 1.5]}, "size must be three finite numbers"),
        ({"yaw": "0.5"}, "yaw must be a number"),
        ({"yaw": False}, "yaw must be a number"),
        ({"track_id": [1, 2]}, "track_id must be a string or a whole number"),
        ({"track_id": True}, "track_id must be a string or a whole number"),
        ({"track_id": {"a": 1}}, "track_id must be a string or a whole number"),
        ({"label": ["car"]}, "label must be a string"),
    ],
)
def test_box_file_fields_are_strictly_typed(change, fragment):
    d = {"center": [10.0, 0.0, 0.75], "size": [4.0, 1.8, 1.5], "yaw": 0.0, "label": "car", **change}
    with pytest.raises(InputFileError, match=r"^b\.json: box 0 ") as info:
        box_from_dict(d, "b.json", "box 0")
    assert fragment in str(info.value)


def test_box_file_integer_track_ids_and_unit_quaternions_still_read():
    b = box_from_dict({"center": [1, 2, 3], "size": [4, 2, 1], "rotation": [1, 0, 0, 0], "track_id": 7}, "b.json")
    assert b.track_id == "7" and np.array_equal(b.rotation, np.eye(3))
    # a quarter turn about z: the box's forward axis is the scan's +y (by hand)
    h = math.sqrt(0.5)
    b = box_from_dict({"center": [0, 0, 0], "size": [4, 2, 1], "rotation": [h, 0, 0, h]}, "b.json")
    np.testing.assert_allclose(b.rotation[:, 0], [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize("q", [[1e300, 1e300, 0, 0], [2.0, 0, 0, 0], [0.5, 0, 0, 0]])
def test_box_file_quaternion_far_from_unit_is_refused(q):
    with pytest.raises(InputFileError, match="quaternion must be a unit quaternion"):
        box_from_dict({"center": [0, 0, 0], "size": [4, 2, 1], "rotation": q}, "b.json")


def test_quaternion_that_cannot_be_normalised_is_refused():
    with pytest.raises(ParameterError, match="cannot be normalised"):
        quaternion_to_matrix(1e300, 1e300, 0.0, 0.0)  # its norm overflows: it became the identity
    with pytest.raises(ParameterError, match="cannot be normalised"):
        quaternion_to_matrix(np.array([1.0, 0.0]), np.zeros(2), np.zeros(2), np.zeros(2))  # a zero row
    # a scaled but normalisable quaternion is still a rotation: half a turn about z (by hand)
    np.testing.assert_allclose(quaternion_to_matrix(0.0, 0.0, 0.0, 3.0), np.diag([-1.0, -1.0, 1.0]), atol=1e-12)


@pytest.mark.parametrize(
    "pose",
    [
        np.zeros((4, 4)).tolist(),  # singular
        np.diag([2.0, 2.0, 2.0, 1.0]).tolist(),  # scaled
        np.diag([1.0, 1.0, -1.0, 1.0]).tolist(),  # a reflection
        [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]],  # not an affine last row
        [[True, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
    ],
)
def test_box_file_sensor_to_world_must_be_rigid(tmp_path, pose):
    from spotlights.data.real.boxfiles import read_json_boxes

    path = tmp_path / "f.json"
    path.write_text(json.dumps({"boxes": [], "sensor_to_world": pose}))
    with pytest.raises(InputFileError, match=r"f\.json: frame sensor_to_world must be a") as info:
        read_json_boxes(path)
    assert "\n" not in str(info.value)


def test_box_file_frame_keys_are_typed(tmp_path):
    from spotlights.data.real.boxfiles import read_json_boxes

    for key, value, fragment in (
        ("timestamp", True, "timestamp must be a number"),
        ("timestamp", "0.1", "timestamp must be a number"),
        ("frame_id", ["a"], "frame_id must be a string"),
        ("sequence", {"a": 1}, "sequence must be a string"),
    ):
        path = tmp_path / "f.json"
        path.write_text(json.dumps({"boxes": [], key: value}))
        with pytest.raises(InputFileError, match=fragment):
            read_json_boxes(path)
    path.write_text(json.dumps({"boxes": [], "sensor_to_world": np.eye(4).tolist(), "frame_id": 3}))
    assert read_json_boxes(path).frame_id == "3"


RIG = make_rig(4, 8, 60.0)


def test_decode_refuses_a_missing_rig_and_reads_a_rig_name():
    depths = np.zeros(RIG.n_rays)
    with pytest.raises(ParameterError, match="rig must be a Rig, a RigSpec or a rig name"):
        decode(depths, None)
    pts, mask = decode(depths, RIG.name)  # a rig name is read as make_rig would make it
    assert pts.shape == (RIG.n_rays, 3) and not mask.any()
    np.testing.assert_allclose(pts, RIG.origins, atol=1e-6)  # every miss at its ray's origin


@pytest.mark.parametrize("bad", [math.nan, math.inf, -0.1, 1.5])
def test_decode_refuses_depths_outside_zero_one(bad):
    depths = np.full(RIG.n_rays, 0.5)
    depths[3] = bad
    with pytest.raises(ParameterError, match=r"depths must be finite numbers in \[0, 1\].*1 of 32"):
        decode(depths, RIG)


@pytest.mark.parametrize("clip", [math.nan, 5.0, -0.2, "0.2"])
def test_decode_refuses_a_clip_outside_zero_one(clip):
    with pytest.raises(ParameterError, match=r"clip must be a depth threshold in \[0, 1\]"):
        decode(np.full(RIG.n_rays, 0.5), RIG, clip=clip)


def test_decode_of_a_depth_by_hand():
    """A depth of 0.5 on a ray from the sphere through the centre lands at the centre: P = P1 + 2 * 0.5 * d."""
    depths = np.zeros(RIG.n_rays)
    k = int(np.argmax(-np.einsum("ij,ij->i", RIG.origins, RIG.directions)))  # the ray most toward the centre
    depths[k] = 0.5
    pts, mask = decode(depths, RIG, clip=0.2)
    assert mask.tolist() == [i == k for i in range(RIG.n_rays)]
    half_chord = -float(RIG.origins[k] @ RIG.directions[k])
    expected = RIG.origins[k] + 2 * min(0.5, half_chord) * RIG.directions[k]
    np.testing.assert_allclose(pts[k], expected, atol=1e-6)


@pytest.mark.parametrize("threads", [0, -1, 1.5, True, "2"])
def test_load_completer_refuses_threads_below_one(threads):
    from spotlights.learning.runtime import load_completer

    with pytest.raises(ParameterError, match=r"`threads` must be a whole number >= 1"):
        load_completer("model.onnx", threads=threads)
