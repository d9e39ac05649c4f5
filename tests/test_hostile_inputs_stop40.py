"""Hostile inputs found by the second fuzzing pass (stop 40), each answered with a clear error instead of a
traceback or a silently wrong run: scan arrays that hold no real numbers, learning-rate schedules that grow or
turn negative, and learning curves whose validation metrics are all NaN."""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.errors import InputFileError, ParameterError
from spotlights.geometry.io import load_points
from spotlights.learning.config import check_schedule


@pytest.mark.parametrize(
    "array",
    [
        np.array([["a", "b", "c"]] * 20),  # text
        np.array([[1 + 2j, 0, 0]] * 20),  # complex: the imaginary part was dropped with a ComplexWarning
        np.ones((20, 3), dtype=bool),
        np.array([["2020-01-01"] * 3] * 20, dtype="datetime64[D]"),
        np.zeros(20, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]),  # records: 1-D of a void dtype
    ],
)
def test_scan_arrays_of_no_real_numbers_are_refused(tmp_path, array):
    path = tmp_path / "scan.npy"
    np.save(path, array)
    with pytest.raises(InputFileError, match="scan.npy.*(real numbers|expected)"):
        load_points(path)


def test_integer_and_float_scans_still_read(tmp_path):
    for dtype in (np.int16, np.float32, np.float64):
        path = tmp_path / f"scan_{np.dtype(dtype).name}.npy"
        np.save(path, (np.arange(60).reshape(20, 3) % 7).astype(dtype))
        pts = load_points(path)
        assert pts.dtype == np.float64 and pts.shape == (20, 3) and pts[3, 0] == 9 % 7


@pytest.mark.parametrize(
    "schedule, message",
    [
        ({"kind": "step", "every": 1, "gamma": -0.5}, "gamma must be a number in \\(0, 1\\]"),
        ({"kind": "step", "every": 1, "gamma": 1.5}, "gamma"),
        ({"kind": "step", "every": 0}, "every must be a number in \\[1, "),
        ({"kind": "step", "every": 2.5}, "every"),
        ({"kind": "step", "every": "abc"}, "every"),
        ({"kind": "step", "gamma": float("nan")}, "gamma"),
        ({"kind": "cosine", "min_factor": 5}, "min_factor must be a number in \\[0, 1\\]"),
        ({"kind": "cosine", "min_factor": "abc"}, "min_factor"),
        ({"kind": "cosine", "min_factor": True}, "min_factor"),
    ],
)
def test_schedules_that_grow_or_turn_negative_are_refused(schedule, message):
    with pytest.raises(ParameterError, match=message):
        check_schedule(schedule)


def test_valid_schedules_pass():
    for schedule in (
        {"kind": "step", "every": 30, "gamma": 0.5},
        {"kind": "step", "every": 1, "gamma": 1.0},
        {"kind": "cosine", "min_factor": 0.0},
        {"kind": "cosine", "min_factor": 0.05},
        {"type": "constant"},
        None,
    ):
        check_schedule(schedule)


def test_learning_curves_of_all_nan_metrics_are_drawn(tmp_path):
    """A short run's validation metrics can all be NaN: the page is drawn (empty panels), no legend to fail."""
    from spotlights.viz.curves import render_learning_curves

    nan = float("nan")
    curves = {"run": {"epoch": [1, 2], "val_accuracy": [nan, nan]}}
    out = render_learning_curves(tmp_path / "c.png", curves, [("val_accuracy", "accuracy")], "epoch", "epoch", "t")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_resume_completes_again_a_frame_whose_json_is_not_a_summary_or_whose_ply_is_gone(tmp_path):
    """``real complete --resume`` skips a frame only when its JSON is a summary of the same run and its scene PLY is
    there (a JSON list raised AttributeError; a deleted or emptied PLY was skipped, the output left incomplete)."""
    import json
    from dataclasses import asdict

    from spotlights.completion.frame import SceneConfig
    from spotlights.completion.frames import done_frame

    cfg = asdict(SceneConfig())
    cfg["clip"] = str(cfg["clip"])
    f = tmp_path / "frame.json"
    ply = tmp_path / "frame.ply"
    f.write_text(json.dumps({"model": "sanet-hit", "checkpoint": "default", "config": cfg, "ply": str(ply)}))
    from spotlights.geometry.io import save_ply

    save_ply(ply, np.zeros((3, 3)), {"source": np.zeros(3, np.uint8)})
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is not None
    ply.write_bytes(b"")
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is None
    ply.unlink()
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is None
    f.write_text("[1, 2]")
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is None


def test_sequence_size_noise_is_bounded_and_never_flattens_a_box():
    from spotlights.data.synthetic.sequences import MAX_SIZE_SIGMA, MIN_SIZE_FACTOR, BoxNoise
    from spotlights.geometry.boxes import Box

    with pytest.raises(ParameterError, match="size-sigma"):
        BoxNoise(size_rel=5.0)
    noise = BoxNoise(size_rel=MAX_SIZE_SIGMA)
    box = Box.from_yaw(np.zeros(3), np.array([4.0, 1.8, 1.5]), 0.0)
    rng = np.random.default_rng(0)
    sizes = np.array([noise.apply(box, rng).size for _ in range(2000)])
    assert (sizes >= MIN_SIZE_FACTOR * box.size - 1e-12).all() and (sizes > 0).all()


def test_checkpoint_with_nan_weights_or_a_bad_threshold_is_refused(tmp_path):
    """A diverged run's checkpoint (NaN weights) passed ``export`` and ``evaluate`` with NaN everywhere; a p(hit)
    threshold of NaN or 2 made ``complete`` say every ray was clipped. Both are now the file's one-line error."""
    torch = pytest.importorskip("torch")
    from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint, save_checkpoint

    from learning_fixtures import make_checkpoint

    path = make_checkpoint(tmp_path / "ok.pt", "sanet-hit")
    ckpt = load_checkpoint(path)
    model_from_checkpoint(ckpt)  # the valid file loads
    state = {k: v.clone() for k, v in ckpt["model_state"].items()}
    first = next(k for k, v in state.items() if v.is_floating_point())
    state[first].view(-1)[0] = float("nan")
    bad = save_checkpoint(tmp_path / "nan.pt", {**ckpt, "model_state": state})
    with pytest.raises(InputFileError, match="nan.pt.*NaN or infinite"):
        model_from_checkpoint(load_checkpoint(bad))
    for value in (float("nan"), 2.0):
        odd = save_checkpoint(tmp_path / "thr.pt", {**ckpt, "hit_threshold": value})
        with pytest.raises(InputFileError, match="threshold"):
            model_from_checkpoint(load_checkpoint(odd))
    assert torch.isfinite(ckpt["model_state"][first]).all()


def test_box_with_infinite_yaw_is_a_clear_error():
    from spotlights.geometry.boxes import Box

    for yaw in (float("inf"), float("nan")):
        with pytest.raises(ParameterError, match="yaw must be a finite number"):
            Box.from_yaw(np.zeros(3), np.ones(3), yaw)
        with pytest.raises(ParameterError, match="yaw must be a finite number"):
            Box(np.zeros(3), np.ones(3), yaw=yaw)
        with pytest.raises(ParameterError, match="yaw must be a finite number"):
            Box(np.zeros(3), np.ones(3), yaw)
