"""ONNX export: every model exports, onnxruntime matches torch on test scans, the rig and the
threshold travel as metadata, ``complete --runtime onnx`` gives torch's completion, a missing runtime is one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

from spotlights.geometry.boxes import unit_extents  # noqa: E402
from spotlights.geometry.rig import RigSpec, make_rig  # noqa: E402
from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint  # noqa: E402
from spotlights.learning.export import export_onnx, load_onnx_completer, parity  # noqa: E402
from spotlights.learning.inference import load_completer  # noqa: E402

from helpers import assert_user_error  # noqa: E402
from learning_fixtures import cli, make_checkpoint, one_torch_thread, tiny_dataset_path  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)
BOX = RigSpec.from_name("box-8x16-ellipsoid-s1")


@pytest.fixture(scope="module")
def test_scans(tmp_path_factory):
    """The tiny dataset's test-split partial scans (B, 256, 3), unit frame."""
    from spotlights.learning.data import TorchCompletionDataset

    ds = TorchCompletionDataset(tiny_dataset_path(tmp_path_factory.getbasetemp() / "export-data"), "test", rig=False)
    return np.stack([ds[i]["partial"].numpy() for i in range(len(ds))]).astype(np.float32)


def _checkpoint(tmp_path, name, rig=None, threshold=None):
    path = make_checkpoint(tmp_path / f"{name}.pt", name, rig=rig)
    if threshold is not None:  # as training stores it
        ck = load_checkpoint(path)
        ck["hit_threshold"] = {"value": threshold, "chosen_on": "val"}
        from spotlights.learning.checkpoint import save_checkpoint

        save_checkpoint(path, {k: v for k, v in ck.items() if k not in ("path", "format", "format_version")})
    return path


@pytest.mark.parametrize(
    "name, rig, threshold",
    [
        ("sanet", None, None),
        ("sanet-hit", None, 0.3),
        ("sanet-hit", BOX, 0.6),
        ("sanet", BOX, None),
        ("pcn", None, None),
        ("foldingnet", None, None),
        ("topnet", None, None),
        ("atlasnet", None, None),
    ],
)
def test_every_model_exports_and_onnxruntime_matches_torch(tmp_path, test_scans, name, rig, threshold):
    ckpt = _checkpoint(tmp_path, name, rig, threshold)
    out = export_onnx(ckpt, tmp_path / "m.onnx")
    onx = load_onnx_completer(out)
    model = model_from_checkpoint(load_checkpoint(ckpt))
    assert onx.model_name == name and onx.n_params == model.param_counts()["total"]
    if model.target == "depths":
        assert onx.rig == model.rig and onx.needs_box == model.needs_box
        assert onx.clip == model.clip and onx.threshold == getattr(model, "threshold", None)
        assert threshold is None or onx.threshold == threshold
    e = unit_extents(np.array([[4.4, 1.8, 1.5], [3.9, 1.7, 1.6], [5.1, 2.0, 1.9]]))[np.arange(len(test_scans)) % 3]
    diff = parity(ckpt, onx, test_scans, extents=e if onx.needs_box else None)
    assert all(v < 1e-4 for k, v in diff.items() if k != "kept_rays_differ"), diff
    assert diff.get("kept_rays_differ", 0) == 0, diff
    # completions: same clouds (batch 1 and a batch, any number of input points)
    ref = load_completer(ckpt, device="cpu")
    kw = {"extents": e} if ref.needs_box else {}
    for x, k in ((test_scans[:1], {k: v[:1] for k, v in kw.items()}), (test_scans[:, :100], kw)):
        a, b = ref.complete(x, **k), onx.complete(x, **k)
        assert [len(p) for p in a] == [len(p) for p in b]
        assert (
            max(float(np.abs(p - q).max()) for p, q in zip(a, b) if len(p)) < 1e-4 if any(len(p) for p in a) else True
        )


def test_a_clip_given_at_run_time_is_applied_like_torch(tmp_path, test_scans):
    ckpt = _checkpoint(tmp_path, "sanet", make_rig(8, 16, 60.0))
    onx = load_onnx_completer(export_onnx(ckpt, tmp_path / "s.onnx"))
    ref = load_completer(ckpt, device="cpu")
    for clip in (None, 0.05, 0.2):
        a, b = ref.complete(test_scans, clip=clip), onx.complete(test_scans, clip=clip)
        assert [len(p) for p in a] == [len(p) for p in b]


def test_the_shipped_paper_sanet_exports_with_its_rig_and_matches_on_test_scans(tmp_path, test_scans, capsys):
    proc = cli(capsys, "export", "paper", "--out", tmp_path / "paper.onnx")
    assert proc.returncode == 0, proc.stderr
    assert "parity" in proc.stdout and "cap-32x64-60" in proc.stdout and "clip 0.2" in proc.stdout
    onx = load_onnx_completer(tmp_path / "paper.onnx")
    assert onx.rig == RigSpec.from_name("cap-32x64-60") and onx.clip == 0.2 and onx.threshold is None
    meta = onx.meta
    assert (
        json.loads(meta["rig"]) == make_rig(32, 64, 60.0).to_dict() and meta["spotlights_format"] == "spotlights-onnx"
    )
    diff = parity("paper", onx, test_scans)
    assert diff["depths"] < 1e-4 and diff["ray_points"] < 1e-4 and diff["kept_rays_differ"] == 0, diff


def test_threads_reach_onnxruntime(tmp_path, capsys):
    """`complete --runtime onnx --threads N`: N is the session's intra-op thread count (it was ignored)."""
    from spotlights.completion.scan import CompletionOptions

    ckpt = _checkpoint(tmp_path, "sanet-hit", make_rig(8, 16, 60.0), 0.4)
    assert cli(capsys, "export", ckpt, "-o", tmp_path / "hit.onnx", "-q").returncode == 0
    for n in (1, 3):
        onx = CompletionOptions(checkpoint=str(tmp_path / "hit.onnx"), runtime="onnx", threads=n).load_completer()
        assert onx.session.get_session_options().intra_op_num_threads == n


def test_complete_runtime_onnx_gives_the_torch_completion(tmp_path, capsys):
    ckpt = _checkpoint(tmp_path, "sanet-hit", make_rig(8, 16, 60.0), 0.4)
    onnx_path = tmp_path / "hit.onnx"
    assert cli(capsys, "export", ckpt, "-o", onnx_path, "-q").returncode == 0
    scan = np.random.default_rng(0).normal(size=(400, 3)) * [1.5, 0.7, 0.5] + [10.0, 2.0, 0.8]
    np.save(tmp_path / "scan.npy", scan)
    box = ["--center", "10", "2", "0.8", "--size", "4.2", "1.8", "1.5", "--yaw", "0.3", "--no-crop"]
    a = cli(capsys, "complete", tmp_path / "scan.npy", *box, "--checkpoint", ckpt, "--out", tmp_path / "a.npy", "-q")
    b = cli(
        capsys,
        "complete",
        tmp_path / "scan.npy",
        *box,
        "--checkpoint",
        onnx_path,
        "--runtime",
        "onnx",
        "--out",
        tmp_path / "b.npy",
        "-q",
    )
    assert a.returncode == 0 and b.returncode == 0, (a.stderr, b.stderr)
    pa, pb = np.load(tmp_path / "a.npy"), np.load(tmp_path / "b.npy")
    assert pa.shape == pb.shape and np.abs(pa - pb).max() < 1e-4
    # an ONNX file selects the runtime by itself; torch refuses one; onnx needs an .onnx file
    c = cli(
        capsys, "complete", tmp_path / "scan.npy", *box, "--checkpoint", onnx_path, "--out", tmp_path / "c.npy", "-q"
    )
    assert c.returncode == 0 and np.array_equal(np.load(tmp_path / "c.npy"), pb)
    d = cli(
        capsys,
        "complete",
        tmp_path / "scan.npy",
        *box,
        "--checkpoint",
        onnx_path,
        "--runtime",
        "torch",
        "--out",
        tmp_path / "d.npy",
    )
    assert_user_error(d, "hit.onnx", "--runtime onnx")
    e = cli(capsys, "complete", tmp_path / "scan.npy", *box, "--runtime", "onnx", "--out", tmp_path / "e.npy")
    assert_user_error(e, "--checkpoint MODEL.onnx")


def test_export_errors_are_one_line(tmp_path, capsys, monkeypatch):
    ckpt = _checkpoint(tmp_path, "sanet", make_rig(8, 16, 60.0))
    proc = cli(capsys, "export", ckpt, "--out", tmp_path / "model.pt")
    assert_user_error(proc, "model.pt", "name it model.onnx")
    assert not (tmp_path / "model.pt").exists()
    not_onnx = tmp_path / "x.onnx"
    not_onnx.write_text("not a model")
    with pytest.raises(Exception, match="x.onnx"):
        load_onnx_completer(not_onnx)
    # without onnxruntime: one line saying how to install it (None in sys.modules makes any import of it fail,
    # whichever import mechanism the code uses)
    import sys

    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    scan = tmp_path / "scan.npy"  # a valid scan: the error must be about the runtime, not the scan
    np.save(scan, np.random.default_rng(0).uniform(-1, 1, (200, 3)).astype(np.float32))
    proc = cli(
        capsys,
        "complete",
        scan,
        "--center",
        "0",
        "0",
        "0",
        "--size",
        "4",
        "2",
        "1.5",
        "--checkpoint",
        not_onnx,
        "--runtime",
        "onnx",
        "--out",
        tmp_path / "o.ply",
    )
    assert proc.returncode == 2 and "pip install 'spotlights[onnx]'" in proc.stderr, proc.stderr


def test_bf16_inference_is_close_to_float32(tmp_path, test_scans):
    """``load_completer(precision="bf16")``: autocast forward, float32 decoding; same rays kept up to rounding."""
    ckpt = _checkpoint(tmp_path, "sanet-hit", make_rig(8, 16, 60.0), 0.5)
    a = load_completer(ckpt, device="cpu")
    b = load_completer(ckpt, device="cpu", precision="bf16")
    assert a.precision == "fp32" and b.precision == "bf16"
    x = torch.from_numpy(test_scans)
    from spotlights.learning.device import autocast

    with torch.inference_mode(), autocast("bf16", torch.device("cpu")):
        code = b.model.encoder(x)
        raw = b.model(x)
    assert code.dtype == torch.bfloat16  # the forward really ran in bf16
    # the packaged sanet-hit config computes the last layer in float32 (float32_head)
    assert raw["depths"].dtype == (torch.float32 if b.model.decoder.float32_last else torch.bfloat16)
    pa, pb = a.complete(test_scans), b.complete(test_scans)
    assert all(p.dtype == np.float32 for p in pb)
    assert abs(sum(map(len, pa)) - sum(map(len, pb))) <= 0.02 * sum(map(len, pa)) + 2


def test_an_export_holds_no_source_locations_so_its_bytes_do_not_depend_on_the_install(tmp_path):
    """The exporter notes each node's Python stack (absolute paths, line numbers); they are stripped, so the
    same checkpoint gives the same bytes wherever spotlights is installed (checked on the file itself)."""
    import onnx

    import spotlights

    ckpt = _checkpoint(tmp_path, "pcn", None, None)
    proto = onnx.load(str(export_onnx(ckpt, tmp_path / "p.onnx")))
    assert len(proto.graph.node) > 10
    assert all(len(n.metadata_props) == 0 for n in proto.graph.node)
    raw = (tmp_path / "p.onnx").read_bytes()
    assert b"stack_trace" not in raw
    assert str(Path(spotlights.__file__).parent).encode() not in raw.replace(str(ckpt).encode(), b"")
