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
#: what a user needs to go from files to files (the front door); written out here, not read from the package
PUBLIC = [
    "BaseCompleter",
    "Box",
    "Frame",
    "ObjectResult",
    "SceneConfig",
    "SceneResult",
    "complete",
    "complete_frame",
    "decode",
    "encode_mesh",
    "load_box",
    "load_completer",
    "load_mesh",
    "load_points",
    "make_rig",
    "read_frames",
    "save_points",
    "track_boxes",
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
    import spotlights.api as api

    # one list of public names: the package's, the lazy table's and the api module's agree
    assert spotlights.__all__[0] == "__version__" and len(set(spotlights.__all__)) == len(spotlights.__all__)
    assert set(api.__all__) - {"FORMATS", "CompleterLike"} == set(spotlights.__all__) - {"__version__"}
    for name in spotlights.__all__[1:]:
        assert getattr(spotlights, name) is getattr(api, name), name
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


def _read_binary_ply(path: Path):
    """A binary little-endian PLY's vertex rows as a numpy record array, read by hand from its header."""
    import numpy as np

    data = path.read_bytes()
    head, body = data.split(b"end_header\n", 1)
    kinds = {"float": "<f4", "double": "<f8", "uchar": "u1", "int": "<i4", "uint8": "u1", "int32": "<i4"}
    fields = [(w[2], kinds[w[1]]) for w in (ln.split() for ln in head.decode().splitlines()) if w[:1] == ["property"]]
    assert b"format binary_little_endian" in head
    return np.frombuffer(body, dtype=np.dtype(fields))


def test_a_result_saves_the_files_the_command_line_writes(tmp_path):
    """``SceneResult.save``: the scene PLY (every scan point once, then the completion, with ``source`` and
    ``object``) and the JSON summary, read back with plyfile and json (independent readers)."""
    pytest.importorskip("torch")
    import json

    import numpy as np

    from spotlights.assets import asset_path

    points = spotlights.load_points(asset_path("demo_scan.pcd"))
    box = spotlights.load_box(asset_path("demo_scan_box.json"))
    result = spotlights.complete_frame(points, [box], complete_unknown=True, any_label=True)
    written = result.save(tmp_path / "scene.ply")
    assert written == [tmp_path / "scene.ply", tmp_path / "scene.json"]
    v = _read_binary_ply(tmp_path / "scene.ply")
    n_done = sum(len(o.completion) for o in result.completed)
    assert len(v) == len(points) + n_done and n_done > 0
    np.testing.assert_allclose(np.c_[v["x"], v["y"], v["z"]][: len(points)], points, atol=1e-5)
    assert set(np.unique(v["source"][len(points) :])) == {2}
    summary = json.loads((tmp_path / "scene.json").read_text())
    assert summary["n_completed"] == len(result.completed) == 1 and summary["out"] == str(tmp_path / "scene.ply")
    assert result.save(tmp_path / "only.ply", summary=False) == [tmp_path / "only.ply"]
    from spotlights.errors import ParameterError

    with pytest.raises(ParameterError, match="summary"):
        result.save(tmp_path / "x.json", summary=tmp_path / "x.json")
    assert not (tmp_path / "x.json").exists()


def test_the_library_is_silent_unless_logging_is_configured():
    """Library lines go to the ``spotlights`` logger: nothing on stderr from a bare import (no last-resort
    handler), the lines once the application configures logging."""
    code = (
        "import logging, spotlights\n"
        "from spotlights import logs\n"
        "logs.warning('first'); logs.info('second')\n"
        "logging.basicConfig(level=logging.INFO, format='%(name)s %(levelname)s %(message)s')\n"
        "logs.warning('third'); logs.info('fourth')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.splitlines() == ["spotlights WARNING third", "spotlights INFO fourth"]


def test_the_command_line_shows_debug_lines_with_vv(tmp_path):
    """``spotlights -vv``: the library's debug lines (a frame's stages) on stderr; without it, none."""
    pytest.importorskip("torch")
    from spotlights.assets import asset_path

    from helpers import run_cli

    args = ["complete", asset_path("demo_scan.pcd"), "--box", asset_path("demo_scan_box.json"), "--complete-unknown"]
    loud = run_cli("-vv", *args, "--out", tmp_path / "a.ply")
    quiet = run_cli(*args, "--out", tmp_path / "b.ply")
    assert loud.returncode == quiet.returncode == 0, loud.stderr + quiet.stderr
    assert "spotlights: 1 box(es), 1 completed by" in loud.stderr and "stages:" in loud.stderr
    assert "stages:" not in quiet.stderr
