"""Layers import downwards only (docs/architecture.md): every import of a project module, at the top of a file or
inside a function, points to the same package or a lower layer; ``data`` and ``analysis`` (one floor) do not
import each other."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "spotlights"
#: package -> floor (higher floors may import lower ones)
FLOORS = {
    "geometry": 0,
    "metrics": 1,
    "data": 2,
    "analysis": 2,
    "viz": 3,
    "learning": 4,
    "tracking": 4.5,
    "completion": 5,
    "experiments": 6,
    "cli": 7,
}


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in ``path`` (relative ones resolved)."""
    package = ["spotlights", *path.relative_to(SRC).parts[:-1]]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            out.append((node.lineno, ".".join(base + ([node.module] if node.module else []))))
        elif isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
    return out


def upward_imports() -> list[str]:
    bad = []
    for path in sorted(SRC.rglob("*.py")):
        layer = path.relative_to(SRC).parts[0]
        if layer not in FLOORS:
            continue
        for line, module in _imports(path):
            parts = module.split(".")
            if parts[0] != "spotlights" or len(parts) < 2 or parts[1] not in FLOORS or parts[1] == layer:
                continue
            if FLOORS[parts[1]] >= FLOORS[layer]:
                bad.append(f"{path.relative_to(SRC.parent)}:{line}: {layer} imports {module}")
    return bad


def test_imports_point_down_only():
    assert upward_imports() == []


def test_the_check_sees_an_upward_import(tmp_path, monkeypatch):
    fake = tmp_path / "spotlights"
    (fake / "geometry").mkdir(parents=True)
    (fake / "geometry" / "x.py").write_text("def f():\n    from ..learning import train\n")
    (fake / "viz").mkdir()
    (fake / "viz" / "y.py").write_text("from ..geometry import boxes\nfrom spotlights.data import store\n")
    monkeypatch.setattr(sys.modules[__name__], "SRC", fake)
    assert upward_imports() == ["spotlights/geometry/x.py:2: geometry imports spotlights.learning"]
