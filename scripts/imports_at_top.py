"""Imports of the project's own modules belong at the top of a file; this finds (and moves) the others.

An import inside a function is kept only where it defers a heavy optional dependency: a
project module is *heavy* when importing it imports one of :data:`HEAVY` (torch, matplotlib,
open3d, pyarrow, pandas, ray, plotly, onnx, onnxruntime, laspy), found by importing each module
in a fresh interpreter. Imports inside ``try`` blocks (optional features) and under
``if TYPE_CHECKING`` are left alone.

    python scripts/imports_at_top.py            # list the function-level imports that should move (exit 1 if any)
    python scripts/imports_at_top.py --fix      # move them to the top of their files, then run `ruff check --fix`
                                                # (import order) and check that every module still imports

``tests/test_style.py`` runs the listing, so a new function-level import of a light module fails the
suite. After ``--fix``, run the tests: a moved import can only break a circular import, which the
import check at the end reports by module.
"""

from __future__ import annotations

import argparse
import ast
import json
import subprocess
import sys
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
PACKAGE = "spotlights"
HEAVY = (
    "torch",
    "matplotlib",
    "open3d",
    "pyarrow",
    "pandas",
    "ray",
    "plotly",
    "onnx",
    "onnxruntime",
    "laspy",
    "trimesh",
)


def module_name(path: Path) -> str:
    parts = path.relative_to(SRC).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def resolve(node: ast.ImportFrom | ast.Import, path: Path) -> list[str]:
    """Absolute names of the project modules an import statement reads (empty for third-party imports)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name.split(".")[0] == PACKAGE]
    if node.level == 0:
        base = node.module or ""
    else:
        pkg = module_name(path).split(".")
        if path.name != "__init__.py":
            pkg = pkg[:-1]
        pkg = pkg[: len(pkg) - (node.level - 1)]
        base = ".".join(pkg + ([node.module] if node.module else []))
    if base.split(".")[0] != PACKAGE:
        return []
    out = []
    for a in node.names:  # `from .pkg import module` reads the submodule
        sub = f"{base}.{a.name}"
        out.append(sub if _is_module(sub) else base)
    return out


@cache
def _is_module(name: str) -> bool:
    rel = Path(*name.split("."))
    return (SRC / rel).with_suffix(".py").is_file() or (SRC / rel / "__init__.py").is_file()


_PROBE = """
import importlib, json, sys
heavy = {heavy!r}
out = {{}}
for name in {names!r}:
    before = set(sys.modules)
    try:
        importlib.import_module(name)
    except Exception as e:
        out[name] = "error: " + type(e).__name__
        continue
    out[name] = sorted({{m.split(".")[0] for m in sys.modules}} & set(heavy))
print(json.dumps(out))
"""


def heavy_modules(names: list[str]) -> dict[str, list[str]]:
    """{module: heavy packages its import pulls in}, each module imported in its own fresh interpreter."""
    out = {}
    for name in sorted(set(names)):
        code = _PROBE.format(heavy=HEAVY, names=[name])
        proc = subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            cwd=ROOT,
            env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"},
            timeout=300,
        )
        out.update(json.loads(proc.stdout.strip().splitlines()[-1]) if proc.returncode == 0 else {name: "error"})
    return out


def function_imports(path: Path) -> list[tuple[ast.stmt, list[str], bool]]:
    """(statement, project modules, sole statement of its block) of every project import inside a function of
    ``path``, except in ``try`` blocks and under ``if TYPE_CHECKING``."""
    tree = ast.parse(path.read_text())
    found = []

    def visit(node, in_function=False, guarded=False):
        for field in ("body", "orelse", "finalbody", "handlers"):
            block = getattr(node, field, None)
            if isinstance(block, list):
                for child in block:
                    if isinstance(child, ast.Import | ast.ImportFrom) and in_function and not guarded:
                        mods = resolve(child, path)
                        if mods:
                            found.append((child, mods, len(block) == 1))
        for child in ast.iter_child_nodes(node):
            fn = in_function or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda)
            g = (
                guarded
                or isinstance(child, ast.Try)
                or (isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test))
            )
            visit(child, fn, g)

    visit(tree)
    return found


def bound_names(node: ast.Import | ast.ImportFrom) -> dict[str, str]:
    """{name bound by the import: what it refers to}."""
    out = {}
    for a in node.names:
        if isinstance(node, ast.Import):
            out[a.asname or a.name.split(".")[0]] = a.name
        else:
            out[a.asname or a.name] = f"{'.' * node.level}{node.module or ''}:{a.name}"
    return out


def top_level_names(path: Path) -> dict[str, str]:
    """Names a module binds at its top level: {name: what} (imports), or {name: "def"} for the rest."""
    out = {}
    for n in ast.parse(path.read_text()).body:
        if isinstance(n, ast.Import | ast.ImportFrom):
            out.update(bound_names(n))
        elif isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            out[n.name] = "def"
        elif isinstance(n, ast.Assign | ast.AnnAssign):
            for t in n.targets if isinstance(n, ast.Assign) else [n.target]:
                for x in ast.walk(t):
                    if isinstance(x, ast.Name):
                        out[x.id] = "def"
    return out


def scan(paths: list[Path]) -> list[tuple]:
    """Every function-level project import of ``paths``: (path, statement, modules, heavy packages behind it,
    sole statement of its block, a name clash that stops it from moving or "")."""
    per_file = {p: function_imports(p) for p in paths}
    heavy = heavy_modules([m for items in per_file.values() for _, mods, _ in items for m in mods])
    rows = []
    for p, items in per_file.items():
        top = top_level_names(p)
        wanted: dict[str, set] = {}
        for node, _, _ in items:
            for name, what in bound_names(node).items():
                wanted.setdefault(name, set()).add(what)
        for node, mods, sole in items:
            why = sorted({h for m in mods for h in (heavy.get(m) if isinstance(heavy.get(m), list) else ["?"])})
            clash = [
                name
                for name, what in bound_names(node).items()
                if (name in top and top[name] != what) or len(wanted[name]) > 1
            ]
            rows.append((p, node, mods, why, sole, ", ".join(clash)))
    return rows


def move_to_top(path: Path, nodes: list[tuple[ast.stmt, bool]]) -> None:
    """Delete ``nodes`` (import statements inside functions; a ``pass`` where one was alone in its block) and add
    them, as written, after the module's last top-level import (``ruff check --fix`` sorts them after)."""
    lines = path.read_text().splitlines(keepends=True)
    tree = ast.parse("".join(lines))
    top = [n for n in tree.body if isinstance(n, ast.Import | ast.ImportFrom)]
    anchor = top[-1].end_lineno if top else (tree.body[0].end_lineno if ast.get_docstring(tree) else 0)
    texts = set()
    for n, sole in sorted(nodes, key=lambda x: x[0].lineno, reverse=True):
        texts.add(" ".join("".join(lines[n.lineno - 1 : n.end_lineno]).split()))
        indent = lines[n.lineno - 1][: len(lines[n.lineno - 1]) - len(lines[n.lineno - 1].lstrip())]
        lines[n.lineno - 1 : n.end_lineno] = [f"{indent}pass\n"] if sole else []
    lines[anchor:anchor] = [t + "\n" for t in sorted(texts)]
    path.write_text("".join(lines))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fix", action="store_true", help="move the imports of light modules to the top of their files")
    ap.add_argument("paths", nargs="*", type=Path, help="files (default: every module under src/)")
    args = ap.parse_args(argv)
    paths = [p.resolve() for p in args.paths] or sorted(SRC.rglob("*.py"))
    rows = scan(paths)
    movable = [(p, n, m, sole) for p, n, m, why, sole, clash in rows if not why and not clash]
    clashing = [(p, n, clash) for p, n, m, why, sole, clash in rows if not why and clash]
    kept = len(rows) - len(movable) - len(clashing)
    for p, n, m, _ in movable:
        print(
            f"{p.relative_to(ROOT)}:{n.lineno}: import of {', '.join(m)} inside a function (light: move it to the top)"
        )
    for p, n, clash in clashing:
        print(
            f"{p.relative_to(ROOT)}:{n.lineno}: import inside a function; moving it would clash on {clash} "
            "(import the module instead, e.g. `from .. import evaluate` and `evaluate.write_report`)"
        )
    print(
        f"{len(movable) + len(clashing)} function-level import(s) of light project modules "
        f"({len(clashing)} with a name clash); {kept} kept (they defer heavy packages)"
    )
    if not args.fix:
        return 1 if movable or clashing else 0
    by_file: dict[Path, list] = {}
    for p, n, _, sole in movable:
        by_file.setdefault(p, []).append((n, sole))
    for p, nodes in by_file.items():
        move_to_top(p, nodes)
    subprocess.run([sys.executable, "-m", "ruff", "check", "--fix", "--select", "I,F401", *map(str, by_file)], cwd=ROOT)
    broken = {m: e for m, e in heavy_modules([module_name(p) for p in by_file]).items() if not isinstance(e, list)}
    for m, e in broken.items():
        print(f"{m}: does not import any more ({e}): a circular import; keep that import inside its function")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
