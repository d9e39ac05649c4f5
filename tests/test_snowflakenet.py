"""SnowflakeNet (the modern peer) and its pure-torch kNN / farthest-point sampling, against brute force."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from spotlights.learning.models import MODEL_NAMES, build_model, load_config  # noqa: E402
from spotlights.learning.models.pointops import (  # noqa: E402
    farthest_point_sample,
    farthest_point_sample_reference,
    gather,
    knn,
    knn_reference,
)

from learning_fixtures import TINY_MODEL_ARGS, one_torch_thread  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)


@pytest.mark.parametrize("block", [1 << 22, 7])  # one block, and one query per block
def test_knn_matches_brute_force(block):
    rng = np.random.default_rng(0)
    query = rng.uniform(-1, 1, (2, 9, 3)).astype(np.float32)
    ref = rng.uniform(-1, 1, (2, 13, 3)).astype(np.float32)
    got = knn(torch.from_numpy(query), torch.from_numpy(ref), 5, block=block).numpy()
    np.testing.assert_array_equal(got, knn_reference(query, ref, 5))
    # a cloud against itself: every point finds itself first
    own = knn(torch.from_numpy(ref), torch.from_numpy(ref), 4, block=block).numpy()
    np.testing.assert_array_equal(own, knn_reference(ref, ref, 4))
    np.testing.assert_array_equal(own[..., 0], np.broadcast_to(np.arange(13), (2, 13)))


def test_knn_ignores_autocast_and_refuses_too_many_neighbours():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1, 1, (1, 40, 3)).astype(np.float32)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = knn(torch.from_numpy(pts).bfloat16(), torch.from_numpy(pts).bfloat16(), 6).numpy()
    # bf16 inputs are rounded, but the search itself runs in float32 on those rounded values
    rounded = torch.from_numpy(pts).bfloat16().float().numpy()
    np.testing.assert_array_equal(got, knn_reference(rounded, rounded, 6))
    with pytest.raises(ValueError, match="k must be in 1..40"):
        knn(torch.from_numpy(pts), torch.from_numpy(pts), 41)


def test_farthest_point_sampling_matches_brute_force():
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(3, 50, 3)).astype(np.float32)
    got = farthest_point_sample(torch.from_numpy(pts), 12).numpy()
    np.testing.assert_array_equal(got, farthest_point_sample_reference(pts, 12))
    assert all(len(set(row)) == 12 for row in got.tolist())
    # a hand case on a line: 0 first, then the far end, then the middle
    line = torch.tensor([[[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [4, 0, 0]]])
    assert farthest_point_sample(line, 3).tolist() == [[0, 3, 2]]
    with pytest.raises(ValueError, match="1..4"):
        farthest_point_sample(line, 5)


def test_gather_picks_rows_per_batch():
    values = torch.arange(2 * 4 * 2, dtype=torch.float32).reshape(2, 4, 2)
    idx = torch.tensor([[[3, 0]], [[1, 1]]])  # (2, 1, 2)
    out = gather(values, idx)
    assert out.shape == (2, 1, 2, 2)
    assert out[0, 0].tolist() == [[6.0, 7.0], [0.0, 1.0]] and out[1, 0].tolist() == [[10.0, 11.0], [10.0, 11.0]]


def test_registered_and_default_output_count_is_16384():
    assert "snowflakenet" in MODEL_NAMES
    torch.manual_seed(0)
    model = build_model(load_config("snowflakenet")).eval()
    assert model.n_points == 512 * 1 * 4 * 8 == 16_384
    with torch.no_grad():
        out = model(torch.rand(1, 256, 3) - 0.5)
    assert out["seeds"].shape == (1, 256, 3) and out["p0"].shape == (1, 512, 3)
    assert [out[f"stage{i}"].shape[1] for i in (1, 2, 3)] == [512, 2048, 16_384]
    assert out["points"].shape == (1, 16_384, 3)
    clouds = model.complete(torch.rand(2, 256, 3) - 0.5)
    assert [tuple(c.shape) for c in clouds] == [(16_384, 3), (16_384, 3)]


def test_children_stay_within_one_of_their_parent():
    """Each stage moves every copy of a parent by tanh(.) per axis: |child - parent| <= 1 per coordinate."""
    torch.manual_seed(0)
    model = build_model(load_config("snowflakenet", overrides={"model": {"args": TINY_MODEL_ARGS["snowflakenet"]}}))
    with torch.no_grad():
        out = model(torch.rand(2, 30, 3))
    parents = out["p0"]
    for i, r in enumerate(model.up_factors, start=1):
        children = out[f"stage{i}"]
        assert children.shape[1] == parents.shape[1] * r
        assert float((children - parents.repeat_interleave(r, dim=1)).abs().max()) <= 1.0
        parents = children


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_forward_backward_gives_finite_gradients_to_every_parameter(precision):
    torch.manual_seed(0)
    model = build_model(load_config("snowflakenet", overrides={"model": {"args": TINY_MODEL_ARGS["snowflakenet"]}}))
    batch = {"partial": torch.rand(3, 30, 3) - 0.5, "gt_points": torch.rand(3, 64, 3) - 0.5}
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision == "bf16"):
        out = model(batch["partial"])
    assert out["points"].shape == (3, model.n_points, 3) == (3, 16 * 2 * 4, 3)
    loss, terms = model.loss({k: v.float() for k, v in out.items()}, batch)
    assert set(terms) == {"cd_seeds", "cd_stage1", "cd_stage2", "partial"} and loss.ndim == 0
    loss.backward()
    for name, p in model.named_parameters():
        assert p.grad is not None, name
        assert torch.isfinite(p.grad).all(), name
    assert any(float(p.grad.abs().max()) > 0 for p in model.stages[-1].parameters())


def test_loss_terms_are_the_chamfer_distances_of_each_stage():
    """Each term against a numpy brute-force Chamfer (CD-L1) to the matching prefix of the ground truth."""
    torch.manual_seed(0)
    model = build_model(load_config("snowflakenet", overrides={"model": {"args": TINY_MODEL_ARGS["snowflakenet"]}}))
    batch = {"partial": torch.rand(2, 30, 3) - 0.5, "gt_points": torch.rand(2, 64, 3) - 0.5}
    with torch.no_grad():
        out = model(batch["partial"])
        _, terms = model.loss(out, batch)

    def cd_l1(a, b):
        d = np.sqrt(((a[:, :, None, :].astype(np.float64) - b[:, None, :, :]) ** 2).sum(-1))
        return float(np.mean(0.5 * (d.min(2).mean(1) + d.min(1).mean(1))))

    gt = batch["gt_points"].numpy()
    for key in ("seeds", "stage1", "stage2"):
        pred = out[key].numpy()
        assert terms[f"cd_{key}"] == pytest.approx(cd_l1(pred, gt[:, : min(pred.shape[1], 64)]), rel=1e-4)
    part = batch["partial"].numpy()
    d = np.sqrt(((part[:, :, None, :] - out["points"].numpy()[:, None, :, :]) ** 2).sum(-1))
    assert terms["partial"] == pytest.approx(float(d.min(2).mean()), rel=1e-4)
