"""Time the test suite at two (or more) commits side by side, on this machine, in one run.

    python3 benchmarks/suite_time.py b26f0e3 HEAD            # a comparison of two commits
    python3 benchmarks/suite_time.py b26f0e3 HEAD --rounds 2 --json out.json
    python3 benchmarks/suite_time.py HEAD --pytest-args "-m 'not slow'"

Each commit is exported (``git archive``, committed files only) into its own folder under a temporary
directory, beside a link ``shared`` to this checkout's ``../shared`` (the tests and the README's
commands read ``../shared/data``), and its suite runs there with the README's test command
(the ``pytest`` line of that commit's Makefile ``test`` target, e.g. ``python -m pytest -q``, plus
``-p no:cacheprovider``) and ``PYTHONPATH=<export>/src``, so every commit runs its own code, its own
test command and its own pytest configuration with this Python and its installed packages (which must
hold what the newest commit's test extra needs, e.g. pytest-xdist). Rounds interleave the commits (A B A B ...), so a change of machine load
hits both alike; the load average before and after each run is printed beside its time: compare
only runs made at the same load (an idle machine for numbers to report).

Prints, per run: wall seconds, pytest's own summary line (tests passed, skipped, its time) and the
load; then the best and median wall time per commit and the ratio to the first commit.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def export(commit: str, dest: Path) -> str:
    """Write the files of ``commit`` into ``dest/repo`` and link ``dest/shared``; returns the full hash."""
    full = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--verify", f"{commit}^{{commit}}"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    repo = dest / "repo"
    repo.mkdir(parents=True)
    archive = dest / "src.tar"
    subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", "-o", str(archive), full], check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(repo, filter="data")
    archive.unlink()
    shared = Path(os.environ.get("SPOTLIGHTS_SHARED", ROOT.parent / "shared")).resolve()
    if shared.exists():
        (dest / "shared").symlink_to(shared, target_is_directory=True)
    return full


def test_command(repo: Path) -> list[str]:
    """The commit's own test command: the ``pytest`` line of its Makefile's ``test`` target (what the
    README's ``make test`` runs, after its install step), with this Python for ``$(PYTHON)``."""
    lines = (repo / "Makefile").read_text().splitlines() if (repo / "Makefile").exists() else []
    start = next((i for i, ln in enumerate(lines) if ln.startswith("test:")), None)
    for ln in lines[start + 1 :] if start is not None else []:
        if not ln.startswith("\t"):
            break
        if "-m pytest" in ln:
            return [sys.executable if w == "$(PYTHON)" else w for w in shlex.split(ln.strip())]
    return [sys.executable, "-m", "pytest", "-q"]


def run_suite(repo: Path, pytest_args: list[str], timeout: float) -> dict:
    """One run of the suite in ``repo``: wall seconds, pytest's summary line, exit code, load averages."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(repo / "src"), env.get("PYTHONPATH")) if p)
    env["SPOTLIGHTS_SHARED"] = str((repo.parent / "shared").resolve())
    env.pop("PYTEST_ADDOPTS", None)
    cmd = [*test_command(repo), "-p", "no:cacheprovider", *pytest_args]
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    tail = [ln for ln in r.stdout.splitlines() if re.search(r"\d+ (passed|failed)", ln)]
    return {
        "command": shlex.join(cmd[1:]),
        "wall_s": round(wall, 1),
        "summary": tail[-1].strip("= ") if tail else (r.stdout + r.stderr)[-300:],
        "returncode": r.returncode,
        "load_before": round(load0, 2),
        "load_after": round(os.getloadavg()[0], 2),
        "cpus": os.cpu_count(),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("commits", nargs="+", help="commits to compare (the first is the reference)")
    ap.add_argument("--rounds", type=int, default=1, help="runs of each commit, interleaved (default 1)")
    ap.add_argument("--pytest-args", default="", help="extra pytest arguments, one shell-quoted string")
    ap.add_argument("--timeout", type=float, default=3600, help="seconds per run before it is stopped")
    ap.add_argument("--json", type=Path, default=None, help="also write every run here")
    ap.add_argument("--keep", action="store_true", help="keep the exported folders (printed)")
    args = ap.parse_args(argv)

    tmp = Path(tempfile.mkdtemp(prefix="suite-time-"))
    runs: dict[str, list[dict]] = {c: [] for c in args.commits}
    try:
        repos = {}
        for i, c in enumerate(args.commits):
            full = export(c, tmp / f"c{i}")
            repos[c] = tmp / f"c{i}" / "repo"
            print(
                f"{c}: {full[:12]} exported to {repos[c]}; runs: {shlex.join(test_command(repos[c])[1:])}", flush=True
            )
        for rnd in range(args.rounds):
            for c in args.commits:
                res = run_suite(repos[c], shlex.split(args.pytest_args), args.timeout)
                runs[c].append(res)
                print(
                    f"round {rnd + 1} {c:>12}: {res['wall_s']:7.1f} s wall  [{res['summary']}]  "
                    f"load {res['load_before']} -> {res['load_after']} on {res['cpus']} CPUs"
                    + ("" if res["returncode"] == 0 else f"  EXIT {res['returncode']}"),
                    flush=True,
                )
    finally:
        if args.keep:
            print(f"exports kept in {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    ref = min(r["wall_s"] for r in runs[args.commits[0]])
    for c in args.commits:
        walls = [r["wall_s"] for r in runs[c]]
        best = min(walls)
        print(
            f"{c:>12}: best {best:.1f} s, median {statistics.median(walls):.1f} s over {len(walls)} run(s); "
            f"{best / ref:.2f} x the best of {args.commits[0]} ({(1 - best / ref) * 100:.0f}% less time)"
        )
    if args.json:
        args.json.write_text(json.dumps(runs, indent=2) + "\n")
    return 0 if all(r["returncode"] == 0 for rs in runs.values() for r in rs) else 1


if __name__ == "__main__":
    sys.exit(main())
