"""Completion of user scans: the Completer contract, frame round trips, the CLI and its errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from spotlights.errors import InputFileError, ParameterError  # noqa: E402
from spotlights.geometry.box_json import box_from_dict, load_box  # noqa: E402
from spotlights.geometry.boxes import Box  # noqa: E402
from spotlights.geometry.frames import normalization_from_box  # noqa: E402
from spotlights.geometry.io import load_points, save_points  # noqa: E402
from spotlights.geometry.rig import make_rig  # noqa: E402
from spotlights.learning.inference import complete_in_boxes, complete_scan, load_completer  # noqa: E402

from helpers import assert_user_error  # noqa: E402
from learning_fixtures import cli, make_checkpoint, one_torch_thread  # noqa: E402

_single_thread = pytest.fixture(autouse=True)(one_torch_thread)


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory):
    d = tmp_path_factory.mktemp("ckpts")
    return {n: make_checkpoint(d / f"{n}.pt", n) for n in ("sanet", "pcn")}


@pytest.fixture
def partial_unit():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(256, 3))
    return (0.6 * p / np.linalg.norm(p, axis=1, keepdims=True)).astype(np.float32)


def test_completer_contract(ckpts, partial_unit):
    sanet = load_completer(ckpts["sanet"])
    assert sanet.model_name == "sanet" and sanet.n_params == sum(p.numel() for p in sanet.model.parameters())
    batch = np.stack([partial_unit, partial_unit[::-1].copy()])
    out = sanet.complete(batch)
    assert isinstance(out, list) and len(out) == 2
    assert all(o.dtype == np.float32 and o.ndim == 2 and o.shape[1] == 3 for o in out)
    # clipped rays are dropped; without clip every ray with depth > 0 is kept
    dev = next(sanet.model.parameters()).device  # the default device: CUDA where there is one
    raw = sanet.model(torch.from_numpy(batch).to(dev))["depths"].detach().cpu().numpy()
    assert [len(o) for o in out] == list((raw >= 0.2).sum(1))
    assert [len(o) for o in sanet.complete(batch, clip=None)] == list((raw > 0).sum(1))
    # the points are the rig's rays at the predicted depths
    rig = make_rig(8, 16, 60.0)
    keep = raw[0] >= 0.2
    np.testing.assert_allclose(out[0], rig.origins[keep] + 2 * raw[0][keep, None] * rig.directions[keep], atol=1e-5)
    pcn = load_completer(ckpts["pcn"])
    assert [o.shape for o in pcn.complete(batch)] == [(128, 3), (128, 3)]  # the tiny PCN: 32 coarse x 2x2
    with pytest.raises(ParameterError, match="NaN"):
        sanet.complete(np.full((1, 256, 3), np.nan, np.float32))
    with pytest.raises(ParameterError, match="empty"):
        sanet.complete(np.zeros((1, 0, 3), np.float32))
    with pytest.raises(ParameterError, match=r"\(B, K, 3\)"):
        sanet.complete(np.zeros((2, 256, 4), np.float32))


def test_complete_scan_round_trips_frames(ckpts, partial_unit):
    completer = load_completer(ckpts["sanet"])
    box = Box(center=(12.0, -4.0, 0.9), size=(4.2, 1.8, 1.5), yaw=0.7)
    norm = normalization_from_box(box.center, box.size, box.yaw)
    # Closed form of the box frame: rotation by yaw about z, scale by half the diagonal.
    c, s = np.cos(0.7), np.sin(0.7)
    r = 0.5 * np.sqrt(4.2**2 + 1.8**2 + 1.5**2)
    world = (partial_unit.astype(np.float64) * r) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + box.center
    res = complete_scan(world, box, completer)
    from spotlights.geometry.sampling import canonical_order

    # exactly 256 points: no resampling, only the canonical (sorted) order
    np.testing.assert_allclose(res["partial_unit"], partial_unit[canonical_order(partial_unit)], atol=1e-5)
    expected_unit = completer.complete(partial_unit[None])[0]
    np.testing.assert_allclose(res["completed_unit"], expected_unit, atol=1e-4)
    np.testing.assert_allclose(res["completed"], norm.from_unit(expected_unit), atol=1e-4)
    np.testing.assert_allclose(norm.to_unit(res["completed"]), res["completed_unit"], atol=1e-5)
    # resampling: more points (FPS) or fewer (repeats) still give 256 network inputs
    more = complete_scan(np.concatenate([world, world + 0.01]), box, completer)
    assert more["partial_unit"].shape == (256, 3)
    fewer = complete_scan(world[:40], box, completer)
    assert fewer["partial_unit"].shape == (256, 3) and fewer["used_points"] == 40
    cropped = complete_scan(np.concatenate([world, [[100.0, 100.0, 100.0]]]), box, completer, crop=0.2)
    assert cropped["used_points"] <= 256
    with pytest.raises(ParameterError, match="empty"):
        complete_scan(np.zeros((0, 3)), box, completer)
    with pytest.raises(ParameterError, match="NaN"):
        complete_scan(np.array([[np.nan, 0, 0]]), box, completer)
    with pytest.raises(ParameterError, match="inside the box"):
        complete_scan(np.array([[100.0, 0, 0]]), box, completer, crop=0.1)


def test_box_parsing(tmp_path):
    b = box_from_dict({"center": [1, 2, 3], "size": [4, 2, 1.5], "yaw_deg": 90})
    assert b.yaw == pytest.approx(np.pi / 2)
    f = tmp_path / "box.json"
    f.write_text(json.dumps({"center": [1, 2, 3], "dimensions": [4, 2, 1.5], "yaw": 0.3}))
    assert tuple(load_box(f).size) == (4.0, 2.0, 1.5)
    f.write_text(json.dumps({"center": [1, 2], "size": [4, 2, 1.5]}))
    with pytest.raises(InputFileError, match="center must be three finite numbers"):
        load_box(f)
    f.write_text("{not json")
    with pytest.raises(InputFileError, match="not valid JSON"):
        load_box(f)
    with pytest.raises(InputFileError, match="no 'size'"):
        box_from_dict({"center": [0, 0, 0]})
    with pytest.raises(InputFileError, match="needs 'yaw' or 'rotation'"):  # a heading is never assumed
        box_from_dict({"center": [0, 0, 0], "size": [4, 2, 1.5]})
    with pytest.raises(InputFileError, match="both a yaw and a rotation"):
        box_from_dict({"center": [0, 0, 0], "size": [4, 2, 1.5], "yaw": 0, "rotation": np.eye(3).tolist()})


def test_cli_complete_writes_the_scan_frame_and_a_picture(ckpts, partial_unit, tmp_path, capsys):
    box = {"center": [5.0, 1.0, 0.8], "size": [4.0, 1.7, 1.5], "yaw": -0.4}
    (tmp_path / "box.json").write_text(json.dumps(box))
    norm = normalization_from_box(box["center"], box["size"], box["yaw"])
    scan = tmp_path / "scan.pcd"
    save_points(scan, norm.from_unit(partial_unit))
    out, png = tmp_path / "done.ply", tmp_path / "done.png"
    proc = cli(
        capsys,
        "complete",
        scan,
        "--checkpoint",
        ckpts["sanet"],
        "--box",
        tmp_path / "box.json",
        "--out",
        out,
        "--show",
        png,
        "--no-clip",
        "--no-crop",
        "--precision",
        "fp32",  # compared with the library's float32 completion below
    )
    assert proc.returncode == 0, proc.stderr
    from spotlights.geometry.io import load_ply_fields

    f = load_ply_fields(out)  # the scene: scan (source 1: every point is the object's input) + completion (2)
    got = np.c_[f["x"], f["y"], f["z"]][f["source"] == 2].astype(np.float64)
    assert (f["source"] == 1).sum() == 256
    # same result as the library on the unit-frame scan, mapped back into the scan's frame
    unit_scan = norm.to_unit(load_points(scan)).astype(np.float32)
    # every ray clipped to the box grown by 0.15 m at decoding, then projected (complete_in_boxes)
    done = complete_in_boxes(load_completer(ckpts["sanet"]), unit_scan[None], np.array([box["size"]]), clip=None)
    expect = norm.from_unit(done[0])
    np.testing.assert_allclose(got[: len(expect)], expect, atol=1e-3)
    # keep-observed (on by default): the observed points (the 256 input points, no repeats) follow the prediction
    observed = np.unique(np.c_[f["x"], f["y"], f["z"]][f["source"] == 1], axis=0)
    assert len(got) == len(expect) + len(observed)
    np.testing.assert_allclose(np.unique(got[len(expect) :], axis=0), observed, atol=1e-3)
    assert png.stat().st_size > 1000
    # flags instead of a JSON file
    proc = cli(
        capsys,
        "complete",
        scan,
        "--checkpoint",
        ckpts["pcn"],
        "--center",
        "5",
        "1",
        "0.8",
        "--size",
        "4",
        "1.7",
        "1.5",
        "--yaw",
        "-0.4",
        "--out",
        tmp_path / "pcn.xyz",
        "--no-crop",
        "--no-keep-observed",
    )
    assert proc.returncode == 0, proc.stderr
    assert load_points(tmp_path / "pcn.xyz").shape == (128, 3)  # other formats: the completion only


def test_cli_complete_bad_inputs(ckpts, tmp_path, capsys):
    (tmp_path / "box.json").write_text(json.dumps({"center": [0, 0, 0], "size": [4, 2, 1.5], "yaw": 0.0}))
    empty = tmp_path / "empty.xyz"
    empty.write_text("")
    nan = tmp_path / "nan.xyz"
    nan.write_text("0 0 0\nnan 1 2\n")
    good = tmp_path / "good.npy"
    np.save(good, np.random.default_rng(0).normal(size=(50, 3)))
    common = ["--checkpoint", str(ckpts["sanet"]), "--out", str(tmp_path / "o.ply")]
    assert_user_error(cli(capsys, "complete", empty, "--box", tmp_path / "box.json", *common), "empty.xyz", "empty")
    assert_user_error(cli(capsys, "complete", nan, "--box", tmp_path / "box.json", *common), "nan.xyz", "holds 1 point")
    assert_user_error(cli(capsys, "complete", good, *common), "boxes are missing")
    assert_user_error(
        cli(capsys, "complete", good, "--box", tmp_path / "nobox.json", *common), "nobox.json", "not found"
    )
    assert_user_error(
        cli(
            capsys,
            "complete",
            good,
            "--box",
            tmp_path / "box.json",
            "--checkpoint",
            tmp_path / "box.json",
            "--out",
            tmp_path / "o.ply",
        ),
        "box.json",
        "not a readable checkpoint",
    )
    assert not (tmp_path / "o.ply").exists()


def test_exported_half_precision_weights_complete_alike(ckpts, partial_unit, tmp_path):
    from spotlights.learning.checkpoint import export_weights

    small = export_weights(ckpts["sanet"], tmp_path / "sanet_half.pt", half=True)
    full, half = load_completer(ckpts["sanet"]), load_completer(small)
    assert half.model_name == "sanet" and half.n_params == full.n_params
    x = torch.from_numpy(partial_unit[None])
    a = full.model(x.to(next(full.model.parameters()).device))["depths"].cpu()
    b = half.model(x.to(next(half.model.parameters()).device))["depths"].cpu()
    torch.testing.assert_close(a, b, atol=5e-3, rtol=0)


def test_default_checkpoint_is_the_packaged_one(tmp_path, capsys):
    from spotlights.errors import SpotlightsError
    from spotlights.learning.checkpoint import PRETRAINED, resolve_checkpoint
    from spotlights.learning.inference import pretrained_checkpoint

    try:
        path = pretrained_checkpoint()
    except SpotlightsError as exc:
        assert "checkpoint is not shipped in this installation" in str(exc)
        (tmp_path / "box.json").write_text(json.dumps({"center": [0, 0, 0], "size": [4, 2, 1.5], "yaw": 0}))
        np.save(tmp_path / "scan.npy", np.random.default_rng(0).normal(size=(50, 3)))
        proc = cli(
            capsys, "complete", tmp_path / "scan.npy", "--box", tmp_path / "box.json", "--out", tmp_path / "o.ply"
        )
        assert_user_error(proc, "is not shipped in this installation", "checkpoint file")
    else:
        # the default: the hit-aware SA-Net on the dense box-targeted rig; the paper's SA-Net by its own name
        default = load_completer(path)
        assert path.name == "default.pt" and default.model_name == "sanet-hit" and default.needs_box
        assert default.rig.n_rays == 128 * 128 and default.clip is None
        assert load_completer("paper").model_name == "sanet"
        # short names resolve to packaged files; None is the default; paths stay paths
        assert resolve_checkpoint(None) == resolve_checkpoint("default") == path
        assert set(PRETRAINED) >= {"default", "paper"} and resolve_checkpoint("paper").is_file()
        assert resolve_checkpoint(str(path)) == path
    with pytest.raises(InputFileError, match="short names: default, paper"):
        resolve_checkpoint(tmp_path / "defualt")


def test_short_checkpoint_names_resolve_to_shipped_float16_files(tmp_path, monkeypatch):
    from spotlights.learning.checkpoint import PRETRAINED, load_checkpoint, resolve_checkpoint

    assert set(PRETRAINED) == {"default", "paper", "classes"}
    paper = resolve_checkpoint("paper")
    assert paper.name == "paper.pt" and resolve_checkpoint(None) == resolve_checkpoint("default")
    for name in PRETRAINED:
        p = resolve_checkpoint(name)
        ck = load_checkpoint(p)
        assert 0.5e6 < p.stat().st_size < 10e6  # a few MB
        assert all(v.dtype == torch.float16 for v in ck["model_state"].values() if v.is_floating_point())
        assert "optimizer_state" not in ck and "scaler_state" not in ck
    ck = load_checkpoint(paper)
    assert ck["model_name"] == "sanet" and ck["rig"] == make_rig(32, 64, 60.0).to_dict()
    assert ck["config"]["model"]["args"]["clip"] == 0.2
    # a path is a path, a near-miss of a short name is a missing file naming the short names
    assert resolve_checkpoint(str(paper)) == paper
    with pytest.raises(InputFileError, match="short names: default, paper"):
        resolve_checkpoint("papr")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "paper.pt").write_bytes(paper.read_bytes())
    assert resolve_checkpoint("paper.pt") == Path("paper.pt")  # a suffix makes it a file
