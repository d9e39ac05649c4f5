"""The per-viewpoint decoder of the hit-aware SA-Net (``model.args.viewpoint_code``): outputs and gradients
against a naive loop over viewpoints and rays, the closed-form parameter count of the packaged variant, the
start from a plain decoder's weights (the plain model's outputs exactly), ONNX export, and the fine-tune path."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

torch = pytest.importorskip("torch")

from spotlights.errors import InputFileError  # noqa: E402
from spotlights.geometry.boxes import unit_extents  # noqa: E402
from spotlights.geometry.rig import RigSpec, make_rig  # noqa: E402
from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint, save_checkpoint  # noqa: E402
from spotlights.learning.models import build_model, load_config  # noqa: E402
from spotlights.learning.models.viewpoint_head import ViewpointDecoder  # noqa: E402
from spotlights.learning.training_run import init_from_checkpoint  # noqa: E402

from learning_fixtures import one_torch_thread  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)
VARIANTS = __import__("pathlib").Path(__file__).resolve().parents[1] / "src/spotlights/learning/configs/variants"
TINY = {"code_size": 24, "encoder_widths": [8, 16, 24], "hidden": [12, 5]}
VOCAB = ["car", "caravan", "truck", "bus", "trailer"]


def tiny(rig, **args):
    cfg = load_config("sanet-hit", overrides={"model": {"args": {**TINY, **args}}})
    return build_model(cfg, rig=rig)


def naive_outputs(model, code):
    """The decoder by loops: hidden layers, then for every viewpoint i its code ReLU(W_c[i] h + b_c[i]) and for
    every output kind p and ray k of it ``sum_j V[i, j, p*M + k] code[j] + v[i, p*M + k]`` at ``p*N*M + i*M + k``."""
    dec = model.decoder
    n, m, c = model.rig.n_primary, model.rig.n_secondary, dec.c
    lin = dec.trunk.linears
    h = code
    for layer in lin[:-1]:
        h = torch.relu(h @ layer.weight.T + layer.bias)
    cols = []
    for b in range(code.shape[0]):
        row = [None] * (2 * n * m)
        for i in range(n):
            w, bias = lin[-1].weight[i * c : (i + 1) * c], lin[-1].bias[i * c : (i + 1) * c]
            z = torch.relu(w @ h[b] + bias)
            for p in range(2):
                for k in range(m):
                    row[p * n * m + i * m + k] = (dec.view_weight[i, :, p * m + k] * z).sum() + dec.view_bias[
                        i, p * m + k
                    ]
        cols.append(torch.stack(row))
    out = torch.stack(cols)
    return out[:, : n * m], out[:, n * m :]


def test_outputs_and_gradients_match_a_naive_loop_over_viewpoints_and_rays():
    rig = make_rig(4, 3, 60.0)  # N = 4 viewpoints of M = 3 rays
    torch.manual_seed(0)
    model = tiny(rig, viewpoint_code=3)
    assert isinstance(model.decoder, ViewpointDecoder)
    x = torch.rand(2, 40, 3) - 0.5
    out = model(x)
    assert out["hit_logits"].shape == out["depths"].shape == (2, rig.n_rays)
    logits, depths = naive_outputs(model, model.encode(x))
    torch.testing.assert_close(out["hit_logits"], logits, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(out["depths"], depths, atol=1e-5, rtol=1e-5)
    # gradients of a loss through the vectorised decoder equal those through the naive loops
    target = torch.rand(2, rig.n_rays) * (torch.rand(2, rig.n_rays) > 0.4)
    params = [model.decoder.view_weight, model.decoder.view_bias, model.decoder.trunk.linears[-1].weight]
    g_fast = torch.autograd.grad(model.loss(model(x), {"depths": target})[0], params)
    lg, dp = naive_outputs(model, model.encode(x))
    g_naive = torch.autograd.grad(model.loss({"hit_logits": lg, "depths": dp}, {"depths": target})[0], params)
    assert any(float(g.abs().max()) > 0 for g in g_fast)
    for a, b in zip(g_fast, g_naive):
        torch.testing.assert_close(a, b, atol=1e-6, rtol=1e-4)


def test_the_packaged_wide_variant_has_its_closed_form_parameter_count():
    cfg = load_config("sanet-hit", overrides=yaml.safe_load((VARIANTS / "sanet-hit-wide.yaml").read_text()))
    rig = RigSpec.from_name(cfg["data"]["rig"])
    model = build_model(cfg, rig=rig)
    n, m = rig.n_primary, rig.n_secondary

    def lin(a, b):
        return a * b + b

    decoder = lin(1024, 256) + lin(256, 64) + lin(64, n * 64) + n * 64 * 2 * m + n * 2 * m
    assert model.param_counts()["decoder"] == decoder == 2_941_248
    out = model(torch.rand(1, 64, 3) - 0.5)
    assert out["depths"].shape == (1, n * m)


@pytest.mark.parametrize("code", [5, 7])
def test_a_plain_decoders_weights_give_the_plain_models_outputs(code):
    rig = make_rig(4, 6, 60.0)
    torch.manual_seed(1)
    plain = tiny(rig, classes=VOCAB, class_templates=True)
    torch.nn.init.normal_(plain.class_embedding.weight, std=1.0)
    torch.nn.init.normal_(plain.class_template.weight, std=0.5)
    wide = tiny(rig, viewpoint_code=code, classes=VOCAB, class_templates=True)
    wide.load_state_dict(wide.init_state(plain.state_dict()), strict=True)
    x, cls = torch.rand(3, 50, 3) - 0.5, torch.tensor([0, 2, -1])
    a, b = plain(x, cls), wide(x, cls)
    for k in ("hit_logits", "depths"):
        torch.testing.assert_close(a[k], b[k], atol=1e-5, rtol=1e-5)
    # a narrower per-viewpoint code than the plain last hidden layer cannot hold it
    with pytest.raises(ValueError, match="viewpoint_code"):
        tiny(rig, viewpoint_code=4).init_state(plain.state_dict())


def _save(path, model, cfg, rig):
    return save_checkpoint(
        path,
        {
            "model_name": "sanet-hit",
            "config": cfg,
            "rig": rig.to_dict(),
            "model_state": model.state_dict(),
            "param_counts": model.param_counts(),
            "epoch": 0,
            "global_step": 0,
        },
    )


def test_a_run_initialised_from_a_plain_checkpoint_starts_as_it_and_reloads(tmp_path):
    rig = make_rig(4, 6, 60.0)
    torch.manual_seed(2)
    cfg = load_config("sanet-hit", overrides={"model": {"args": dict(TINY)}})
    plain = build_model(cfg, rig=rig)
    path = _save(tmp_path / "plain.pt", plain, cfg, rig)
    wide = tiny(rig, viewpoint_code=5)
    init_from_checkpoint(wide, path)
    x = torch.rand(2, 30, 3) - 0.5
    torch.testing.assert_close(plain(x)["depths"], wide(x)["depths"], atol=1e-5, rtol=1e-5)
    # its own checkpoint loads back as a per-viewpoint model with the same outputs
    wcfg = load_config("sanet-hit", overrides={"model": {"args": {**TINY, "viewpoint_code": 5}}})
    back = model_from_checkpoint(load_checkpoint(_save(tmp_path / "wide.pt", wide, wcfg, rig)))
    torch.testing.assert_close(back(x)["depths"], wide(x)["depths"])
    # a plain checkpoint of other hidden widths is a one-line error naming the file
    other = build_model(load_config("sanet-hit", overrides={"model": {"args": {**TINY, "hidden": [12, 9]}}}), rig=rig)
    bad = _save(tmp_path / "other.pt", other, cfg, rig)
    with pytest.raises(InputFileError, match="other.pt"):
        init_from_checkpoint(tiny(rig, viewpoint_code=5), bad)


def test_bf16_autocast_keeps_the_float32_head():
    rig = make_rig(4, 6, 60.0)
    torch.manual_seed(3)
    model = tiny(rig, viewpoint_code=5, float32_head=True)
    x = torch.rand(2, 30, 3) - 0.5
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = model(x)
    assert out["depths"].dtype == torch.float32
    ref = model(x)["depths"]
    assert float((out["depths"] - ref).detach().abs().max()) < 0.05


def test_bad_viewpoint_code_is_refused():
    with pytest.raises(ValueError, match="viewpoint_code"):
        tiny(make_rig(4, 6, 60.0), viewpoint_code=0)


def test_onnx_export_matches_torch(tmp_path):
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from spotlights.learning.export import export_onnx, load_onnx_completer, parity

    rig = RigSpec.from_name("box-8x16-ellipsoid-s1")
    torch.manual_seed(4)
    args = {**TINY, "viewpoint_code": 5, "classes": VOCAB, "class_templates": True}
    cfg = load_config("sanet-hit", overrides={"model": {"args": args}})
    model = build_model(cfg, rig=rig)
    torch.nn.init.normal_(model.class_embedding.weight, std=1.0)
    ckpt = _save(tmp_path / "wide.pt", model, cfg, rig)
    onx = load_onnx_completer(export_onnx(ckpt, tmp_path / "wide.onnx"))
    rng = np.random.default_rng(0)
    scans = (rng.uniform(-0.4, 0.4, size=(3, 64, 3))).astype(np.float32)
    extents = unit_extents(np.array([[4.4, 1.8, 1.5], [12.0, 2.5, 3.8], [16.0, 2.5, 4.0]]))
    # parity's class rows are -1, 0, 1, ...: no class and every class of the vocabulary in turn
    diff = parity(ckpt, onx, np.concatenate([scans, scans]), extents=np.concatenate([extents, extents]))
    assert all(v < 1e-4 for k, v in diff.items() if k != "kept_rays_differ"), diff
    assert diff.get("kept_rays_differ", 0) == 0, diff
