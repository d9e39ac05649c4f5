"""Models: output shapes, parameter counts against closed forms, registry and configs."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from spotlights.errors import InputFileError, ParameterError  # noqa: E402
from spotlights.geometry.encode import decode  # noqa: E402
from spotlights.geometry.rig import make_rig  # noqa: E402
from spotlights.learning.models import MODEL_NAMES, build_model, load_config  # noqa: E402

from helpers import src_pythonpath  # noqa: E402
from learning_fixtures import TINY_MODEL_ARGS, one_torch_thread  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)


def lin(a, b):
    return a * b + b


def bn(c):
    return 2 * c


ENCODER = lin(3, 128) + lin(128, 256) + lin(512, 512) + lin(512, 1024)


def expected_decoder(name: str) -> int:
    """Closed-form decoder parameter counts of the default configs (docs/learning.md)."""
    if name == "sanet":
        return lin(1024, 256) + lin(256, 256) + lin(256, 2048)
    if name == "sanet-hit":  # a hit logit and a depth per ray
        return lin(1024, 256) + lin(256, 256) + lin(256, 2 * 2048)
    if name == "sanet-local":  # the dense default's hidden layers, then a shared per-ray MLP over the evidence
        features = 4 * 3 + 1 + 8  # 4 near-ray candidates x (depth, distance, valid), their count, 8 carved bins
        local = lin(3, 16) + lin(1024 + 2 + 16 + features, 32) + lin(32, 32) + lin(32, 2)
        return lin(1024, 256) + lin(256, 64) + lin(64, 2 * 2048) + local
    if name == "pcn":
        return 2 * lin(1024, 1024) + lin(1024, 512 * 3) + lin(1024 + 5, 512) + lin(512, 512) + lin(512, 3)
    if name == "foldingnet":
        return lin(1026, 512) + lin(512, 512) + lin(512, 3) + lin(1027, 512) + lin(512, 512) + lin(512, 3)
    if name == "topnet":
        root = lin(1024, 256) + bn(256) + lin(256, 64) + bn(64) + lin(64, 8 * 2)
        n = 1032
        hidden = lin(n, n) + lin(n, n // 2) + lin(n // 2, n // 4) + lin(n // 4, n // 8)
        hidden_bn = bn(n) + bn(n // 2) + bn(n // 4) + bn(n // 8)
        inner = 4 * (hidden + hidden_bn + lin(n // 8, 8 * 4))
        last = hidden + lin(n // 8, 3 * 4)
        return root + inner + last
    if name == "atlasnet":
        b = 1026
        return 4 * (lin(b, b) + bn(b) + lin(b, b // 2) + bn(b // 2) + lin(b // 2, b // 4) + bn(b // 4) + lin(b // 4, 3))
    if name == "snowflakenet":  # dim 32, 256 seeds from a 256-d split code, up factors 1, 4, 8
        d = 32
        seeds = lin(1024, 256) + lin(256, 256 * d) + lin(d + 1024, 2 * d) + lin(2 * d, d) + lin(d, 3)
        transformer = lin(2 * d, d) + lin(d, d) + 2 * lin(d, d) + lin(3, 32) + lin(32, d) + 2 * lin(d, d) + lin(d, d)
        spd = (
            lin(1027, 2 * d) + lin(2 * d, d) + transformer + lin(2 * d, d) + lin(d, d) + lin(d, d // 2) + lin(d // 2, 3)
        )
        return seeds + sum(spd + lin(d, r * d) for r in (1, 4, 8))
    raise KeyError(name)


@pytest.fixture(scope="module")
def rig():
    return make_rig(32, 64, 60.0)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_default_model_shapes_and_parameter_counts(name, rig):
    torch.manual_seed(0)
    model = build_model(load_config(name), rig=rig).eval()
    counts = model.param_counts()
    assert counts["encoder"] == ENCODER == 821_504
    assert counts["decoder"] == expected_decoder(name)
    assert counts["total"] == counts["encoder"] + counts["decoder"]
    x = torch.rand(2, 256, 3) * 1.1 - 0.55
    with torch.no_grad():
        out = model(x)
    if name.startswith("sanet"):
        assert out["depths"].shape == (2, 2048)
    else:
        assert out["points"].shape == (2, 16_384 if name == "snowflakenet" else 2048, 3)
    clouds = model.complete(x)
    assert len(clouds) == 2 and all(c.ndim == 2 and c.shape[1] == 3 and c.dtype == torch.float32 for c in clouds)


def test_sanet_decoder_is_small_and_a_quarter_of_the_papers_baselines():
    counts = build_model(load_config("sanet"), rig=make_rig()).param_counts()
    assert counts["decoder"] <= 1_000_000
    # The paper's smallest baseline (TopNet, 7.5M): SA-Net must be at most a quarter of it.
    assert counts["total"] <= 7.5e6 / 4


def test_encoder_is_permutation_invariant_and_accepts_any_point_count():
    torch.manual_seed(0)
    model = build_model(load_config("pcn", overrides={"model": {"args": TINY_MODEL_ARGS["pcn"]}})).eval()
    x = torch.rand(3, 100, 3)
    perm = torch.randperm(100)
    with torch.no_grad():
        a = model.encoder(x)
        b = model.encoder(x[:, perm])
        c = model.encoder(x[:, :7])
    torch.testing.assert_close(a, b)
    assert c.shape == (3, 64) and a.shape == (3, 64)


def test_sanet_decoding_matches_geometry_decode():
    rig = make_rig(8, 16, 60.0)
    model = build_model(load_config("sanet", overrides={"model": {"args": TINY_MODEL_ARGS["sanet"]}}), rig=rig)
    rng = np.random.default_rng(0)
    depths = rng.uniform(-0.1, 0.9, size=(3, rig.n_rays)).astype(np.float32)
    depths[:, ::5] = 0.0
    for clip in (None, 0.2):
        pts, mask = model.decode(torch.from_numpy(depths), clip)
        ref_pts, ref_mask = decode(np.clip(depths, 0, None), rig, clip)
        np.testing.assert_array_equal(mask.numpy(), ref_mask)
        np.testing.assert_allclose(pts.numpy()[mask.numpy()], ref_pts[ref_mask], atol=1e-6)
    # complete() keeps exactly the rays with depth >= clip, in ray order
    out = model.outputs_to_points({"depths": torch.from_numpy(depths)}, 0.2)
    for b in range(3):
        keep = depths[b] >= 0.2
        # a predicted depth is clamped to half its ray's chord through the unit sphere: P stays in the sphere
        half_chord = -np.sum(rig.origins[keep] * rig.directions[keep], axis=1)
        d = np.minimum(depths[b][keep], half_chord)
        expect = rig.origins[keep] + 2 * d[:, None] * rig.directions[keep]
        np.testing.assert_allclose(out[b].numpy(), expect, atol=1e-6)
        assert np.linalg.norm(out[b].numpy(), axis=1).max() <= 1 + 1e-6


def test_pcn_alpha_schedule_and_fine_points_refine_coarse():
    model = build_model(load_config("pcn", overrides={"model": {"args": TINY_MODEL_ARGS["pcn"]}}))
    assert model.alpha(0.0) == 0.01 and model.alpha(0.05) == 0.1 and model.alpha(0.1) == 0.5 and model.alpha(0.9) == 1.0
    with torch.no_grad():
        out = model(torch.rand(2, 50, 3))
    assert out["coarse"].shape == (2, 32, 3) and out["points"].shape == (2, 128, 3)


def test_topnet_leaf_count_and_tanh_range():
    model = build_model(load_config("topnet", overrides={"model": {"args": {"degrees": [2, 4, 4, 4, 4, 4]}}})).eval()
    assert model.n_points == 2048
    with torch.no_grad():
        pts = model(torch.rand(2, 64, 3))["points"]
    assert pts.shape == (2, 2048, 3) and float(pts.abs().max()) <= 1.0


def test_atlasnet_random_patches_in_training_regular_grid_in_eval():
    torch.manual_seed(0)
    model = build_model(load_config("atlasnet", overrides={"model": {"args": TINY_MODEL_ARGS["atlasnet"]}}))
    x = torch.rand(2, 32, 3)
    model.eval()
    with torch.no_grad():
        a, b = model(x)["points"], model(x)["points"]
    torch.testing.assert_close(a, b)
    model.train()
    with torch.no_grad():
        c, d = model(x)["points"], model(x)["points"]
    assert not torch.equal(c, d)
    assert a.shape == (2, 128, 3)


def test_foldingnet_grid_is_exactly_32_by_64():
    model = build_model(load_config("foldingnet"))
    g = model.grid.numpy()
    assert g.shape == (2048, 3 - 1)
    assert len(np.unique(g[:, 0])) == 32 and len(np.unique(g[:, 1])) == 64
    np.testing.assert_allclose(np.diff(np.unique(g[:, 0])).mean(), np.diff(np.unique(g[:, 1])).mean(), rtol=1e-5)


def test_configs_override_and_errors(tmp_path):
    cfg = load_config("sanet", overrides={"train": {"epochs": 3}})
    assert cfg["train"]["epochs"] == 3 and cfg["model"]["args"]["clip"] == 0.2
    user = tmp_path / "u.yaml"
    user.write_text("model:\n  args:\n    hidden: [64]\ntrain:\n  lr: 0.01\n")
    cfg = load_config("sanet", user)
    assert cfg["model"]["args"]["hidden"] == [64] and cfg["train"]["lr"] == 0.01 and cfg["train"]["batch_size"] == 32
    other = tmp_path / "o.yaml"
    other.write_text("model:\n  name: pcn\n")
    with pytest.raises(InputFileError, match="for model 'pcn', not 'sanet'"):
        load_config("sanet", other)
    bad = tmp_path / "b.yaml"
    bad.write_text("model: [1, 2\n")
    with pytest.raises(InputFileError, match="invalid YAML"):
        load_config("sanet", bad)
    with pytest.raises(ParameterError, match="unknown model"):
        load_config("pointr")
    with pytest.raises(ParameterError, match="unknown key 'model.args.bogus' for model 'pcn'"):
        build_model(load_config("pcn", overrides={"model": {"args": {"bogus": 1}}}))
    with pytest.raises(ParameterError, match="invalid arguments for model 'sanet'"):
        build_model(load_config("sanet", overrides={"model": {"args": {"output_activation": "tanh"}}}), rig=make_rig())
    with pytest.raises(ParameterError, match="needs a rig"):
        build_model(load_config("sanet"))


def test_registry_imports_no_model_or_torch_at_start_up():
    code = (
        "import sys; import spotlights.learning.models as m; import spotlights.cli as c; c.build_parser(); "
        "assert 'torch' not in sys.modules, 'torch imported'; "
        "assert 'trimesh' not in sys.modules and 'scipy' not in sys.modules, 'trimesh/scipy imported'; "
        "assert not any(k.startswith('spotlights.learning.models.') for k in sys.modules), 'a model imported'"
    )
    env = {"PYTHONPATH": src_pythonpath()}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr


def test_schedules_merge_between_defaults_and_user_config(tmp_path):
    cpu = load_config("foldingnet", schedule="cpu")
    assert cpu["data"]["max_views"] == 25 and cpu["train"]["epochs"] == 13 and cpu["data"]["val_max_views"] == 10
    assert cpu["train"]["lr_schedule"] == {"kind": "cosine", "min_factor": 0.05}  # replaced whole, not merged
    assert load_config("sanet", schedule="cpu")["data"]["max_views"] == 200
    user = tmp_path / "u.yaml"
    user.write_text("train:\n  epochs: 3\n")
    assert load_config("sanet", user, schedule="cpu")["train"]["epochs"] == 3
    paper = load_config("topnet", schedule="paper")
    assert paper["data"]["max_views"] is None and paper["train"]["epochs"] == 40
    with pytest.raises(ParameterError, match="unknown schedule 'gpu-fast'"):
        load_config("sanet", schedule="gpu-fast")


def test_mac_counts_match_closed_forms(rig):
    from spotlights.learning.bench import count_macs

    enc = 256 * (3 * 128 + 128 * 256 + 512 * 512 + 512 * 1024)
    sanet = build_model(load_config("sanet"), rig=rig)
    assert count_macs(sanet) == enc + 1024 * 256 + 256 * 256 + 256 * 2048
    fold = build_model(load_config("foldingnet"))
    # the code's share of each fold's first layer is computed once per shape, not per point
    fold1 = 1024 * 512 + 2048 * (2 * 512 + 512 * 512 + 512 * 3)
    fold2 = 1024 * 512 + 2048 * (3 * 512 + 512 * 512 + 512 * 3)
    assert count_macs(fold) == enc + fold1 + fold2
    pcn = build_model(load_config("pcn"))
    coarse = 1024 * 1024 + 1024 * 1024 + 1024 * 1536
    folding = 1024 * 512 + 2048 * (2 * 512 + 3 * 512 + 512 * 512 + 512 * 3)  # grid and point per point, code once
    assert count_macs(pcn) == enc + coarse + folding
    atlas = build_model(load_config("atlasnet")).eval()
    b = 1026
    patch = 1024 * b + 512 * (2 * b + b * (b // 2) + (b // 2) * (b // 4) + (b // 4) * 3)
    assert count_macs(atlas) == enc + 4 * patch
    top = build_model(load_config("topnet")).eval()
    n = 1032
    root = 1024 * 256 + 256 * 64 + 64 * 16
    tail = n * (n // 2) + (n // 2) * (n // 4) + (n // 4) * (n // 8)
    levels = 0
    nodes = 2
    for i, d in enumerate([4, 4, 4, 4, 4]):
        nout = 3 if i == 4 else 8
        levels += 1024 * n + nodes * (8 * n + tail + (n // 8) * nout * d)
        nodes *= d
    assert count_macs(top) == enc + root + levels


# --- Decoders that broadcast the code instead of concatenating it: checked against the
# --- naive form of the original papers (code replicated on every point, then concatenated).


def _naive(mlp, parts, n):
    """The MLP on the explicit concatenation, every part expanded to (B, n, C_i)."""
    b = max(p.shape[0] for p in parts)
    return mlp(torch.cat([p.expand(b, n, -1) for p in parts], dim=-1))


def _naive_forward(model, x):
    code = model.encoder(x).unsqueeze(1)
    b = code.shape[0]
    if model.name == "foldingnet":
        f1 = _naive(model.fold1, [code, model.grid.unsqueeze(0)], model.n_points)
        return _naive(model.fold2, [code, f1], model.n_points)
    if model.name == "pcn":
        g2 = model.grid_size**2
        coarse = model.coarse_mlp(code[:, 0]).reshape(b, model.num_coarse, 3)
        pf = coarse.repeat_interleave(g2, dim=1)
        grid = model.grid.repeat(model.num_coarse, 1).unsqueeze(0)
        return _naive(model.folding, [grid, pf, code], model.n_points) + pf
    if model.name == "atlasnet":
        uv = model.grid.unsqueeze(0)
        return torch.cat([torch.tanh(_naive(p, [code, uv], model.points_per_patch)) for p in model.patches], dim=1)
    if model.name == "topnet":
        nodes = torch.tanh(model.root(code[:, 0])).reshape(b, model.degrees[0], model.nfeat)
        for i, level in enumerate(model.levels, start=1):
            nout = 3 if i == len(model.degrees) - 1 else model.nfeat
            y = _naive(level, [nodes, code], nodes.shape[1])
            nodes = torch.tanh(y).reshape(b, nodes.shape[1] * model.degrees[i], nout)
        return nodes
    raise KeyError(model.name)


@pytest.mark.parametrize("name", ["foldingnet", "pcn", "atlasnet", "topnet"])
@pytest.mark.parametrize("train_mode", [False, True])
def test_broadcast_decoders_match_the_naive_concatenation(name, train_mode):
    torch.manual_seed(0)
    model = build_model(load_config(name, overrides={"model": {"args": TINY_MODEL_ARGS[name]}}))
    model.train(train_mode)
    if name == "atlasnet":  # the regular grid in both modes, so that the two forms see the same uv
        model.eval()
        for m in model.modules():  # ... but batch statistics when train_mode (batch norm in training)
            if isinstance(m, torch.nn.BatchNorm1d):
                m.train(train_mode)
    x = torch.rand(3, 40, 3)
    got = model(x)["points"]
    want = _naive_forward(model, x)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)
    if train_mode:  # same gradients for every parameter
        g_got = torch.autograd.grad(got.square().sum(), list(model.parameters()), allow_unused=True)
        g_want = torch.autograd.grad(
            _naive_forward(model, x).square().sum(), list(model.parameters()), allow_unused=True
        )
        # biases feeding a batch norm have a zero true gradient: compare at the gradients' scale
        scale = max(float(g.abs().max()) for g in g_want if g is not None)
        for a, b in zip(g_got, g_want):
            assert (a is None) == (b is None)
            if a is not None:
                torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5 * scale)


def test_materialised_concatenation_switch_gives_the_same_outputs():
    """The benchmarks' switch to the original form (MLP.materialise_concat) changes only the speed."""
    from spotlights.learning.models.base import MLP

    torch.manual_seed(1)
    model = build_model(load_config("foldingnet", overrides={"model": {"args": TINY_MODEL_ARGS["foldingnet"]}})).eval()
    x = torch.rand(2, 30, 3)
    with torch.no_grad():
        a = model(x)["points"]
        MLP.materialise_concat = True
        try:
            b = model(x)["points"]
        finally:
            MLP.materialise_concat = False
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)


def test_forward_concat_rejects_a_channel_mismatch():
    from spotlights.learning.models.base import MLP

    mlp = MLP([5, 4, 3])
    with pytest.raises(ValueError, match="channels"):
        mlp.forward_concat([torch.zeros(1, 2, 3), torch.zeros(1, 1, 3)])


def _encoder_by_hand(enc, points: torch.Tensor) -> torch.Tensor:
    """PCN's encoder as the paper writes it, one shape at a time on all its rows (repeats included)."""
    codes = []
    for shape in points:
        f = enc.first(shape)  # (K, 256)
        f = torch.cat([f, f.amax(dim=0, keepdim=True).expand_as(f)], dim=-1)
        codes.append(enc.second(f).amax(dim=0))
    return torch.stack(codes)


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_encoder_without_gradients_skips_repeated_rows_bit_for_bit(precision):
    """Inference runs the encoder on each shape's distinct rows only: the same codes bit for bit as the dense
    forward and as a shape-by-shape reference, for sparse scans padded by repeats, a shape of one point repeated,
    a shape with no repeat, rows equal in another shape, and -0.0 beside 0.0."""
    from spotlights.learning.device import autocast
    from spotlights.learning.models.base import PCNEncoder

    torch.manual_seed(0)
    enc = PCNEncoder(64, (16, 32, 48)).eval()
    rng = np.random.default_rng(3)
    k = 64
    shapes = []
    for n_distinct in (5, 1, 64, 17):
        rows = rng.normal(size=(n_distinct, 3)).astype(np.float32)
        shapes.append(np.concatenate([rows, rows[rng.integers(0, n_distinct, k - n_distinct)]]))
    shapes[3][:5] = shapes[0][:5]  # rows shared between two shapes stay in both
    shapes[1][:] = 100.0  # one point repeated, after every other row of shape 0 in the sort (by bits, x first):
    shapes[0][0] = shapes[1][0]  # ... the last sorted row of shape 0 and the first of shape 1 are equal
    shapes[2][0] = (0.0, 0.0, 0.0)
    shapes[2][1] = (-0.0, 0.0, 0.0)
    points = torch.from_numpy(np.stack([s[rng.permutation(k)] for s in shapes]))
    with autocast(precision, torch.device("cpu")):
        with torch.enable_grad():
            dense = enc(points)
        with torch.no_grad():
            distinct = enc(points)
            by_hand = _encoder_by_hand(enc, points)
    assert dense.requires_grad and not distinct.requires_grad
    assert torch.equal(distinct, dense.detach())
    assert torch.equal(distinct, by_hand)
    assert distinct.shape == (4, 64)


def test_encoder_distinct_rows_run_fewer_rows():
    """The inference path runs the layers on the distinct rows only (counted at the first Linear)."""
    from spotlights.learning.models.base import PCNEncoder

    enc = PCNEncoder(8, (4, 8, 8)).eval()
    seen = []
    enc.first.linears[0].register_forward_hook(lambda mod, args, out: seen.append(args[0].shape[0]))
    rows = torch.randn(3, 3)
    points = torch.stack([rows[[0, 1, 2, 0, 1, 2, 0, 0]], rows[[1, 1, 1, 1, 1, 1, 1, 1]]])  # 3 + 1 distinct
    with torch.no_grad():
        enc(points)
    assert seen == [4]


@pytest.mark.parametrize("dtype", [torch.float64, torch.bfloat16, torch.float16])
def test_encoder_distinct_rows_in_other_dtypes(dtype):
    """A model cast to float64 or a 16-bit float (``model.to(dtype)``, no autocast) keeps the dense forward's codes
    without gradients (float64: up to the matrix library's rounding, whose kernels depend on the row count), and
    its repeated rows are skipped (16-bit rows are compared as float32, which is exact)."""
    from spotlights.learning.models.base import PCNEncoder

    torch.manual_seed(1)
    enc = PCNEncoder(16, (8, 16, 16)).eval().to(dtype)
    seen = []
    enc.first.linears[0].register_forward_hook(lambda mod, args, out: seen.append(args[0].shape[0]))
    rows = torch.randn(5, 3).to(dtype)
    points = torch.stack([rows[[0, 1, 2, 0, 1, 2, 0, 0]], rows[[3, 4, 3, 4, 3, 4, 3, 4]]])  # 3 + 2 distinct
    with torch.no_grad():
        distinct = enc(points)
    with torch.enable_grad():
        dense = enc(points)
    assert seen == [5, 16] and distinct.dtype == dtype
    torch.testing.assert_close(distinct, dense.detach(), rtol=1e-12 if dtype == torch.float64 else 0, atol=0)
