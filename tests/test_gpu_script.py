"""The GPU recipe (scripts/gpu_train.sh) at a tiny scale on the CPU: build, probe, plan, train, outputs."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from types import SimpleNamespace

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("embreex")

from helpers import REPO, assert_user_error, load_script  # noqa: E402
from learning_fixtures import TINY_MODEL_ARGS, run_gpu_script, write_category_shapes  # noqa: E402


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    return write_category_shapes(tmp_path_factory.mktemp("gpu-meshes"))


@pytest.mark.slow  # the recipe end to end: a dataset build and a training (seconds)
def test_tiny_cpu_run_writes_a_loadable_checkpoint_log_and_config(tmp_path, meshes):
    from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint

    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(json.dumps({"model": {"name": "snowflakenet", "args": TINY_MODEL_ARGS["snowflakenet"]}}))
    out = tmp_path / "out"
    # a budget of 60 minutes: --steps 20 are all done however slow the machine (with 1 minute, a loaded machine
    # stopped after 10: the run stops at its budget); the plan is then the steps asked for, not a timing
    proc = run_gpu_script(
        tmp_path, cfg, 60, "--cpu", "--meshes", meshes, "--split", "3/3/3", "--views", 4, "--steps", 20,
        "--intervals", 2, "--batch-size", 4, "--probe-steps", 2, "--val-views", 2, "--workers", 1,
        "--out", out, "--work", tmp_path / "work",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr + proc.stdout
    assert {"best.pt", "last.pt", "log.csv", "config.yaml", "gpu_train.log", "plan.json"} <= {
        p.name for p in out.iterdir()
    }
    plan = json.loads((out / "plan.json").read_text())
    assert plan["device"] == "cpu" and plan["planned_steps"] == plan["steps_done"] == 20
    assert plan["dataset"]["samples"] == 9 * 4 and plan["step_seconds"] > 0
    rows = list(csv.DictReader((out / "log.csv").open()))
    assert [int(r["epoch"]) for r in rows] == [1, 2]
    ck = load_checkpoint(out / "best.pt", expect_model="snowflakenet")
    assert ck["config"]["train"]["steps_per_epoch"] == 10 and ck["config"]["train"]["precision"] == "bf16"
    assert ck["global_step"] in (10, 20)
    assert load_checkpoint(out / "last.pt")["global_step"] == 20
    model = model_from_checkpoint(ck)
    clouds = model.complete(torch.rand(1, 40, 3) - 0.5)
    assert clouds[0].shape == (16 * 2 * 4, 3)
    assert "step time:" in (out / "gpu_train.log").read_text()


def test_bad_inputs_exit_2_with_one_line(tmp_path, meshes, capsys, monkeypatch):
    proc = run_gpu_script(tmp_path, "no-such-model", 1, "--cpu", "--out", tmp_path / "o")
    assert_user_error(proc, "unknown model 'no-such-model'")
    gpu = load_script("scripts/gpu_train.py")  # the same checks in-process (no torch is imported before them)
    monkeypatch.delenv("OUT", raising=False)
    no_gpu = not torch.cuda.is_available()
    for argv, message in (
        (
            ["pcn", "1", "--cpu", "--meshes", str(tmp_path / "nothing"), "--out", str(tmp_path / "o")],
            "no such mesh folder",
        ),
        (["pcn", "0", "--cpu", "--meshes", str(meshes), "--out", str(tmp_path / "o")], "MINUTES must be > 0"),
        ([str(tmp_path / "missing.yaml"), "--out", str(tmp_path / "o")], "no such config file"),
        (["pcn", "1", "--cpu"], "no output folder"),
        *([(["pcn", "1", "--meshes", str(meshes), "--out", str(tmp_path / "o")], "no CUDA device")] * no_gpu),
    ):
        assert gpu.main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0] and err[0].startswith("gpu_train: error:"), err
    assert not (tmp_path / "o").exists() and not (tmp_path / "o-work").exists()  # refused before any work


def test_plan_fits_the_time_left_and_caps_at_the_paper_scale():
    gpu = load_script("scripts/gpu_train.py")
    args = SimpleNamespace(steps=None, overhead=1.25, intervals=10)
    # 300 s at 0.02 s x 1.25 per step: 12,000 steps in 10 intervals of 1,200
    assert gpu.plan_steps(args, 0.02, 300.0) == (10, 1200)
    assert gpu.plan_steps(args, 1e-5, 3600.0) == (10, 16_000)  # capped at 160,000 steps
    assert gpu.plan_steps(args, 1.0, 3.0) == (2, 1)  # 2 steps fit: 2 intervals of one step
    assert gpu.plan_steps(SimpleNamespace(steps=25, overhead=1.0, intervals=10), 9.0, 0.0) == (10, 3)


def test_fit_intervals_shortens_to_what_the_measured_interval_leaves_room_for():
    gpu = load_script("scripts/gpu_train.py")
    # 10 planned; the first took 27 s; 190 s left: 190 // (1.05 * 27) = 6 more -> 7 in all
    assert gpu.fit_intervals(10, 1, 27.0, 190.0) == 7
    assert gpu.fit_intervals(10, 1, 10.0, 1e6) == 10  # never lengthened
    assert gpu.fit_intervals(10, 1, 30.0, -5.0) == 1  # nothing fits: the done one
    assert gpu.fit_intervals(10, 1, 20.0, 21.0) == 2  # exactly one more at 1.05 x 20 s


@pytest.mark.slow  # a tiny build and 10-15 steps on the CPU (seconds)
@pytest.mark.parametrize(
    "planned, fits, kept",
    [
        (3, {1: 2}, 2),  # the first interval shows 2 fit
        (4, {1: 4, 2: 3}, 3),  # all 4 seem to fit after the first; after the second, 3
    ],
)
def test_replanned_run_ends_its_cosine_schedule(tmp_path, meshes, monkeypatch, planned, fits, kept):
    """An interval shows fewer intervals fit than planned: the run trains those and its learning rate still ends
    at the fair schedule's floor (5e-5), instead of stopping midway down the cosine."""
    gpu = load_script("scripts/gpu_train.py")
    monkeypatch.setattr(gpu, "plan_steps", lambda args, step_s, left_s: (planned, 5))
    monkeypatch.setattr(gpu, "fit_intervals", lambda intervals, done, took, left: fits[done])
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(json.dumps({"model": {"name": "snowflakenet", "args": TINY_MODEL_ARGS["snowflakenet"]}}))
    out = tmp_path / "out"
    argv = [
        str(cfg), "1", "--cpu", "--meshes", str(meshes), "--split", "3/3/3", "--views", "2", "--batch-size", "4",
        "--probe-steps", "1", "--val-views", "1", "--workers", "1", "--out", str(out), "--work", str(tmp_path / "w"),
    ]  # fmt: skip
    assert gpu.main(argv) == 0
    from spotlights.learning.checkpoint import load_checkpoint

    plan = json.loads((out / "plan.json").read_text())
    assert plan["replanned_intervals"] == kept and plan["intervals_done"] == kept and plan["steps_done"] == 5 * kept
    assert plan["first_interval_seconds"] > 0
    last = load_checkpoint(out / "last.pt")
    assert last["global_step"] == 5 * kept and last["config"]["train"]["epochs"] == kept
    lr = last["optimizer_state"]["param_groups"][0]["lr"]
    assert lr == pytest.approx(5e-5, rel=1e-6), lr  # the cosine ended (the planned intervals kept: it would not)
    assert f"re-plan after interval {kept - 1}: " in (out / "gpu_train.log").read_text()


@pytest.mark.slow  # a pytest run inside the suite (seconds)
def test_gpu_check_runs_pytest_and_writes_its_log_and_junit(tmp_path):
    """scripts/gpu_check.sh (the suite where CUDA is) on a tiny selection here: pytest's status, log and XML."""
    env = dict(os.environ, OUT=str(tmp_path / "out"), GPU_BUNDLE=str(tmp_path / "no-wheels"), PYTHON=sys.executable)
    script = REPO / "scripts" / "gpu_check.sh"
    proc = subprocess.run(
        ["bash", str(script), "tests/test_device.py", "-p", "no:randomly"],
        capture_output=True, text=True, env=env, timeout=240, cwd=REPO,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    log = (tmp_path / "out" / "gpu_check.log").read_text()
    assert proc.stdout.startswith("torch ") and log.startswith("torch ") and "passed" in log
    assert "<testsuite" in (tmp_path / "out" / "gpu_check.xml").read_text()
    bad = subprocess.run(
        ["bash", str(script), "tests/no_such_test.py"], capture_output=True, text=True, env=env, timeout=240, cwd=REPO
    )
    assert bad.returncode == 4  # pytest's own status passes through (4: no such test file), not the script's 2


@pytest.mark.slow  # two tiny builds (seconds)
def test_reuse_data_keeps_a_dataset_built_the_same_way(tmp_path, meshes):
    """--reuse-data: a second model in the same call keeps WORK/cars.h5 when it was built from the same meshes,
    views, split and seed with the rig it needs; anything else is built again, and the log says why."""
    gpu = load_script("scripts/gpu_train.py")
    lines: list[str] = []
    args = SimpleNamespace(views=2, split="3/3/3", seed=0, workers=1, reuse_data=True)
    out = tmp_path / "cars.h5"

    def said(start: int, text: str) -> bool:
        return any(text in ln for ln in lines[start:])

    first = gpu.build_data(meshes, out, args, "box-4x8-ellipsoid-s1", lines.append)
    assert first["reused"] is False and said(0, "built again: none there yet")
    n = len(lines)
    again = gpu.build_data(meshes, out, args, None, lines.append)  # a point model: any rig will do
    assert again["reused"] is True and again["samples"] == first["samples"] == 9 * 2 and said(n, " reused (")
    n = len(lines)
    more = SimpleNamespace(**{**vars(args), "views": 3})
    other = gpu.build_data(meshes, out, more, None, lines.append)
    assert other["reused"] is False and other["samples"] == 9 * 3 and said(n, "its views is 2, not 3")
    n = len(lines)
    rig = gpu.build_data(meshes, out, more, "box-8x8-ellipsoid-s1", lines.append)
    assert rig["reused"] is False and said(n, "has no rig box-8x8-ellipsoid-s1")
