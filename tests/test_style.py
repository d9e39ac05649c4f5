"""Style the suite enforces: ruff (lint and format, configured in pyproject.toml) and imports of the project's own
modules at the top of files (inside functions only where they defer a heavy optional dependency)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import load_script

ROOT = Path(__file__).resolve().parents[1]


def _imports_script():
    return load_script("scripts/imports_at_top.py")


@pytest.mark.slow
def test_light_project_modules_are_imported_at_the_top():
    script = _imports_script()
    rows = script.scan(sorted(script.SRC.rglob("*.py")))
    inside = [
        f"{path.relative_to(ROOT)}:{node.lineno}: {', '.join(modules)}" + (f" (name clash: {clash})" if clash else "")
        for path, node, modules, heavy, _, clash in rows
        if not heavy
    ]
    assert not inside, (
        "project modules imported inside functions; only modules that import a heavy optional package "
        f"({', '.join(script.HEAVY)}) may be: move these to the top (python scripts/imports_at_top.py --fix):\n"
        + "\n".join(inside)
    )


def test_the_import_check_tells_light_modules_from_heavy_ones(tmp_path):
    script = _imports_script()
    sample = tmp_path / "sample.py"
    sample.write_text(
        "def light():\n"
        "    from spotlights.errors import ParameterError\n"
        "    return ParameterError\n"
        "\n"
        "\n"
        "def heavy():\n"
        "    from spotlights.learning.train import train\n"
        "    return train\n"
        "\n"
        "\n"
        "def optional():\n"
        "    try:\n"
        "        from spotlights.utils import atomic_output\n"
        "    except ImportError:\n"
        "        return None\n"
        "    return atomic_output\n"
    )
    rows = {node.lineno: heavy for _, node, _, heavy, _, _ in script.scan([sample])}
    assert set(rows) == {2, 7}  # the import inside a try block (an optional feature) is left alone
    assert rows[2] == []  # spotlights.errors imports nothing heavy: it belongs at the top
    assert rows[7]  # spotlights.learning.train imports torch (or cannot be imported without it): may stay


def _ruff(*args: str) -> subprocess.CompletedProcess:
    if importlib.util.find_spec("ruff") is None:
        pytest.skip("ruff is not installed (it comes with the test extra: pip install -e '.[test]')")
    return subprocess.run([sys.executable, "-m", "ruff", *args], cwd=ROOT, capture_output=True, text=True)


def test_ruff_check_passes():
    proc = _ruff("check", "--no-cache", ".")
    assert proc.returncode == 0, f"ruff check found problems (make format fixes most):\n{proc.stdout}{proc.stderr}"


def test_ruff_format_leaves_every_file_as_it_is():
    proc = _ruff("format", "--check", "--no-cache", ".")
    assert proc.returncode == 0, f"files ruff format would change (run make format):\n{proc.stdout}{proc.stderr}"
