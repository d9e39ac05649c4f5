"""The library refuses what it cannot use with one clear ParameterError, never a deep numpy/scipy/torch error or a
silent wrong answer: spotlights.complete_frame / complete_scene (points, boxes, completer, config, axes) and
SceneConfig's fields (found by a hostile-input pass)."""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.completion.frame import SceneConfig, complete_scene, scene_points
from spotlights.errors import ParameterError
from spotlights.geometry.boxes import Box

pytestmark = pytest.mark.timeout(120)

BOX = Box([10.0, 2.0, -0.9], [4.2, 1.8, 1.5], 0.0, label="car", cls="car")


def _scan(n: int = 400) -> np.ndarray:
    rng = np.random.default_rng(0)
    return (rng.uniform(-0.5, 0.5, (n, 3)) * [4.2, 1.8, 1.5] + [10.0, 2.0, -0.9]).astype(np.float32)


class _Stub:
    """A completer that must never be reached: every case below is refused before any model runs."""

    model_name, rig, needs_box, domain = "stub", None, False, None

    def complete(self, *a, **k):  # pragma: no cover - reached only if a refusal is missing
        raise AssertionError("a bad input reached the model")


@pytest.mark.parametrize(
    "points, message",
    [
        (np.zeros((300, 4)), r"got shape \(300, 4\) \(pass points\[:, :3\]"),
        (np.zeros((300, 2)), r"got shape \(300, 2\)$"),
        (np.zeros(900), r"got shape \(900,\)"),
        (np.zeros((300, 3, 1)), r"got shape \(300, 3, 1\)"),
        (np.array(5.0), r"got shape \(\)"),
        (np.zeros((300, 3), dtype=complex), "must be real numbers"),
        (np.array([["a", "b", "c"]] * 300), "must be real numbers"),
        (np.vstack([np.zeros((299, 3)), [[np.nan, 0, 0]]]), r"1 of the 300 points are not finite"),
        (np.vstack([np.zeros((298, 3)), [[np.inf, 0, 0], [0, -np.inf, 0]]]), r"2 of the 300 points are not finite"),
    ],
)
def test_scene_points_refuses_what_is_not_an_n_by_3_array_of_finite_numbers(points, message):
    with pytest.raises(ParameterError, match=message):
        scene_points(points)
    with pytest.raises(ParameterError, match=message):  # before any model is asked
        complete_scene(points, [BOX], _Stub())


def test_scene_points_keeps_every_accepted_input():
    a = _scan()
    for given in (a, a.astype(np.float64), a.astype(np.int32), a[:, ::-1][:, ::-1], a.tolist()):
        got = scene_points(given)
        assert got.dtype == np.float64 and got.shape == (400, 3)
        np.testing.assert_array_equal(got, np.asarray(given, dtype=np.float64))


@pytest.mark.parametrize(
    "boxes, message",
    [
        (None, "boxes must be a list of Box objects"),
        (BOX, r"boxes must be a list of Box objects \(for one box: \[box\]"),
        ("car", "boxes must be a list of Box objects"),
        ([BOX, {"center": [0, 0, 0], "size": [4, 2, 1.5], "yaw": 0}], r"boxes\[1\] is a dict, not a Box"),
        ([BOX, "car"], r"boxes\[1\] is a str, not a Box"),
    ],
)
def test_complete_scene_refuses_boxes_that_are_not_a_list_of_box(boxes, message):
    with pytest.raises(ParameterError, match=message):
        complete_scene(_scan(), boxes, _Stub())


def test_complete_scene_refuses_a_completer_a_config_or_axes_it_cannot_use():
    with pytest.raises(ParameterError, match="completer must be a loaded model"):
        complete_scene(_scan(), [BOX], 5)
    with pytest.raises(ParameterError, match="config must be a SceneConfig, got dict"):
        complete_scene(_scan(), [BOX], _Stub(), {})
    for axes in (np.eye(2), np.ones((3, 3)), np.full((3, 3), np.nan), np.diag([1.0, 1.0, -1.0]), "x"):
        with pytest.raises(ParameterError, match=r"axes must be a \(3, 3\) rotation"):
            complete_scene(_scan(), [BOX], _Stub(), axes=axes)


@pytest.mark.parametrize(
    "options, message",
    [
        ({"margin": "0.2"}, "`margin` must be a number, got '0.2'"),
        ({"heading_margin": None}, "`heading_margin` must be a number"),
        ({"min_points": 2.5}, "`min_points` must be a whole number, got 2.5"),
        ({"seed": -1}, "the seed must be a whole number in 0..2\\*\\*63-1, got -1"),
        ({"seed": 2**63}, "the seed must be a whole number in 0..2\\*\\*63-1"),
        ({"seed": 1.0}, "`seed` must be a whole number"),
        ({"clip": 5.0}, r"clip must be a depth threshold in \[0, 1\]"),
        ({"clip": float("nan")}, r"clip must be a depth threshold in \[0, 1\]"),
        ({"clip": "none"}, r"clip must be a depth threshold"),
        ({"clip": True}, r"clip must be a depth threshold"),
    ],
)
def test_scene_config_refuses_values_of_the_wrong_kind(options, message):
    with pytest.raises(ParameterError, match=message):
        SceneConfig(**options)


def test_scene_config_keeps_the_accepted_values():
    assert SceneConfig(clip=None).clip is None and SceneConfig(clip=0.2).clip == 0.2 and SceneConfig().clip == "default"
    assert SceneConfig(margin=np.float32(0.2), seed=np.int64(3), min_points=np.int32(5)).seed == 3
    assert SceneConfig(clip=1).clip == 1 and SceneConfig(clip=0.0).clip == 0.0


def test_the_api_answers_the_same_way():
    import spotlights

    with pytest.raises(ParameterError, match=r"pass points\[:, :3\]"):
        spotlights.complete_frame(np.c_[_scan(300), np.ones(300)], [BOX], _Stub(), fallback=None)
    with pytest.raises(ParameterError, match="boxes must be a list of Box objects"):
        spotlights.complete_frame(_scan(), BOX, _Stub(), fallback=None)
    with pytest.raises(ParameterError, match="the seed must be a whole number in 0"):
        spotlights.complete_frame(_scan(), [BOX], _Stub(), fallback=None, seed=-1)


def test_library_errors_name_parameters_and_the_cli_writes_its_options():
    """A library error names the Python parameters (```heading_margin```); the command line shows its options
    instead (``--heading-margin``), also for a parameter whose option has another first spelling."""
    import argparse

    from spotlights.errors import ParameterError
    from spotlights.options import option_names

    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    cmd = sub.add_parser("complete")
    cmd.add_argument("--heading-margin", type=float)
    cmd.add_argument("--no-heading-check", dest="heading_check", action="store_false")
    cmd.add_argument("--heading-check", dest="heading_check", action="store_true")
    cmd.add_argument("-c", "--ckpt", dest="checkpoint")
    exc = ParameterError(
        "`heading_margin` goes with `heading_check` (the heading margin)", "heading_margin", "heading_check"
    )
    assert option_names(exc, parser) == "--heading-margin goes with --heading-check (the heading margin)"
    exc = ParameterError("pass `checkpoint` MODEL.onnx; `threads` too", "checkpoint", "threads")
    assert option_names(exc, parser) == "pass --ckpt MODEL.onnx; --threads too"
    assert option_names(ParameterError("plain `words`"), parser) == "plain `words`"
