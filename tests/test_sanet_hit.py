"""Hit-aware SA-Net: loss, threshold chosen on validation and used, bf16, old checkpoints.

Independent truths: the loss of a 2 x 3 batch computed by hand (BCE and the hit-only L1
written out with ``math``); completions rebuilt in numpy from the raw logits and depths
(``sigmoid >= t``, ``P = o + 2 clamp(d, 0, 1) dir``); the threshold the training stores is
the CD-L1 minimiser of a brute-force scan (scipy KD-tree) over the grid; the shipped
paper SA-Net checkpoint evaluated by a numpy re-implementation of its forward pass.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from spotlights.geometry.rig import make_rig  # noqa: E402
from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint  # noqa: E402
from spotlights.learning.models import build_model, load_config  # noqa: E402
from spotlights.learning.models.sanet_hit import box_outside_term, hit_depth_loss  # noqa: E402
from spotlights.learning.train import train, validate  # noqa: E402

from learning_fixtures import TINY_MODEL_ARGS, one_torch_thread, tiny_dataset_path, tiny_overrides  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return tiny_dataset_path(tmp_path_factory.getbasetemp() / "hit-data")


@pytest.fixture(scope="module")
def run(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("hitrun")
    res = train(
        "sanet-hit",
        data,
        out,
        overrides=tiny_overrides("sanet-hit", epochs=3, precision="fp32"),
        progress=False,
        log=lambda *a: None,
    )
    return out, res


def tiny_model(rig=None, **args):
    cfg = load_config("sanet-hit", overrides={"model": {"args": {**TINY_MODEL_ARGS["sanet-hit"], **args}}})
    torch.manual_seed(0)
    return build_model(cfg, rig=rig or make_rig(8, 16, 60.0))


def sigmoid(x):
    return 1.0 / (1.0 + math.exp(-x))


def test_loss_matches_a_hand_computation():
    logits = torch.tensor([[2.0, -1.0, 0.5], [-3.0, 0.0, 1.5]])
    depths = torch.tensor([[0.40, 0.90, 0.10], [0.30, 0.25, -0.2]])
    target = torch.tensor([[0.50, 0.00, 0.20], [0.00, 0.00, 0.10]])  # hits: (0,0), (0,2), (1,2)
    labels = [[1, 0, 1], [0, 0, 1]]
    bce = 0.0
    for i in range(2):
        for j in range(3):
            p = sigmoid(float(logits[i, j]))
            bce -= labels[i][j] * math.log(p) + (1 - labels[i][j]) * math.log(1 - p)
    bce /= 6
    l1 = (abs(0.40 - 0.50) + abs(0.10 - 0.20) + abs(-0.2 - 0.10)) / 3  # the misses' depths do not count
    loss, terms = hit_depth_loss(logits, depths, target)
    assert float(loss) == pytest.approx(bce + l1, rel=1e-6)
    assert terms["bce"] == pytest.approx(bce, rel=1e-6) and terms["l1_hits"] == pytest.approx(l1, rel=1e-6)
    assert terms["hit_accuracy"] == pytest.approx(5 / 6)  # logit >= 0 vs label: only (1,1) (logit 0) is wrong
    loss2, _ = hit_depth_loss(logits, depths, target, hit_weight=0.5, depth_weight=3.0)
    assert float(loss2) == pytest.approx(0.5 * bce + 3.0 * l1, rel=1e-6)
    # a batch without hits: the L1 term is 0, not NaN; gradients reach both heads
    lg, dp = logits.clone().requires_grad_(), depths.clone().requires_grad_()
    loss3, t3 = hit_depth_loss(lg, dp, torch.zeros_like(target))
    assert t3["l1_hits"] == 0.0 and math.isfinite(float(loss3.detach()))
    loss, _ = hit_depth_loss(lg, dp, target)
    loss.backward()
    assert torch.all(dp.grad[target == 0] == 0) and torch.all(dp.grad[target > 0] != 0)
    # d BCE / d logit = (p - y) / n
    want = (torch.sigmoid(logits) - torch.tensor(labels, dtype=torch.float32)) / 6
    torch.testing.assert_close(lg.grad, want)


def test_box_term_matches_a_hand_computation_and_pushes_points_into_the_box():
    """The box term: p(hit) * Euclidean distance outside the grown box, over the number of true hits."""
    half = torch.tensor([[0.2, 0.5, 0.5]])  # the box [-0.2, 0.2] x [-0.5, 0.5]^2
    origins = torch.tensor([[-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    s = 1 / math.sqrt(1.5**2 + 0.9**2)
    dirs = torch.tensor([[[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.5 * s, 0.9 * s, 0.0]]])
    # ray 0: x = -1 + 2 d = 0.5, 0.3 beyond the face x = 0.2; ray 1: x = 0.1, inside;
    # ray 2: the point (0.5, 0.9, 0): 0.3 beyond x = 0.2 and 0.4 beyond y = 0.5 -> 0.5 from the box's edge
    d2 = 0.5 * math.hypot(1.5, 0.9)
    depths = torch.tensor([[0.75, 0.55, d2]], requires_grad=True)
    logits = torch.tensor([[0.4, 3.0, -1.0]], requires_grad=True)
    target = torch.tensor([[0.6, 0.5, 0.0]])  # two true hits: the normaliser
    p = [sigmoid(0.4), sigmoid(3.0), sigmoid(-1.0)]
    one = box_outside_term(logits[:, :1], depths[:, :1], target[:, :1], origins[:1], dirs[:, :1], half)
    assert float(one.detach()) == pytest.approx(p[0] * 0.3, rel=1e-6)  # one ray, one hit: exactly p * 0.3
    inside = box_outside_term(logits[:, 1:2], depths[:, 1:2], target[:, 1:2], origins[1:2], dirs[:, 1:2], half)
    assert float(inside.detach()) == 0.0
    term = box_outside_term(logits, depths, target, origins, dirs, half)
    assert float(term.detach()) == pytest.approx((p[0] * 0.3 + p[2] * 0.5) / 2, rel=1e-6)
    term.backward()
    g = depths.grad[0]
    assert torch.all(torch.isfinite(g)) and float(g[1]) == 0.0  # inside: no pull (and no NaN at distance 0)
    # d/dd of p * |x - 0.2| / 2 with x = -1 + 2 d: p; a descent step moves the point toward the box
    assert float(g[0]) == pytest.approx(p[0], rel=1e-6)
    # ray 2: d/dd = p * 2 u . n / 2 with n = (0.3, 0.4) / 0.5 the outward normal at the point
    assert float(g[2]) == pytest.approx(p[2] * (1.5 * s * 0.6 + 0.9 * s * 0.8), rel=1e-5)
    assert float(logits.grad[0, 0]) > 0 and float(logits.grad[0, 1]) == 0.0  # turned off, not the inside one
    with torch.no_grad():
        moved = box_outside_term(logits, depths - 0.1 * depths.grad, target, origins, dirs, half)
    assert float(moved) < float(term.detach())


def test_box_weight_adds_the_box_term_and_zero_leaves_the_loss_exactly_as_before():
    model = tiny_model()
    r = model.rig.n_rays
    g = torch.Generator().manual_seed(0)
    out = {"hit_logits": torch.randn(2, r, generator=g), "depths": torch.rand(2, r, generator=g)}
    target = torch.where(torch.rand(2, r, generator=g) > 0.5, torch.rand(2, r, generator=g), torch.zeros(2, r))
    dirs = model.directions.expand(2, r, 3)
    half = torch.tensor([[0.8, 0.4, 0.3], [0.6, 0.5, 0.4]])
    base, base_terms = hit_depth_loss(out["hit_logits"], out["depths"], target)
    loss0, terms0 = model.loss(out, {"depths": target})  # box_weight 0 (the default): no box needed
    assert torch.equal(loss0, base) and terms0 == base_terms
    # the box term by hand in numpy: each ray's point, its distance outside each sample's box
    o, u = model.origins.numpy().astype(np.float64), dirs.numpy().astype(np.float64)
    pts = o + 2.0 * out["depths"].numpy()[..., None] * u
    outside = np.linalg.norm(np.maximum(np.abs(pts) - half.numpy()[:, None, :], 0.0), axis=-1)
    p = 1.0 / (1.0 + np.exp(-out["hit_logits"].numpy().astype(np.float64)))
    box = (p * outside).sum() / (target.numpy() > 0).sum()
    assert box > 0
    model.box_weight = 0.7
    loss, terms = model.loss(out, {"depths": target, "directions": dirs, "box_half": half})
    assert float(loss) == pytest.approx(float(base) + 0.7 * box, rel=1e-5)
    assert terms["box"] == pytest.approx(box, rel=1e-5)
    with pytest.raises(ValueError, match="grown box"):
        model.loss(out, {"depths": target})
    with pytest.raises(ValueError, match="box_weight"):
        tiny_model(box_weight=-1.0)


def test_parameter_counts_and_outputs():
    model = build_model(load_config("sanet-hit"), rig=make_rig(32, 64, 60.0))
    lin = lambda a, b: a * b + b  # noqa: E731
    assert model.param_counts()["decoder"] == lin(1024, 256) + lin(256, 256) + lin(256, 2 * 2048)
    out = model(torch.rand(2, 256, 3) - 0.5)
    assert out["hit_logits"].shape == out["depths"].shape == (2, 2048)
    assert model.clip is None and model.threshold == 0.5


def test_completion_keeps_rays_with_p_at_or_above_the_threshold_and_clamps_depths():
    rig = make_rig(8, 16, 60.0)
    model = tiny_model(rig).eval()
    rng = np.random.default_rng(0)
    logits = rng.normal(size=(2, rig.n_rays)).astype(np.float32) * 2
    depths = rng.uniform(-0.2, 1.3, size=(2, rig.n_rays)).astype(np.float32)
    outs = {"hit_logits": torch.from_numpy(logits), "depths": torch.from_numpy(depths)}
    for t in (0.3, 0.5, 0.8):
        model.threshold = t
        clouds = model.outputs_to_points(outs)
        for b in range(2):
            keep = 1 / (1 + np.exp(-logits[b].astype(np.float64))) >= t
            half_chord = -np.sum(rig.origins[keep] * rig.directions[keep], axis=1)  # <= 1
            d = np.minimum(np.clip(depths[b][keep], 0, None), half_chord)
            want = rig.origins[keep] + 2 * d[:, None] * rig.directions[keep]
            np.testing.assert_allclose(clouds[b].numpy(), want, atol=1e-6)
            assert np.linalg.norm(clouds[b].numpy(), axis=1).max() <= 1 + 1e-6  # inside the unit sphere
    # an explicit threshold wins over the stored one
    a = model.outputs_to_points(outs, threshold=0.9)
    assert all(len(x) < len(y) for x, y in zip(a, model.outputs_to_points(outs, threshold=0.1)))


def test_threshold_is_chosen_on_validation_stored_and_used(run, data):
    from scipy.spatial import cKDTree

    from spotlights.learning.data import TorchCompletionDataset
    from spotlights.learning.evaluate import evaluate_checkpoint
    from spotlights.learning.inference import load_completer

    out, res = run
    best = load_checkpoint(out / "best.pt")
    rec = best["hit_threshold"]
    grid = [float(t) for t in rec["scan"]]
    assert grid == list(load_config("sanet-hit")["model"]["args"]["threshold_grid"])
    model = model_from_checkpoint(best)
    assert model.threshold == rec["value"] == best["best"]["hit_threshold"]
    assert res["history"][best["epoch"] - 1]["val_threshold"] == rec["value"]
    # brute force: score every grid threshold on the val split with scipy, the stored one is the CD-L1 minimiser
    val = TorchCompletionDataset(data, "val", rig=None, max_views=2)
    dense = val.gt_dense()
    batch = torch.utils.data.default_collate([val[i] for i in range(len(val))])
    with torch.no_grad():
        o = model(batch["partial"])
    logits, depths = o["hit_logits"].numpy().astype(np.float64), o["depths"].numpy().astype(np.float64)
    rig = model.rig.for_box(None)  # the model holds the RigSpec; a cap spec's rig needs no box
    cd = {}
    for t in grid:
        acc, comp, n = 0.0, 0.0, 0
        for b, m in enumerate(batch["model"].tolist()):
            keep = 1 / (1 + np.exp(-logits[b])) >= t
            if not keep.any():
                continue
            half_chord = -np.sum(rig.origins[keep] * rig.directions[keep], axis=1)
            d = np.minimum(np.clip(depths[b][keep], 0, None), half_chord)
            pts = rig.origins[keep] + 2 * d[:, None] * rig.directions[keep]
            acc += cKDTree(dense[m]).query(pts)[0].mean()
            comp += cKDTree(pts).query(dense[m])[0].mean()
            n += 1
        cd[t] = (acc + comp) / (2 * n) if n else math.inf
        assert rec["scan"][f"{t:g}"]["chamfer_l1"] == pytest.approx(cd[t], rel=1e-4) if n else True
    assert rec["value"] == min(grid, key=lambda t: cd[t])
    assert best["best"]["value"] == pytest.approx(cd[rec["value"]], rel=1e-4)
    # the Completer and evaluate use the stored threshold
    comp = load_completer(out / "best.pt", device="cpu")
    assert comp.model.threshold == rec["value"]
    x = batch["partial"][:3].numpy()
    clouds = comp.complete(x)
    for b in range(3):
        keep = 1 / (1 + np.exp(-logits[b])) >= rec["value"]
        assert len(clouds[b]) == keep.sum()
    ev = evaluate_checkpoint(out / "best.pt", data, "val", max_views=2, latency=False, progress=False)
    assert [r["variant"] for r in ev["rows"]] == [f"p(hit) >= {rec['value']:g}"] and ev["rows"][0]["threshold"] == rec[
        "value"
    ]
    assert ev["rows"][0]["summary"]["mean_over_samples"]["chamfer_l1"] == pytest.approx(cd[rec["value"]], rel=1e-4)


def test_log_and_resume_keep_the_threshold(run, data):
    import csv

    out, res = run
    rows = list(csv.DictReader((out / "log.csv").open()))
    assert [float(r["val_threshold"]) for r in rows] == [h["val_threshold"] for h in res["history"]]
    last = load_checkpoint(out / "last.pt")
    assert last["hit_threshold"]["value"] == res["history"][-1]["val_threshold"]


def test_bf16_training_is_finite_decreasing_and_float32_loadable(data, tmp_path):
    ov = tiny_overrides("sanet-hit", epochs=6, precision="bf16")
    res = train("sanet-hit", data, tmp_path / "bf16", overrides=ov, progress=False, log=lambda *a: None)
    losses = [h["train_loss"] for h in res["history"]]
    assert all(math.isfinite(v) for v in losses) and losses[-1] < 0.9 * losses[0], losses
    ck = load_checkpoint(tmp_path / "bf16" / "best.pt")
    assert ck["precision"] == "bf16"
    assert all(v.dtype == torch.float32 for v in ck["model_state"].values() if v.is_floating_point())
    out = model_from_checkpoint(ck)(torch.rand(2, 64, 3) - 0.5)
    assert all(v.dtype == torch.float32 for v in out.values())


def test_validate_scores_an_explicit_threshold_list(run, data):
    out, _ = run
    from spotlights.learning.data import TorchCompletionDataset

    model = model_from_checkpoint(load_checkpoint(out / "best.pt"))
    val = TorchCompletionDataset(data, "val", rig=None, max_views=2)
    r = validate(model, val, 4, torch.device("cpu"), val.gt_dense(), thresholds=[0.5])
    assert r["val_threshold"] == 0.5 and list(r["val_threshold_scan"]) == ["0.5"]
    r2 = validate(model, val, 4, torch.device("cpu"), val.gt_dense(), thresholds=[0.99999, 0.5])
    assert r2["val_chamfer_l1"] <= r2["val_threshold_scan"]["0.99999"]["chamfer_l1"] or math.isnan(
        r2["val_threshold_scan"]["0.99999"]["chamfer_l1"]
    )


def _numpy_sanet(state: dict, x: np.ndarray) -> np.ndarray:
    """The paper SA-Net's forward pass in numpy float64 from a state dict: PCN encoder + FC decoder."""
    w = {k: v.double().numpy() for k, v in state.items()}

    def mlp(prefix, h, n):
        for j in range(n):
            h = h @ w[f"{prefix}.linears.{j}.weight"].T + w[f"{prefix}.linears.{j}.bias"]
            if j < n - 1:
                h = np.maximum(h, 0)
        return h

    f = mlp("encoder.first", x, 2)
    f = np.concatenate([f, np.broadcast_to(f.max(axis=1, keepdims=True), f.shape)], axis=-1)
    code = mlp("encoder.second", f, 2).max(axis=1)
    n_dec = len({k.split(".")[2] for k in w if k.startswith("decoder.linears.")})
    return mlp("decoder", code, n_dec)


def test_the_shipped_paper_checkpoint_loads_and_gives_the_same_outputs():
    from spotlights.errors import SpotlightsError
    from spotlights.geometry.encode import decode
    from spotlights.learning.inference import load_completer, pretrained_checkpoint

    try:
        path = pretrained_checkpoint("paper")
    except SpotlightsError:
        pytest.skip("no pretrained checkpoint shipped in this checkout")
    comp = load_completer(path, device="cpu")
    assert comp.model_name == "sanet" and comp.clip == 0.2 and not hasattr(comp.model, "hit_probabilities")
    x = (np.random.default_rng(5).normal(size=(3, 256, 3)) * 0.3).astype(np.float32)
    ref = _numpy_sanet(load_checkpoint(path)["model_state"], x.astype(np.float64))
    with torch.no_grad():
        got = comp.model(torch.from_numpy(x))["depths"].numpy()
    np.testing.assert_allclose(got, ref, atol=2e-4)
    for clip in (0.2, None):
        clouds = comp.complete(x, clip=clip)
        for b in range(3):
            # the network's raw depths clipped to decode's domain [0, 1]: both decodings clamp to the ray's chord and
            # drop depths <= 0
            pts, keep = decode(np.clip(got[b], 0.0, 1.0), comp.rig.for_box(None), clip)
            np.testing.assert_allclose(clouds[b], pts[keep], atol=1e-5)


def test_schedules_without_a_section_train_it_like_sanet(tmp_path):
    from spotlights.learning.models import load_schedule

    assert load_schedule("cpu", "sanet-hit") == load_schedule("cpu", "sanet")
    own = tmp_path / "own.yaml"
    own.write_text("default: {train: {lr: 0.002}}\nsanet: {train: {epochs: 3}}\nsanet-hit: {train: {epochs: 5}}\n")
    assert load_schedule(own, "sanet-hit")["train"] == {"lr": 0.002, "epochs": 5}
    assert load_schedule(own, "sanet")["train"] == {"lr": 0.002, "epochs": 3}


def test_evaluate_table1_columns_training_facts_and_opt_in_latency(run, data, tmp_path, capsys):
    from spotlights.learning.evaluate import evaluate_checkpoints, report_markdown

    from learning_fixtures import cli

    out, res = run
    rep = evaluate_checkpoints([out / "best.pt"], data, "test", max_views=2, progress=False)
    r = rep["results"][0]
    assert "latency_ms" not in r  # opt-in
    ck = load_checkpoint(out / "best.pt")
    h = res["history"][ck["epoch"] - 1]
    assert r["training"] == {
        "steps": ck["global_step"],
        "epochs": ck["epoch"],
        "best_epoch": ck["best"]["epoch"],
        "samples_seen": h["samples_seen"],
        "minutes": pytest.approx(h["wall_seconds"] / 60),
        "precision": "fp32",
    }
    md = report_markdown(rep)
    head = "| Method | Accuracy | Completeness | CD-L1 | F@0.01 | Points | #Params | Steps |"
    assert head in md and "Latency not measured" in md
    row = next(line for line in md.splitlines() if line.startswith("| SA-Net (hit-aware) (p(hit) >= "))
    m = r["rows"][0]["summary"]["mean_over_samples"]
    assert f"{m['accuracy']:.5f} | {m['completeness']:.5f} | {m['chamfer_l1']:.5f} | {m['fscore']:.4f}" in row
    proc = cli(
        capsys,
        "evaluate",
        "--data",
        data,
        "--checkpoint",
        out / "best.pt",
        "--max-views",
        "1",
        "--latency",
        "--latency-repeats",
        "1",
        "--examples",
        "0",
        "--out",
        tmp_path / "rep",
        "--no-progress",
    )
    assert proc.returncode == 0, proc.stderr
    timed = json.loads((tmp_path / "rep.json").read_text())["results"][0]
    assert timed["latency_ms"]["1"]["complete_ms"] > 0 and timed["latency_ms"]["32"]["forward_ms"] > 0


def test_float32_head_under_bf16_autocast():
    """float32_head: the last decoder layer runs in float32 under a bf16 autocast (its output equals the float32
    Linear applied to the bf16 hidden activations); without it the outputs are bf16. The packaged config sets it,
    checkpoints without the key (the shipped default) keep the old bf16 head."""
    torch.manual_seed(0)
    rig = make_rig(4, 8, 60.0)
    args = dict(TINY_MODEL_ARGS["sanet-hit"])
    x = torch.rand(2, 64, 3)
    outs = {}
    for head in (False, True):
        torch.manual_seed(0)
        model = build_model(
            load_config("sanet-hit", overrides={"model": {"args": {**args, "float32_head": head}}}), rig=rig
        )
        with torch.autocast("cpu", dtype=torch.bfloat16):
            outs[head] = model(x)
            code = model.encoder(x).reshape(-1, model.decoder.linears[0].in_features)
            hidden = code
            for lin in model.decoder.linears[:-1]:
                hidden = torch.relu(lin(hidden))
        last = model.decoder.linears[-1]
        want = hidden.float() @ last.weight.T + last.bias  # plain float32 arithmetic, outside autocast
        n = rig.n_rays
        if head:
            np.testing.assert_allclose(
                outs[head]["hit_logits"].detach().numpy(), want[:, :n].detach().numpy(), rtol=1e-5, atol=1e-6
            )
    assert outs[True]["hit_logits"].dtype == torch.float32 and outs[False]["hit_logits"].dtype == torch.bfloat16
    assert load_config("sanet-hit")["model"]["args"]["float32_head"] is True
