"""Shared test helpers: where the shared data is, analytic shapes, CLI runner."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("SPOTLIGHTS_SHARED", REPO.parent / "shared")).resolve()
DATA = SHARED / "data"
CARS = DATA / "meshes" / "apolloscape-cars"
KENNEY = DATA / "meshes" / "kenney-vehicles"
CATEGORIES = DATA / "meshes" / "categories"
LIDAR = DATA / "lidar"


def src_pythonpath() -> str:
    """PYTHONPATH for a child Python: the checkout's src/ first, then the parent's own PYTHONPATH (where a machine
    has its packages, e.g. wheels installed with --target on a GPU machine; replacing it lost them)."""
    return os.pathsep.join(p for p in (str(REPO / "src"), os.environ.get("PYTHONPATH", "")) if p)


def has_module(name: str) -> bool:
    """Whether ``name`` can be imported here (an optional extra such as plotly)."""
    return importlib.util.find_spec(name) is not None


def load_script(relpath: str):
    """Import a script of the repository that is not part of the package (``scripts/``, ``benchmarks/``) as a module."""
    path = REPO / relpath
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def need(path: Path) -> Path:
    """Skip the calling test, with the reason, when a shared-data path is absent."""
    if not path.exists():
        pytest.skip(f"shared data not found at {path} (set SPOTLIGHTS_SHARED to the folder holding data/)")
    return path


def run_cli(*args: str, cwd: Path | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    """Run ``spotlights ARGS`` in this process through ``spotlights.cli.main`` (no interpreter start-up).

    The result looks like :func:`run_cli_subprocess`'s: ``returncode`` (main's return value; a
    ``SystemExit``'s code; 1 for an uncaught exception, whose traceback is appended to ``stderr``
    as the interpreter would print it), ``stdout`` and ``stderr`` as text. The working folder,
    ``os.environ``, the warning filters (reset to a fresh interpreter's), the SIGINT/SIGTERM
    handlers and torch's thread count are restored afterwards. Child processes the command starts
    write to this process's real stdout/stderr (not captured). ``timeout`` is accepted for
    compatibility; pytest-timeout bounds an in-process run. Use :func:`run_cli_subprocess` for
    what needs a real process: signals, the interpreter's exit code, start-up imports.
    """
    import contextlib
    import io
    import signal
    import threading
    import traceback
    import warnings

    import torch

    from spotlights.cli import main

    argv = [str(a) for a in args]
    out, err = io.StringIO(), io.StringIO()

    def show(message, category, filename, lineno, file=None, line=None):
        err.write(warnings.formatwarning(message, category, filename, lineno, line))

    old_cwd, old_env, old_threads = os.getcwd(), dict(os.environ), torch.get_num_threads()
    main_thread = threading.current_thread() is threading.main_thread()  # only it may set handlers
    old_handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)} if main_thread else {}
    try:
        if cwd is not None:
            os.chdir(cwd)
        os.environ.setdefault("MPLBACKEND", "Agg")
        with warnings.catch_warnings(), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            warnings.resetwarnings()  # a fresh interpreter's filters (pytest's are stricter)
            warnings.filterwarnings("ignore", category=DeprecationWarning)
            warnings.filterwarnings("ignore", category=PendingDeprecationWarning)
            warnings.filterwarnings("ignore", category=ImportWarning)
            warnings.filterwarnings("ignore", category=ResourceWarning)
            warnings.showwarning = show  # printed to the captured stderr, as a process would
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse (--help, usage errors)
                if exc.code is None or isinstance(exc.code, int):
                    code = exc.code or 0
                else:
                    err.write(f"{exc.code}\n")
                    code = 1
            except Exception:  # what the interpreter would do with an uncaught exception
                err.write(traceback.format_exc())
                code = 1
    finally:
        os.chdir(old_cwd)
        os.environ.clear()
        os.environ.update(old_env)
        torch.set_num_threads(old_threads)
        for sig, handler in old_handlers.items():
            signal.signal(sig, handler)
    return subprocess.CompletedProcess(["spotlights", *argv], int(code), out.getvalue(), err.getvalue())


def run_cli_subprocess(*args: str, cwd: Path | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    """Run ``python -m spotlights ARGS`` in a subprocess (the package from this checkout): for tests
    of what needs a real process (signals, the interpreter's exit code, start-up imports)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO / "src") + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("MPLBACKEND", "Agg")
    return subprocess.run(
        [sys.executable, "-m", "spotlights", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=timeout,
    )


def assert_user_error(proc: subprocess.CompletedProcess, *fragments: str) -> None:
    """A one-line error with exit code 2 and no traceback, containing every fragment."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    assert "Traceback" not in proc.stderr, proc.stderr
    err_lines = [ln for ln in proc.stderr.strip().splitlines() if "error" in ln]
    assert len(err_lines) == 1, proc.stderr
    for frag in fragments:
        assert frag in err_lines[0], (frag, proc.stderr)


def write_box_scan(root: Path) -> dict:
    """A scan (.npy, float32, metres) of 600 points in a car-sized box at x = 10 m and its box file (.json), written
    into ``root``: {"root", "scan", "box"} paths (the hostile-input tests' shared input)."""
    import json

    rng = np.random.default_rng(0)
    pts = rng.uniform([-2.0, -0.9, 0.0], [2.0, 0.9, 1.5], size=(600, 3)) + [10.0, 0.0, 0.0]
    np.save(root / "scan.npy", pts.astype(np.float32))
    (root / "box.json").write_text(json.dumps({"center": [10.0, 0.0, 0.75], "size": [4.0, 1.8, 1.5], "yaw": 0.0}))
    return {"root": root, "scan": root / "scan.npy", "box": root / "box.json"}


def sphere_ray_depths(origins: np.ndarray, directions: np.ndarray, center, radius: float):
    """Closed-form first hit of rays with a sphere: (t (K,), discriminant (K,)); t = inf on a miss.

    t solves |o + t d - c|^2 = r^2 with the smallest t >= 0 (origins outside the sphere).
    """
    oc = origins - np.asarray(center, dtype=np.float64)
    b = np.einsum("ij,ij->i", oc, directions)
    c = np.einsum("ij,ij->i", oc, oc) - radius**2
    disc = b * b - c
    t = np.where(disc >= 0, -b - np.sqrt(np.clip(disc, 0, None)), np.inf)
    t = np.where(t >= 0, t, np.inf)
    return t, disc


def brute_force_first_hit(mesh, o, d):
    """Naive Moller-Trumbore reference: every ray (o, d: (K, 3) float64) against every triangle
    of ``mesh``, both windings. Returns (K,) float64 first-hit distances (inf on a miss) and
    (K,) the smallest barycentric margin of that hit (how close it is to a triangle edge)."""
    tri = mesh.vertices[mesh.faces]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d[:, None], e2[None])
    det = np.einsum("fc,rfc->rf", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1 / np.where(ok, det, 1), 0)
    s = o[:, None] - tri[None, :, 0]
    u = np.einsum("rfc,rfc->rf", s, p) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("rc,rfc->rf", d, q) * inv
    tt = np.einsum("fc,rfc->rf", e2, q) * inv
    margin = np.minimum(np.minimum(u, v), 1 - u - v)
    valid = ok & (margin >= 0) & (tt > 0)
    tt = np.where(valid, tt, np.inf)
    first = tt.argmin(axis=1)
    rows = np.arange(len(o))
    return tt[rows, first], np.abs(margin[rows, first])


def slab_interval(origins, directions, lo, hi):
    """Independent ray/box slab test (numpy, no Embree): rays ``origins + t * directions``
    ((K, 3) or broadcastable, float64) against the axis-aligned box [lo, hi]. Returns
    (t_enter, t_exit), each (K,) float64; the ray meets the box iff t_enter <= t_exit and
    t_exit >= 0 (a ray parallel to a slab plane is bounded only by the others)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / directions
        t1, t2 = (lo - origins) * inv, (hi - origins) * inv
    t1 = np.where(np.isnan(t1), -np.inf, t1)
    t2 = np.where(np.isnan(t2), np.inf, t2)
    return np.minimum(t1, t2).max(axis=1), np.maximum(t1, t2).min(axis=1)


def wait_until_command_started(pid: int, limit_s: float = 300.0) -> None:
    """Return once the ``python -m spotlights`` process ``pid`` runs the package's code: its main thread holds Ctrl-C
    (SIGINT blocked: the package's first lines do that for the command), or the process ended, or (not Linux: no /proc)
    at once. A Ctrl-C test counts its delays from there: Python's own start-up, which no code of the package can
    guard and which takes seconds on a loaded machine, is not what it tests. ``limit_s``: a generous bound."""
    import signal
    import time

    status = Path(f"/proc/{pid}/status")
    if not status.exists():
        return
    deadline = time.monotonic() + limit_s
    bit = 1 << (signal.SIGINT - 1)
    while time.monotonic() < deadline:
        try:
            text = status.read_text()
        except OSError:  # ended
            return
        blocked = next((line.split()[1] for line in text.splitlines() if line.startswith("SigBlk:")), "0")
        if int(blocked, 16) & bit or "State:\tZ" in text:
            return
        time.sleep(0.0005)


#: What the suite keeps of a failed run's temporary folders (pytest keeps a failed test's ``tmp_path``, and every
#: module fixture's folder of a run with a failure): no file above KEEP_FILE_BYTES, and KEEP_TOTAL_BYTES in all, the
#: largest files removed first (datasets, checkpoints; a failed run left 718 MB). Logs, configs and small outputs,
#: what a failing test is read by, stay; TRIMMED.txt in the folder lists what went.
KEEP_FILE_BYTES = 8 << 20
KEEP_TOTAL_BYTES = 64 << 20


def trim_kept_files(root: Path, file_bytes: int = KEEP_FILE_BYTES, total_bytes: int = KEEP_TOTAL_BYTES) -> list:
    """Remove files under ``root`` (links are not followed) until none is larger than ``file_bytes`` and all
    together hold at most ``total_bytes``, largest first; list them in ``root/TRIMMED.txt``. Returns the
    ``(path, size)`` pairs removed."""
    root = Path(root)
    if not root.is_dir():
        return []
    files = []
    for dirpath, _, names in os.walk(root):
        for name in names:
            p = Path(dirpath) / name
            try:
                if not p.is_symlink():
                    files.append((p.stat().st_size, str(p)))
            except OSError:
                continue
    files.sort(reverse=True)
    total = sum(size for size, _ in files)
    removed = []
    for size, path in files:
        if size <= file_bytes and total <= total_bytes:
            break
        try:
            os.unlink(path)
        except OSError:
            continue
        total -= size
        removed.append((path, size))
    if removed:
        lines = [f"{size} {os.path.relpath(path, root)}" for path, size in removed]
        (root / "TRIMMED.txt").write_text(
            "removed after the run to keep a failed run's folders small (bytes, file):\n" + "\n".join(lines) + "\n"
        )
    return removed
