"""The Ray cases of ``test_distributed.py``, run in a child process with one local Ray instance.

A Ray driver lives in the process that calls ``ray.init``; when Ray's own processes fail (under heavy load, or a
port race with another instance), Ray may end that process. Run inside a pytest-xdist worker, that took the worker
down ("node down: Not properly terminated") and stalled the suite. Here the driver is a child process: the cases
run in it, one after another, and it writes ``{case: "ok" | "error text"}`` to a JSON file; the tests read it, and
a dead child is one failing test run with its output, not a lost worker.

    python tests/ray_cases.py MESHES LOCAL_REF WORKDIR RESULTS_JSON
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import sys
import traceback
from pathlib import Path

import numpy as np

CASES = ("byte_identical", "metrics", "failing_mesh", "retry_exception", "retry_crash")
MESHES = {"suv/a.ply": (4.8, 2.0, 1.8), "sedan/b.ply": (4.5, 1.8, 1.45), "sedan/c.ply": (4.1, 1.75, 1.5)}


def cfg(root, **kw):
    """The BuildConfig of the distributed tests' small build of the meshes in ``root``."""
    from spotlights.data.synthetic import BuildConfig

    base = dict(
        meshes=str(root),
        views=12,
        split="1/1/1",
        seed=4,
        gt_dense=1024,
        gt_points=512,
        default_rig="8x16@60",
        extra_rigs=["box-8x8-ellipsoid-s1"],
    )
    base.update(kw)
    return BuildConfig(**base)


def build_argv(root, out) -> list[str]:
    """The ``spotlights dataset build`` arguments of the build :func:`cfg` describes, writing ``out``."""
    c = cfg(root)
    argv = ["dataset", "build", "--meshes", str(root), "--out", str(out), "--views", str(c.views)]
    argv += ["--split", c.split, "--seed", str(c.seed), "--gt-dense", str(c.gt_dense), "--gt-points", str(c.gt_points)]
    argv += ["--default-rig", c.default_rig]
    for rig in c.extra_rigs:
        argv += ["--rig", rig]
    return argv


def sha(p) -> str:
    return hashlib.sha256(Path(p).read_bytes()).hexdigest()


def _quiet(m):
    return None


def byte_identical(ray, meshes: Path, local_ref: Path, work: Path) -> None:
    """A Ray build, a sharded Ray build merged, and add-rig on Ray give the local build's bytes."""
    from spotlights.cli import main
    from spotlights.data.synthetic import add_rig, build_dataset
    from spotlights.data.synthetic.consolidate import merge_shards

    one = work / "ray1.h5"
    build_dataset(cfg(meshes), one, backend="ray", workers=1, block=4, progress=False, log=_quiet)
    assert sha(one) == sha(local_ref), "a Ray build differs from the local build"
    index = work / "ray.json"
    assert main(build_argv(meshes, index) + ["--backend", "ray", "--shard-size", "24", "-q"]) == 0
    assert sha(merge_shards(index, work / "m.h5", progress=False)["out"]) == sha(local_ref), "merged Ray shards differ"
    a, b = work / "a.h5", work / "b.h5"
    a.write_bytes(local_ref.read_bytes())
    b.write_bytes(local_ref.read_bytes())
    add_rig(a, "4x4@30", workers=1, progress=False)
    add_rig(b, "4x4@30", backend="ray", progress=False)
    assert sha(a) == sha(b), "add-rig on Ray differs from add-rig locally"


def metrics(ray, *_) -> None:
    """RayMetrics gives evaluate_completions' arrays exactly."""
    from spotlights.learning.ray_metrics import RayMetrics
    from spotlights.metrics.completion import evaluate_completions

    rng = np.random.default_rng(0)
    gt = [rng.normal(size=(500, 3)) for _ in range(3)]
    models = np.array([2, 0, 0, 1, 2, 2, 0])
    preds = [rng.normal(size=(int(rng.integers(0, 80)), 3)) for _ in models]
    preds[3] = np.zeros((0, 3))
    want = evaluate_completions(preds, models, gt, 0.3, True)
    got = RayMetrics(ray, chunk=2)(preds, models, gt, 0.3, True)
    assert want.keys() == got.keys()
    for k in want:
        np.testing.assert_array_equal(want[k], got[k])


def failing_mesh(ray, meshes: Path, local_ref: Path, work: Path) -> None:
    """A mesh that never gives enough returns stops a Ray build with one line naming it; nothing left behind."""
    import trimesh

    from spotlights.cli import main

    bad = work / "bad"
    for p in sorted(meshes.rglob("*.ply")):
        rel = p.relative_to(meshes)
        (bad / rel).parent.mkdir(parents=True, exist_ok=True)
        (bad / rel).write_bytes(p.read_bytes())
    trimesh.creation.box(extents=(0.01, 0.01, 0.01)).export(bad / "sedan" / "tiny.ply")  # loads, never 50 returns
    out = work / "bad.h5"
    err_buf = io.StringIO()
    with contextlib.redirect_stderr(err_buf), contextlib.redirect_stdout(io.StringIO()):
        rc = main(["dataset", "build", "--meshes", str(bad), "--out", str(out), "--views", "4", "--split", "2/1/1",
                   "--gt-dense", "256", "--backend", "ray", "-q"])  # fmt: skip
    err = err_buf.getvalue().strip()
    assert rc == 2 and err.count("\n") == 0 and "Traceback" not in err, err
    assert "tiny.ply" in err and "no pose" in err, err
    assert not out.exists()
    # the input error crossed from the Ray task as itself: the build removed its parts
    assert not (work / "bad.h5.parts").exists()


def _flaky(counter: str, crash: bool):
    """Fails on every attempt (an exception, or a dead worker process), counting attempts in a file."""
    with open(counter, "a") as fh:
        fh.write("x")
    if crash:
        os._exit(1)
    raise RuntimeError("disk on fire")


def _retried(ray, work: Path, crash: bool) -> None:
    """A task that fails every attempt is tried 1 + retries times, then one line (exit code 1)."""
    from spotlights.data.synthetic.ray_backend import RayBuild
    from spotlights.errors import SpotlightsError

    runner = RayBuild(ray, retries=1)
    task = ray.remote(num_cpus=1, max_retries=1, retry_exceptions=True)(_flaky)
    counter = work / f"attempts-{int(crash)}"
    try:
        runner.stream(lambda i: task.remote(str(counter), crash), [0], lambda i: "cars/x.ply: views 0-9 of model x",
                      lambda i, r: None)  # fmt: skip
    except SpotlightsError as exc:
        msg = str(exc)
        assert exc.exit_code == 1, exc.exit_code  # failed every attempt: not the input's fault (ProcessFailure)
        assert "\n" not in msg and msg.startswith(
            "cars/x.ply: views 0-9 of model x failed on the Ray cluster after 2 attempts"
        ), msg
        assert ("disk on fire" in msg) if not crash else ("Worker" in msg or "died" in msg or "crash" in msg.lower()), (
            msg
        )
        assert counter.read_text() == "xx", counter.read_text()  # 1 + 1 retry, no more
        return
    raise AssertionError("the failing task did not stop the run")


def retry_exception(ray, meshes, local_ref, work) -> None:
    _retried(ray, work, crash=False)


def retry_crash(ray, meshes, local_ref, work) -> None:
    _retried(ray, work, crash=True)


def run(meshes: Path, local_ref: Path, work: Path, results: Path) -> None:
    """Start one local Ray instance (2 CPUs), run every case in :data:`CASES` in its own folder under ``work``,
    write the results JSON, shut Ray down."""
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="ERROR",
             object_store_memory=256 << 20)  # fmt: skip
    out = {}
    try:
        for name in CASES:
            folder = work / name
            folder.mkdir(parents=True, exist_ok=True)
            try:
                globals()[name](ray, meshes, local_ref, folder)
                out[name] = "ok"
            except BaseException:  # noqa: BLE001 - every failure is reported to the test that reads it
                out[name] = traceback.format_exc(limit=6)
            tmp = results.with_suffix(".tmp")
            tmp.write_text(json.dumps(out))
            tmp.replace(results)
    finally:
        ray.shutdown()


if __name__ == "__main__":
    run(*(Path(a) for a in sys.argv[1:5]))
