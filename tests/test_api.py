"""The public API (``import spotlights``): light to import, every name there, its page's examples run, mypy clean."""

from __future__ import annotations

import doctest
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

import spotlights

ROOT = Path(__file__).resolve().parents[1]
PUBLIC = [
    "Box",
    "SceneResult",
    "complete",
    "complete_frame",
    "decode",
    "encode_mesh",
    "load_completer",
    "load_mesh",
    "make_rig",
    "read_frames",
]


def test_import_spotlights_loads_no_heavy_library():
    code = (
        "import sys, spotlights; heavy = [m for m in ('torch', 'trimesh', 'scipy', 'matplotlib', 'h5py') "
        "if m in sys.modules]; assert not heavy, heavy; spotlights.Box; spotlights.make_rig; "
        "assert 'torch' not in sys.modules"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_every_public_name_resolves_and_is_listed():
    assert set(PUBLIC) <= set(spotlights.__all__) and set(PUBLIC) <= set(dir(spotlights))
    for name in PUBLIC:
        obj = getattr(spotlights, name)
        assert obj.__doc__, name
        assert obj.__module__.startswith("spotlights."), name
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        spotlights.nope  # noqa: B018
    assert (ROOT / "src" / "spotlights" / "py.typed").is_file()


def test_api_page_examples_run():
    pytest.importorskip("torch")
    failures, tried = doctest.testfile(
        str(ROOT / "docs" / "api.md"),
        module_relative=False,
        optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
        report=True,
        verbose=False,
    )
    assert tried > 20 and failures == 0


@pytest.mark.slow  # about 3 s of CPU with an empty cache (as on CI), 1 s with .mypy_cache
@pytest.mark.skipif(importlib.util.find_spec("mypy") is None, reason="mypy is not installed (pip install -e .[test])")
def test_public_modules_type_check():
    """``mypy`` as configured in pyproject.toml ([tool.mypy]: the API's modules, every function annotated)."""
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", "--no-error-summary"], capture_output=True, text=True, cwd=ROOT
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
