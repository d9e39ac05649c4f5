"""The light runtime of one frame: ``--runtime auto`` picks onnxruntime for the packaged models shipped with their
ONNX exports (never importing torch on that path), torch elsewhere; the exports give torch's outputs (both models,
every class of the class model) and the same statuses when the fallback routes a van to the class model."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from spotlights.errors import ParameterError
from spotlights.learning import runtime as rt

from helpers import LIDAR, need, src_pythonpath

KITTI = LIDAR / "kitti-object" / "training-fov-cropped"
PARITY_TOLERANCE = 1e-4
"""Largest |onnxruntime - torch| of any graph output (depths, ray points, p(hit); unit frame) of the shipped
exports on float32: measured 8e-7 to 3e-6 (docs/studies/speed.md), rounding of the two runtimes' kernels."""


def _no_cuda(monkeypatch):
    monkeypatch.setattr(rt, "cuda_present", lambda: False)


def test_auto_picks_onnx_for_shipped_exports_on_the_cpu_and_torch_elsewhere(monkeypatch):
    _no_cuda(monkeypatch)
    assert rt.shipped_onnx("default").name == "default.onnx" and rt.shipped_onnx(None).name == "default.onnx"
    assert rt.shipped_onnx("classes").name == "classes.onnx"
    assert rt.shipped_onnx("paper") is None and rt.shipped_onnx("runs/x/best.pt") is None
    assert rt.choose_runtime("default") == ("onnx", rt.shipped_onnx("default"))
    assert rt.choose_runtime(None, None, "cpu", "fp32") == ("onnx", rt.shipped_onnx("default"))
    assert rt.choose_runtime("classes", "auto", None, "auto")[0] == "onnx"
    # torch: a checkpoint without an export, a CUDA device, bf16 asked for, or the torch runtime asked for
    assert rt.choose_runtime("paper") == ("torch", "paper")
    assert rt.choose_runtime("runs/x/best.pt") == ("torch", "runs/x/best.pt")
    assert rt.choose_runtime("default", device="cuda:0")[0] == "torch"
    assert rt.choose_runtime("default", precision="bf16")[0] == "torch"
    assert rt.choose_runtime("default", "torch") == ("torch", "default")
    monkeypatch.setattr(rt, "cuda_present", lambda: True)  # a GPU machine, no device given: torch decides
    assert rt.choose_runtime("default")[0] == "torch" and rt.choose_runtime("default", device="cpu")[0] == "onnx"
    # an ONNX file always runs with onnxruntime; torch refuses one; onnx needs a file or a shipped export
    assert rt.choose_runtime("m.onnx", "auto", "cuda") == ("onnx", "m.onnx")
    with pytest.raises(ParameterError, match="m.onnx is an ONNX file"):
        rt.choose_runtime("m.onnx", "torch")
    with pytest.raises(ParameterError, match="pass `checkpoint` MODEL.onnx"):
        rt.choose_runtime("paper", "onnx")
    assert rt.choose_runtime("default", "onnx") == ("onnx", rt.shipped_onnx("default"))
    with pytest.raises(ParameterError, match="unknown `runtime`"):
        rt.choose_runtime("default", "tensorrt")


def test_auto_falls_back_to_torch_without_onnxruntime(monkeypatch):
    _no_cuda(monkeypatch)
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # any import of it fails
    assert not rt.onnxruntime_imports()
    assert rt.choose_runtime("default") == ("torch", "default")


def test_the_fallback_runs_with_the_main_runtime_where_it_can():
    assert rt.fallback_runtime("auto", "classes") == "auto" and rt.fallback_runtime(None, "classes") == "auto"
    assert rt.fallback_runtime("onnx", "classes") == "onnx"  # its export ships
    assert rt.fallback_runtime("onnx", "my.pt") == "auto" and rt.fallback_runtime("torch", "c.onnx") == "auto"
    assert rt.fallback_runtime("torch", "classes") == "torch"


@pytest.mark.parametrize("name", ["default", "classes"])
@pytest.mark.timeout(120)
def test_shipped_exports_give_the_torch_outputs(name):
    pytest.importorskip("torch")
    from spotlights.geometry.boxes import unit_extents
    from spotlights.learning.export import load_onnx_completer, parity

    onx = load_onnx_completer(rt.shipped_onnx(name), threads=1)
    x = (np.random.default_rng(3).normal(size=(6, 256, 3)) * [0.35, 0.2, 0.15]).astype(np.float32)
    if name == "classes":
        assert onx.classes == ("car", "caravan", "truck", "bus", "trailer") and "classes" in onx.inputs
        rows = np.array([-1, 0, 1, 2, 3, 4])  # no class, then every class in turn
        extents = unit_extents(np.array([[4.4, 1.8, 1.5], [4.4, 1.8, 1.5], [5.2, 2.0, 2.1], [8.0, 2.5, 3.2]] * 2)[:6])
    else:
        assert onx.classes == ()
        rows, extents = None, unit_extents(np.array([[4.4, 1.8, 1.5]] * 6))
    diff = parity(name, onx, x, extents=extents, classes=rows)
    assert diff["kept_rays_differ"] == 0, diff
    assert max(v for k, v in diff.items() if k != "kept_rays_differ") < PARITY_TOLERANCE, diff


@pytest.mark.timeout(180)
def test_fallback_routing_gives_the_same_statuses_in_both_runtimes(monkeypatch):
    """KITTI 002155: the van (KITTI ``Van``: class caravan) goes to the class model in both runtimes; every box gets
    the same status and model, and the completions agree within float rounding."""
    pytest.importorskip("torch")
    _no_cuda(monkeypatch)
    from spotlights.completion.frame import complete_scene
    from spotlights.completion.scan import CompletionOptions
    from spotlights.data.real import open_reader

    frame = open_reader(need(KITTI), "kitti").load(("", "002155"))
    results = {}
    for runtime in ("onnx", "torch"):
        opts = CompletionOptions(runtime=runtime, precision="fp32", threads=1)
        main, fb = opts.load_completer(), opts.load_fallback()
        assert main.runtime == fb.runtime == runtime and fb.classes  # the class model beside the default
        results[runtime] = complete_scene(
            frame.points, frame.boxes, main, opts.scene_config(), fallback=fb, fallback_name=opts.fallback_model
        )
    a, b = results["onnx"], results["torch"]
    sa = [(o.status, o.completed_by) for o in a.objects]
    assert sa == [(o.status, o.completed_by) for o in b.objects]
    vans = [o for o in a.objects if o.box.cls == "caravan"]
    assert vans and all(o.status == "completed" and o.completed_by == "classes" for o in vans)
    for oa, ob in zip(a.completed, b.completed):
        assert abs(len(oa.completion) - len(ob.completion)) <= 2  # a ray on the p(hit) threshold may flip
        if len(oa.completion) == len(ob.completion):
            assert np.abs(oa.completion - ob.completion).max() < 1e-3  # metres


@pytest.mark.timeout(120)
def test_one_frame_from_the_command_line_never_imports_torch(tmp_path):
    """``spotlights complete`` on KITTI 002155 with default options, in a fresh process through the console
    script's entry: onnxruntime runs both models (the van goes to the class model) and torch is never imported."""
    root = need(KITTI)
    code = (
        "import sys\n"
        "from spotlights.entry import main\n"
        "sys.argv = ['spotlights'] + sys.argv[1:]\n"
        "rc = main()\n"
        "print('TORCH' if 'torch' in sys.modules else 'NO-TORCH')\n"
        "raise SystemExit(rc)\n"
    )
    env = {**os.environ, "PYTHONPATH": src_pythonpath(), "MPLBACKEND": "Agg"}
    env.pop("CUDA_VISIBLE_DEVICES", None)
    args = [
        "complete",
        root / "velodyne_reduced" / "002155.bin",
        "--boxes",
        root / "label_2" / "002155.txt",
        "--calib",
        root / "calib" / "002155.txt",
        "--out",
        tmp_path / "o.ply",
        "--summary",
        tmp_path / "o.json",
        "--device",
        "cpu",
    ]
    proc = subprocess.run(
        [sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, env=env, timeout=110
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().endswith("NO-TORCH"), proc.stdout
    assert "(sanet-hit, onnxruntime fp32)" in proc.stdout
    summ = json.loads((tmp_path / "o.json").read_text())
    assert summ["runtime"] == "onnx" and summ["precision"] == "fp32"
    assert any(o.get("completed_by") == "classes" for o in summ["objects"])


def test_auto_runs_many_frames_with_torch_at_bf16_where_the_cpu_has_it(monkeypatch):
    """``frames`` >= MANY_FRAMES on a CPU with native bfloat16: torch (its bf16 scans cost less than onnxruntime's
    float32 ones, and the frames repay its start-up); one frame, or a CPU without bf16, or bf16 refused: onnx."""
    _no_cuda(monkeypatch)
    many, bf16, plain = rt.MANY_FRAMES, {"avx512_bf16", "avx512f"}, {"avx2", "avx512f"}
    assert rt.choose_runtime("default", frames=many, flags=bf16) == ("torch", "default")
    assert rt.choose_runtime("default", frames=many, flags={"amx_bf16"})[0] == "torch"
    assert rt.choose_runtime("default", frames=many - 1, flags=bf16)[0] == "onnx"
    assert rt.choose_runtime("default", frames=many, flags=plain)[0] == "onnx"
    assert rt.choose_runtime("default", precision="fp32", frames=many, flags=bf16)[0] == "onnx"
    monkeypatch.setattr(rt, "torch_imports", lambda: False)  # a core install with onnxruntime only
    assert rt.choose_runtime("default", frames=many, flags=bf16)[0] == "onnx"
