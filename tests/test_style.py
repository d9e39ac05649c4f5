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
        "        from spotlights.outputs import atomic_output\n"
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


def test_one_stage_timer():
    """Stages are timed by timing.StageTimer; time.perf_counter appears only there and in
    learning.bench (the latency timer of repeated calls)."""
    allowed = {"timing.py", "learning/bench.py"}
    src = ROOT / "src" / "spotlights"
    found = [
        str(f.relative_to(src))
        for f in src.rglob("*.py")
        if "perf_counter" in f.read_text() and str(f.relative_to(src)) not in allowed
    ]
    assert not found, f"hand-written stage timing (use spotlights.timing.StageTimer) in: {found}"


def _declaration_lines(source: str) -> int:
    """Lines of the dataclasses of ``source`` (a command's options, declared as ``option()`` fields)."""
    import ast

    return sum(
        node.end_lineno - node.lineno + 1 + len(node.decorator_list)
        for node in ast.parse(source).body
        if isinstance(node, ast.ClassDef) and any("dataclass" in ast.unparse(d) for d in node.decorator_list)
    )


def test_the_cli_stays_thin():
    """The CLI parses, builds settings, calls one library function and prints: under 1,500 lines
    besides its option declarations (dataclasses of ``option()`` fields) and no function over
    cyclomatic complexity 15 (ruff's mccabe count)."""
    sources = [f.read_text() for f in (ROOT / "src" / "spotlights" / "cli").glob("*.py")]
    lines = sum(len(s.splitlines()) - _declaration_lines(s) for s in sources)
    assert lines < 1500, f"the CLI has {lines} lines besides its option declarations: move logic into the library"
    proc = _ruff(
        "check", "--no-cache", "--select", "C901", "--config", "lint.mccabe.max-complexity=15", "src/spotlights/cli"
    )
    assert proc.returncode == 0, f"CLI functions over complexity 15:\n{proc.stdout}{proc.stderr}"


# ---------------------------------------------------------------------------------------------
# tests use the public API only: no private spotlights name is imported or reached
# ---------------------------------------------------------------------------------------------
# Private attributes of other libraries that tests may reach, each for a reason (nothing public does it).
FOREIGN_PRIVATE = {
    "_exit": "os._exit: a child that dies at once, as a killed worker does",
    "_actions": "argparse keeps a parser's options only there",
    "_subparsers": "argparse: the sub-commands of a parser",
    "_group_actions": "argparse: the sub-commands of a parser",
    "_SubParsersAction": "argparse: the class of a sub-command action",
}


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def private_uses(source: str) -> list[tuple[int, str]]:
    """(line, what) for every private spotlights name a test module imports or reaches.

    Flagged: ``from spotlights.x import _y`` and private modules; ``obj._y`` on anything but ``self``
    and ``cls`` (unless ``_y`` is in FOREIGN_PRIVATE); ``setattr``/``getattr``/``monkeypatch.setattr``
    with a private attribute name; strings naming ``spotlights....._y`` (monkeypatch targets)."""
    import ast
    import re

    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "spotlights":
            parts = node.module.split(".") + [a.name for a in node.names]
            found += [(node.lineno, f"imports {node.module}.{p}") for p in parts if _is_private(p)]
        elif isinstance(node, ast.Import):
            found += [
                (node.lineno, f"imports {a.name}")
                for a in node.names
                if a.name.split(".")[0] == "spotlights" and any(_is_private(p) for p in a.name.split("."))
            ]
        elif isinstance(node, ast.Attribute) and _is_private(node.attr) and node.attr not in FOREIGN_PRIVATE:
            root = node.value
            while isinstance(root, (ast.Attribute, ast.Call, ast.Subscript)):
                root = root.func if isinstance(root, ast.Call) else root.value
            if not (isinstance(root, ast.Name) and root.id in ("self", "cls")):
                found.append((node.lineno, f"reaches {ast.unparse(node)}"))
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) in (
            "setattr",
            "getattr",
            "delattr",
            "hasattr",
        ):
            names = [a.value for a in node.args[1:2] if isinstance(a, ast.Constant) and isinstance(a.value, str)]
            found += [(node.lineno, f"{ast.unparse(node.func)} of {n}") for n in names if _is_private(n)]
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            m = re.search(r"\bspotlights(?:\.\w+)*\.(_\w+)", node.value)
            if m and _is_private(m.group(1)):
                found.append((node.lineno, f"names {m.group(0)}"))
    return sorted(found)


def test_the_private_name_check_finds_each_kind_of_reach():
    src = (  # SL stands for the package's name (this file's own strings name nothing private)
        "from SL.learning.train import _stream_indices, train\n"
        "import SL.geometry._hidden as h\n"
        "from SL.geometry import raycast\n"
        "raycast._run_split(3, 2, print)\n"
        "ds = open_dataset(p); ds._h5()['rigs']\n"
        "monkeypatch.setattr(runner, '_run_unit', f)\n"
        "monkeypatch.setattr('SL.data.synthetic.runner._run_unit', f)\n"
        "os._exit(1); self._cache = 1; parser._actions\n"
        "raycast.run_split(3, 2, print); Dunder.__init__\n"
    ).replace("SL", "spotlights")
    lines = [line for line, _ in private_uses(src)]
    assert lines == [1, 2, 4, 5, 6, 7], private_uses(src)


def test_no_test_imports_or_reaches_a_private_name():
    """Tests check public behaviour: a private name (``_foo``) of spotlights is not imported, reached or
    monkeypatched; a unit worth testing on its own is made public (documented, annotated)."""
    bad = [
        f"{path.relative_to(ROOT)}:{line}: {what}"
        for path in sorted((ROOT / "tests").glob("*.py"))
        for line, what in private_uses(path.read_text())
    ]
    assert not bad, "private names in tests:\n" + "\n".join(bad)
