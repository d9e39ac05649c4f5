"""``spotlights real extract | evaluate | show`` end to end, with a fake completer module."""

from __future__ import annotations

import json
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from spotlights.cli import build_parser, main

from helpers import LIDAR, assert_user_error, need, run_cli
from learning_fixtures import tiny_dataset_path


def scene(tmp_path) -> Path:
    """A generic two-frame scene with two tracked cars."""
    rng = np.random.default_rng(2)
    frames = []
    for f in range(2):
        pts, boxes = [rng.uniform(-40, 40, (3000, 3)) * [1, 1, 0.02] + [0, 0, -1.6]], []  # ground-ish clutter
        for tid, c in (("a", [10.0 + 0.5 * f, 2.0, -0.8]), ("b", [-6.0, -5.0 + 0.3 * f, -0.8])):
            obj = rng.uniform(-0.5, 0.5, (300, 3)) * [4.2, 1.8, 1.5]
            obj[:, 2] = np.abs(obj[:, 2])
            pts.append(obj + c)
            boxes.append({"center": c, "size": [4.2, 1.8, 1.5], "yaw": 0.3, "label": "car", "track_id": tid})
        np.save(tmp_path / f"scan{f}.npy", np.concatenate(pts).astype(np.float32))
        frames.append({"scan": f"scan{f}.npy", "frame_id": f"f{f}", "timestamp": f, "boxes": boxes})
    (tmp_path / "scene.json").write_text(json.dumps({"frames": frames}))
    return tmp_path / "scene.json"


@pytest.fixture
def fake_learning(monkeypatch, tmp_path):
    """Install a stand-in for spotlights.learning.inference whose completer returns a fixed ellipsoid."""
    build_parser()  # the command modules import the library at their top: load them before the stand-in

    class Completer:
        n_params = 1
        clips: list = []
        calls: list = []  # model name of every complete() call
        interrupt = None  # a model name whose complete() acts as Ctrl-C

        def __init__(self, name):
            self.model_name = name

        def complete(self, partials, clip="default"):
            Completer.clips.append(clip)
            Completer.calls.append(self.model_name)
            if self.model_name == Completer.interrupt:
                raise KeyboardInterrupt
            t = np.linspace(0, 2 * np.pi, 64)
            ring = np.c_[0.9 * np.cos(t), 0.38 * np.sin(t), np.zeros_like(t)].astype(np.float32)
            return [np.concatenate([ring, p[:32]]) for p in partials]  # depends a little on the input

    mod = types.ModuleType("spotlights.learning.inference")

    def load_completer(path, device=None):
        stem = Path(path).stem.split("_")[0]
        return Completer(Path(path).parent.name.split("-")[0] if stem in ("best", "last") else stem)

    mod.load_completer = load_completer
    mod.Completer = Completer
    monkeypatch.setitem(sys.modules, "spotlights.learning.inference", mod)
    ckpts = []
    for name in ("sanet_1.pt", "pcn_1.pt"):
        (tmp_path / name).write_bytes(b"x")
        ckpts.append(str(tmp_path / name))
    return ckpts


def test_cli_extract_evaluate_show(tmp_path, capsys, fake_learning):
    src = scene(tmp_path)
    out = tmp_path / "obs.h5"
    assert (
        main(["real", "extract", str(src), "--format", "generic", "--out", str(out)]) == 0
    )  # -q would silence the summary
    text = capsys.readouterr().out
    assert "4 observations" in text and "objects observed in two or more frames: 2" in text
    assert "skipped boxes: class_excluded 0" in text

    prefix = tmp_path / "rep"
    assert main(["real", "evaluate", str(out), "--checkpoint", *fake_learning, "--out", str(prefix)]) == 0
    text = capsys.readouterr().out
    assert "| sanet |" in text and "| pcn |" in text
    rep = json.loads((tmp_path / "rep.json").read_text())
    assert [m["name"] for m in rep["models"]] == ["sanet", "pcn"]
    assert rep["models"][0]["classes"]["car"]["n_objects"] == 2
    assert (tmp_path / "rep.md").read_text().startswith("# Consistency")
    clips = sys.modules["spotlights.learning.inference"].Completer.clips
    assert set(clips) == {"default"}  # no --clip: the model's own default
    assert (
        main(
            [
                "real",
                "evaluate",
                str(out),
                "--checkpoint",
                fake_learning[0],
                "--out",
                str(prefix),
                "-q",
                "--clip",
                "0.2",
            ]
        )
        == 0
    )
    assert clips[-1] == 0.2
    capsys.readouterr()
    # two checkpoints of one model: named by their run folders (best.pt) or file names
    for run in ("sanet-a", "sanet-b"):
        (tmp_path / run).mkdir()
        (tmp_path / run / "best.pt").write_bytes(b"x")
    assert (
        main(
            [
                "real",
                "evaluate",
                str(out),
                "-c",
                str(tmp_path / "sanet-a" / "best.pt"),
                str(tmp_path / "sanet-b" / "best.pt"),
                fake_learning[1],
                "--out",
                str(prefix),
                "-q",
            ]
        )
        == 0
    )
    assert [m["name"] for m in json.loads((tmp_path / "rep.json").read_text())["models"]] == [
        "sanet (sanet-a)",
        "sanet (sanet-b)",
        "pcn",
    ]
    capsys.readouterr()
    # --names: the rows named as given (reproduce names them after its runs); --heading-margin recorded
    ck = [str(tmp_path / "sanet-a" / "best.pt"), fake_learning[1]]
    argv = ["real", "evaluate", str(out), "-c", *ck, "--out", str(prefix), "-q", "--heading-margin", "0.3"]
    assert main([*argv, "--names", "run-a", "run-b"]) == 0
    rep = json.loads((tmp_path / "rep.json").read_text())
    assert [m["name"] for m in rep["models"]] == ["run-a", "run-b"]
    assert all(m["heading"]["margin"] == 0.3 for m in rep["models"])
    assert "Heading flips (margin 0.3)" in (tmp_path / "rep.md").read_text()
    for bad, msg in ((["--names", "x"], "give 2 distinct names"), (["--names", "x", "x"], "give 2 distinct names")):
        assert main([*argv, *bad]) == 2
        assert msg in capsys.readouterr().err
    assert main([*argv[:-2], "--heading-margin", "1.0"]) == 2
    assert "--heading-margin must be in [0, 1)" in capsys.readouterr().err
    # --reference: the minimal matching distance against a completion dataset's cars
    ref = tiny_dataset_path(tmp_path / "ds")
    assert (
        main(
            [
                "real",
                "evaluate",
                str(out),
                "-c",
                fake_learning[0],
                "--out",
                str(prefix),
                "-q",
                "--reference",
                str(ref),
                "--reference-split",
                "train",
            ]
        )
        == 0
    )
    rep = json.loads((tmp_path / "rep.json").read_text())
    assert rep["models"][0]["average"]["mmd"] > 0 and rep["data"]["mmd_reference"]["file"] == str(ref)
    assert rep["data"]["mmd_reference"]["split"] == "train" and "MMD reference" in (tmp_path / "rep.md").read_text()
    capsys.readouterr()
    assert main(["real", "evaluate", str(out), "-c", fake_learning[0], "--reference", str(tmp_path / "nope.h5")]) == 2
    err = capsys.readouterr().err.strip()
    assert "nope.h5" in err and len(err.splitlines()) == 1

    png = tmp_path / "pic.png"
    assert main(["real", "show", str(out), "--checkpoint", fake_learning[0], "--frame", "f1", "--out", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (
        main(["real", "show", str(out), "--out", str(tmp_path / "nocomp.png"), "--no-completion"]) == 0
    )  # raw + partial only


@pytest.mark.parametrize(
    "argv, message",
    [
        (["real", "extract", "{tmp}/missing", "--format", "kitti", "--out", "{tmp}/o.h5"], "missing: not a folder"),
        (["real", "extract", "{tmp}", "--format", "av2", "--out", "{tmp}/o.h5"], "not an Argoverse 2 folder"),
        (
            ["real", "extract", "{tmp}", "--format", "kitti", "--out", "{tmp}/o.h5", "--boxes", "b.json"],
            "--boxes applies to --format generic only",
        ),
        (["real", "evaluate", "{tmp}/none.h5", "--checkpoint", "x.pt"], "none.h5: file not found"),
        (
            ["real", "evaluate", "{tmp}/none.h5", "--checkpoint", "x.pt", "--reference-split", "test"],
            "--reference-split needs --reference",
        ),
    ],
)
def test_cli_errors_one_line_exit_2(tmp_path, capsys, argv, message):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert message in err
    assert not (tmp_path / "o.h5").exists()


def test_cli_malformed_kitti_label_and_missing_calib(tmp_path, capsys):
    import shutil

    need(LIDAR / "kitti-object")
    root = tmp_path / "training"
    shutil.copytree(LIDAR / "kitti-object" / "training", root)
    for p in root.rglob("*"):
        p.chmod(0o644 if p.is_file() else 0o755)
    (root / "label_2" / "000002.txt").write_text("Car 0 0 0 1 2 3\n")
    out = tmp_path / "o.h5"
    assert main(["real", "extract", str(root), "--format", "kitti", "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("label_2/000002.txt: line 1: expected 15 or 16 fields (type, 14 numbers[, score]), got 7")
    assert not out.exists()
    (root / "calib" / "000001.txt").unlink()
    assert main(["real", "extract", str(root), "--format", "kitti", "--out", str(out), "-q"]) == 2
    assert "calib/000001.txt: calibration file not found" in capsys.readouterr().err


def test_cli_evaluate_resume_reuses_only_matching_models(tmp_path, capsys, fake_learning):
    """--resume copies a model's entry only for the same name, checkpoint bytes and settings; the result
    equals a fresh run of every model; an interrupted run leaves PREFIX.partial.json to resume from."""
    out = tmp_path / "obs.h5"
    assert main(["real", "extract", str(scene(tmp_path)), "--format", "generic", "--out", str(out), "-q"]) == 0
    sanet, pcn = fake_learning
    Completer = sys.modules["spotlights.learning.inference"].Completer

    def evaluate(prefix, *ckpts, extra=()):
        Completer.calls.clear()
        code = main(["real", "evaluate", str(out), "-c", *ckpts, "--out", str(tmp_path / prefix), "-q", *extra])
        return code, list(Completer.calls), tmp_path / f"{prefix}.json"

    code, _, fresh = evaluate("fresh", sanet, pcn)
    assert code == 0
    fresh_models = json.loads(fresh.read_text())["models"]

    assert evaluate("rep", sanet)[0] == 0
    code, calls, rep = evaluate("rep", sanet, pcn, extra=["--resume"])
    assert code == 0 and set(calls) == {"pcn"}  # sanet copied from rep.json, not completed again
    assert json.loads(rep.read_text())["models"] == fresh_models  # the same table as a fresh run
    assert not (tmp_path / "rep.partial.json").exists()

    Path(sanet).write_bytes(b"retrained")  # another checkpoint under the same name: scored again
    code, calls, _ = evaluate("rep", sanet, pcn, extra=["--resume"])
    assert code == 0 and set(calls) == {"sanet"}
    capsys.readouterr()
    code, calls, _ = evaluate("rep", sanet, pcn, extra=["--resume", "--equal-points", "64"])  # other settings
    assert code == 0 and set(calls) == {"sanet", "pcn"}
    assert "no model of" in capsys.readouterr().err

    Completer.interrupt = "pcn"  # Ctrl-C while the second model runs: the first is kept aside
    try:
        code, _, _ = evaluate("cut", sanet, pcn)
    finally:
        Completer.interrupt = None
    assert code == 130 and not (tmp_path / "cut.json").exists()
    kept = json.loads((tmp_path / "cut.partial.json").read_text())
    assert [m["name"] for m in kept["models"]] == ["sanet"]
    code, calls, cut = evaluate("cut", sanet, pcn, extra=["--resume"])
    assert code == 0 and set(calls) == {"pcn"} and not (tmp_path / "cut.partial.json").exists()
    assert [m["name"] for m in json.loads(cut.read_text())["models"]] == ["sanet", "pcn"]

    # a finished table and an interrupted run of other settings side by side: each file's entries are
    # reused only under its own settings (pcn at 512 points is not taken for a run at 64)
    Completer.interrupt = "pcn"
    try:
        assert evaluate("cut", sanet, pcn, extra=["--equal-points", "64"])[0] == 130
    finally:
        Completer.interrupt = None
    code, calls, cut = evaluate("cut", sanet, pcn, extra=["--resume", "--equal-points", "64"])
    assert code == 0 and set(calls) == {"pcn"}
    assert [m["equal_points"]["n_points"] for m in json.loads(cut.read_text())["models"]] == [64, 64]


def test_cli_evaluate_untracked_file(tmp_path, capsys, fake_learning):
    need(LIDAR / "kitti-object")
    out = tmp_path / "k.h5"
    assert (
        main(
            ["real", "extract", str(LIDAR / "kitti-object" / "training"), "--format", "kitti", "--out", str(out), "-q"]
        )
        == 0
    )
    capsys.readouterr()
    assert main(["real", "evaluate", str(out), "--checkpoint", fake_learning[0]]) == 2
    assert "no object is observed in two or more frames" in capsys.readouterr().err


def test_cli_subprocess_missing_calib(tmp_path):
    """The real process: exit code 2, one error line naming the file, no traceback, no output file."""
    import shutil

    root = tmp_path / "training"
    shutil.copytree(need(LIDAR / "kitti-object" / "training"), root)
    for p in root.rglob("*"):
        p.chmod(0o644 if p.is_file() else 0o755)
    (root / "calib" / "000000.txt").unlink()
    proc = run_cli("real", "extract", root, "--format", "kitti", "--out", tmp_path / "o.h5")
    assert_user_error(proc, "calib/000000.txt: calibration file not found")
    assert not (tmp_path / "o.h5").exists()
