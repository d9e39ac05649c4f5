"""Chamfer losses: KD-tree, batched argmin and autograd-through-cdist paths agree with brute force."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from spotlights.learning.losses import chamfer_distance, depth_l1, nearest_indices, nearest_squared_distances  # noqa: E402

from learning_fixtures import one_torch_thread  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)


def brute_chamfer(p: np.ndarray, g: np.ndarray, kind: str) -> float:
    d = ((p[:, None, :].astype(np.float64) - g[None, :, :].astype(np.float64)) ** 2).sum(-1)
    a, b = d.min(1), d.min(0)
    return float(a.mean() + b.mean()) if kind == "l2" else float((np.sqrt(a).mean() + np.sqrt(b).mean()) / 2)


@pytest.fixture
def pair():
    g = torch.Generator().manual_seed(0)
    pred = torch.rand(4, 200, 3, generator=g, dtype=torch.float64)
    target = torch.rand(4, 150, 3, generator=g, dtype=torch.float64)
    return pred, target


@pytest.mark.parametrize("kind", ["l1", "l2"])
@pytest.mark.parametrize("method", ["kdtree", "argmin", "cdist"])
def test_values_match_brute_force(pair, kind, method):
    pred, target = pair
    per = chamfer_distance(pred, target, kind, method, reduction="none")
    ref = [brute_chamfer(p.numpy(), t.numpy(), kind) for p, t in zip(pred, target)]
    np.testing.assert_allclose(per.detach().numpy(), ref, rtol=1e-5)
    assert float(chamfer_distance(pred, target, kind, method)) == pytest.approx(np.mean(ref), rel=1e-5)


@pytest.mark.parametrize("kind", ["l1", "l2"])
def test_fast_paths_have_the_reference_gradients(pair, kind):
    grads = {}
    for method in ("kdtree", "argmin", "cdist"):
        p = pair[0].clone().requires_grad_(True)
        t = pair[1].clone().requires_grad_(True)
        chamfer_distance(p, t, kind, method).backward()
        grads[method] = (p.grad.numpy(), t.grad.numpy())
    for method in ("kdtree", "argmin"):
        np.testing.assert_allclose(grads[method][0], grads["cdist"][0], rtol=1e-5, atol=1e-9)
        np.testing.assert_allclose(grads[method][1], grads["cdist"][1], rtol=1e-5, atol=1e-9)


def test_float32_paths_agree_and_indices_are_nearest():
    g = torch.Generator().manual_seed(1)
    pred, target = torch.rand(3, 500, 3, generator=g), torch.rand(3, 700, 3, generator=g)
    i_kd = nearest_indices(pred, target, "kdtree")
    i_am = nearest_indices(pred, target, "argmin")
    d = torch.cdist(pred.double(), target.double())
    best = d.min(2).values
    picked_kd = torch.gather(d, 2, i_kd.unsqueeze(-1)).squeeze(-1)
    picked_am = torch.gather(d, 2, i_am.unsqueeze(-1)).squeeze(-1)
    torch.testing.assert_close(picked_kd, best, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(picked_am, best, rtol=1e-6, atol=1e-6)
    a = nearest_squared_distances(pred, target, "kdtree")
    b = nearest_squared_distances(pred, target, "cdist")
    torch.testing.assert_close(a[0], b[0], rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(a[1], b[1], rtol=1e-4, atol=1e-6)


def test_zero_distance_has_finite_gradient():
    p = torch.zeros(1, 5, 3, requires_grad=True)
    chamfer_distance(p, torch.zeros(1, 5, 3), "l1").backward()
    assert torch.isfinite(p.grad).all()


def test_depth_l1_and_errors():
    pred = torch.tensor([[0.0, 0.5, 0.2], [1.0, 0.0, 0.0]])
    target = torch.tensor([[0.0, 0.4, 0.0], [0.5, 0.0, 0.3]])
    np.testing.assert_allclose(depth_l1(pred, target, "none").numpy(), [0.3 / 3, 0.8 / 3], rtol=1e-6)
    assert float(depth_l1(pred, target)) == pytest.approx(0.55 / 3)
    with pytest.raises(ValueError, match="shapes differ"):
        depth_l1(pred, target[:, :2])
    with pytest.raises(ValueError, match=r"\(B, K, 3\)"):
        chamfer_distance(torch.zeros(2, 5, 2), torch.zeros(2, 5, 3))
    with pytest.raises(ValueError, match="unknown"):
        chamfer_distance(torch.zeros(1, 5, 3), torch.zeros(1, 5, 3), method="octree")


@pytest.mark.parametrize("kind", ["l1", "l2"])
def test_losses_equal_the_numpy_metrics(pair, kind):
    """The loss is the metric of spotlights.geometry.distances that owns the definition, per sample."""
    from spotlights.geometry.distances import chamfer_l1, chamfer_l2

    pred, target = pair
    metric = chamfer_l1 if kind == "l1" else chamfer_l2
    per = chamfer_distance(pred, target, kind, "kdtree", reduction="none").detach().numpy()
    np.testing.assert_allclose(per, [metric(p.numpy(), t.numpy()) for p, t in zip(pred, target)], rtol=1e-6)
