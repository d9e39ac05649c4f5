"""The README's two set-up commands: which Python `make demo` / `make test` install into, and what they install.

The full path (a fresh clone, `make demo` on Debian's externally managed Python, creating .venv)
needs minutes and the package registries: scripts/check_setup.sh runs it (docs/install.md).
Here: the decision, by `make -n` (a dry run, nothing installed), and the extras CI exercises.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

import pytest

from helpers import REPO, load_script

pytestmark = pytest.mark.timeout(60)


def _load_detector():
    return load_script("scripts/externally_managed.py")


def test_externally_managed_follows_pep_668(tmp_path, monkeypatch):
    det = _load_detector()
    stdlib = tmp_path / "lib" / "python3"
    stdlib.mkdir(parents=True)
    monkeypatch.setattr(sysconfig, "get_path", lambda name, *a, **k: str(stdlib))
    monkeypatch.setattr(sys, "prefix", sys.base_prefix)  # a base interpreter, no virtual environment
    assert not det.externally_managed()
    (stdlib / "EXTERNALLY-MANAGED").write_text("[externally-managed]\nError=use apt\n")
    assert det.externally_managed()
    monkeypatch.setattr(sys, "prefix", str(tmp_path / "venv"))  # inside a venv the marker does not count
    assert not det.externally_managed()


def _fake_python(tmp_path: Path, answer: str) -> Path:
    """An interpreter stand-in whose scripts/externally_managed.py answer is ``answer``."""
    p = tmp_path / f"python-{answer}"
    p.write_text(f"#!/bin/sh\necho {answer}\n")
    p.chmod(0o755)
    return p


def _dry_run(tmp_path: Path, env_extra: dict, *args: str) -> list[str]:
    """The commands `make -n install` would run (nothing is executed), in a bare copy of the
    Makefile and scripts/ under ``tmp_path``: the checkout's state (an existing ``.venv``) cannot
    change the answer."""
    work = tmp_path / "checkout"
    work.mkdir()
    shutil.copy2(REPO / "Makefile", work / "Makefile")
    shutil.copytree(REPO / "scripts", work / "scripts")
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "CONDA_PREFIX", "PYTHON", "MAKEFLAGS")}
    env.update(env_extra)
    proc = subprocess.run(
        ["make", "-n", "-s", "install", *args], cwd=work, env=env, capture_output=True, text=True, timeout=30
    )
    assert proc.returncode == 0, proc.stderr
    return [line.strip() for line in proc.stdout.splitlines() if line.strip()]


needs_make = pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")


def _pip_lines(cmds: list[str]) -> list[str]:
    return [c for c in cmds if " -m pip install " in c]


@needs_make
def test_make_uses_a_project_venv_on_an_externally_managed_python(tmp_path):
    managed = _fake_python(tmp_path, "yes")
    cmds = _dry_run(tmp_path, {"SYSTEM_PYTHON": str(managed)})
    assert any(f"{managed} -m venv .venv" in c for c in cmds), cmds
    pips = _pip_lines(cmds)
    assert [p.split()[0] for p in pips] == [".venv/bin/python", ".venv/bin/python"], pips
    assert pips[0].endswith("torch==2.13.0") and pips[1].endswith('-e ".[all,test]"'), pips  # torch first, alone


@needs_make
@pytest.mark.parametrize("env", [{"VIRTUAL_ENV": "/some/venv"}, {"CONDA_PREFIX": "/some/conda"}])
def test_make_installs_into_an_active_environment(tmp_path, env):
    managed = _fake_python(tmp_path, "yes")  # even where the base interpreter is externally managed
    cmds = _dry_run(tmp_path, {"SYSTEM_PYTHON": str(managed), **env})
    assert not any("-m venv" in c for c in cmds), cmds
    assert [p.split()[0] for p in _pip_lines(cmds)] == ["python3", "python3"]


@needs_make
def test_make_installs_into_a_python_that_allows_it(tmp_path):
    cmds = _dry_run(tmp_path, {"SYSTEM_PYTHON": str(_fake_python(tmp_path, "no"))})
    assert not any("-m venv" in c for c in cmds), cmds
    assert [p.split()[0] for p in _pip_lines(cmds)] == ["python3", "python3"]


@needs_make
def test_an_explicit_python_wins(tmp_path):
    cmds = _dry_run(tmp_path, {"SYSTEM_PYTHON": str(_fake_python(tmp_path, "yes"))}, "PYTHON=/opt/py/bin/python")
    assert not any("-m venv" in c for c in cmds), cmds
    assert [p.split()[0] for p in _pip_lines(cmds)] == ["/opt/py/bin/python", "/opt/py/bin/python"]


@needs_make
def test_debian_system_python_gets_the_venv(tmp_path):
    """Where Debian's own Python is here (marked externally managed), the real decision."""
    marker = Path("/usr/lib") / f"python3.{sys.version_info.minor}" / "EXTERNALLY-MANAGED"
    system = Path("/usr/bin/python3")
    if not system.exists() or not any(Path("/usr/lib").glob("python3*/EXTERNALLY-MANAGED")):
        pytest.skip(f"no externally managed system Python here ({marker} absent)")
    answer = subprocess.run(
        [str(system), str(REPO / "scripts" / "externally_managed.py")], capture_output=True, text=True, timeout=30
    ).stdout.strip()
    cmds = _dry_run(tmp_path, {"SYSTEM_PYTHON": str(system)})
    assert answer == "yes" and any("-m venv .venv" in c for c in cmds), (answer, cmds)


def test_the_test_command_installs_every_extra():
    """CI runs `make test` on a clean clone: `.[all,test]` must pull in every optional dependency group."""
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())
    extras = cfg["project"]["optional-dependencies"]
    (spec,) = extras["all"]
    inside = set(re.fullmatch(r"spotlights\[([\w,\s-]+)\]", spec).group(1).replace(" ", "").split(","))
    assert inside == set(extras) - {"all", "test"}, f"'all' = {sorted(inside)}; extras: {sorted(extras)}"
    make = (REPO / "Makefile").read_text()
    assert '-e ".[all,test]"' in make and make.index("torch==2.13.0") < make.index('".[all,test]"')
