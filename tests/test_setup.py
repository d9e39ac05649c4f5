"""The README's two set-up commands: which Python `make demo` / `make test` install into, and what they install.

The rule, on every system: `PYTHON=...` if given, else the active virtual/conda environment's
python3, else a project environment .venv (created on first use). The full path (a fresh clone,
`make demo` creating .venv and installing into it) needs minutes: scripts/check_setup.sh runs it
(docs/install.md). Here: the decision, by `make -n` (a dry run, nothing installed) in a bare copy
of the Makefile, and the extras CI exercises.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest

from helpers import REPO

pytestmark = pytest.mark.timeout(60)

SYSTEM = "/opt/some/python3"  # the interpreter .venv is made from (never run by a dry run)


def _checkout(tmp_path: Path) -> Path:
    """A bare copy of the Makefile under ``tmp_path``: the checkout's state (an existing ``.venv``)
    cannot change what make decides."""
    work = tmp_path / "checkout"
    work.mkdir(exist_ok=True)
    shutil.copy2(REPO / "Makefile", work / "Makefile")
    return work


def _make(work: Path, env_extra: dict, *args: str) -> list[str]:
    """The output lines of ``make -s ARGS`` in ``work`` with ``env_extra`` and no environment active."""
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "CONDA_PREFIX", "PYTHON", "MAKEFLAGS")}
    env.update({"SYSTEM_PYTHON": SYSTEM, **env_extra})
    proc = subprocess.run(["make", "-s", *args], cwd=work, env=env, capture_output=True, text=True, timeout=30)
    assert proc.returncode == 0, proc.stderr
    return [line.strip() for line in proc.stdout.splitlines() if line.strip()]


def _dry_run(work: Path, env_extra: dict, *args: str) -> list[str]:
    """The commands `make -n install` would run (nothing is executed)."""
    return _make(work, env_extra, "-n", "install", *args)


needs_make = pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")


def _pip_lines(cmds: list[str]) -> list[str]:
    return [c for c in cmds if " -m pip install " in c]


@needs_make
def test_without_an_environment_make_creates_and_uses_a_project_venv(tmp_path):
    """Any python3 (Debian's, pyenv's, a container's): .venv is made from it, everything goes into .venv."""
    work = _checkout(tmp_path)
    cmds = _dry_run(work, {})
    assert any(f"{SYSTEM} -m venv .venv" in c for c in cmds), cmds
    pips = _pip_lines(cmds)
    assert [p.split()[0] for p in pips] == [".venv/bin/python", ".venv/bin/python"], pips
    assert pips[0].endswith("torch==2.13.0") and pips[1].endswith('-e ".[all,test]"'), pips  # torch first, alone
    assert _make(work, {}, "where") == [f"PYTHON=.venv/bin/python (the project environment .venv; made from {SYSTEM})"]
    # a later command reuses the environment: nothing is created again, the same interpreter is used
    (work / ".venv" / "bin").mkdir(parents=True)
    (work / ".venv" / "bin" / "python").touch()
    cmds = _dry_run(work, {})
    assert not any("-m venv" in c for c in cmds), cmds
    assert [p.split()[0] for p in _pip_lines(cmds)] == [".venv/bin/python", ".venv/bin/python"]


@needs_make
@pytest.mark.parametrize("env", [{"VIRTUAL_ENV": "/some/venv"}, {"CONDA_PREFIX": "/some/conda"}])
def test_make_installs_into_an_active_environment(tmp_path, env):
    work = _checkout(tmp_path)
    cmds = _dry_run(work, env)
    assert not any("-m venv" in c for c in cmds), cmds
    assert [p.split()[0] for p in _pip_lines(cmds)] == ["python3", "python3"]
    assert _make(work, env, "where") == [f"PYTHON=python3 (the active environment {next(iter(env.values()))})"]


@needs_make
@pytest.mark.parametrize("env", [{}, {"VIRTUAL_ENV": "/some/venv"}])
def test_an_explicit_python_wins(tmp_path, env):
    work = _checkout(tmp_path)
    cmds = _dry_run(work, env, "PYTHON=/opt/py/bin/python")
    assert not any("-m venv" in c for c in cmds), cmds
    assert [p.split()[0] for p in _pip_lines(cmds)] == ["/opt/py/bin/python", "/opt/py/bin/python"]


def test_the_test_command_installs_every_extra():
    """CI runs `make test` on a clean clone: `.[all,test]` must pull in every optional dependency group."""
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())
    extras = cfg["project"]["optional-dependencies"]
    (spec,) = extras["all"]
    inside = set(re.fullmatch(r"spotlights\[([\w,\s-]+)\]", spec).group(1).replace(" ", "").split(","))
    assert inside == set(extras) - {"all", "test"}, f"'all' = {sorted(inside)}; extras: {sorted(extras)}"
    make = (REPO / "Makefile").read_text()
    assert '-e ".[all,test]"' in make and make.index("torch==2.13.0") < make.index('".[all,test]"')


def test_the_readme_starts_with_the_two_commands_and_ci_runs_one_verbatim():
    readme = (REPO / "README.md").read_text()
    first = re.search(r"```bash\n(.*?)```", readme, re.S).group(1)
    assert [ln.split("#")[0].strip() for ln in first.strip().splitlines()] == ["make demo", "make test"], first
    ci = [ln.strip() for ln in (REPO / ".ci" / "run").read_text().splitlines()]
    assert "make test" in ci, ci
