"""Sizes a maintainer can read: no module of the package over 600 lines, no function over 80 lines, none over
cyclomatic complexity 20 (ruff's mccabe count); the command line's argparse registration (``register``) is the
one exception to the length. The counts are the AST's and ruff's, not the code's own."""

from __future__ import annotations

import ast
import subprocess
import sys

import pytest

from helpers import REPO

SRC = REPO / "src" / "spotlights"
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80
MAX_COMPLEXITY = 20


def long_functions(source: str, limit: int) -> list[tuple[int, str, int]]:
    """(line, name, length) of every function or method of ``source`` longer than ``limit`` lines, counted from its
    ``def`` to its last line (decorators excluded, docstring included)."""
    return [
        (node.lineno, node.name, node.end_lineno - node.lineno + 1)
        for node in ast.walk(ast.parse(source))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno + 1 > limit
    ]


def test_the_length_count_on_a_known_source():
    body = "\n".join(f"    x{i} = {i}" for i in range(5))
    src = f"@decorator\ndef f():\n{body}\n\nclass C:\n    def g(self):\n        return 1\n"
    assert long_functions(src, 5) == [(2, "f", 6)]
    assert long_functions(src, 6) == []


def test_no_module_over_600_lines():
    big = [
        f"{p.relative_to(REPO)}: {n} lines"
        for p in sorted(SRC.rglob("*.py"))
        if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES
    ]
    assert not big, "split these modules by job:\n" + "\n".join(big)


def test_no_function_over_80_lines():
    cli = SRC / "cli"
    long = [
        f"{p.relative_to(REPO)}:{line} {name}: {n} lines"
        for p in sorted(SRC.rglob("*.py"))
        for line, name, n in long_functions(p.read_text(), MAX_FUNCTION_LINES)
        if not (p.parent == cli and name == "register")
    ]
    assert not long, "cut these functions by job:\n" + "\n".join(long)


@pytest.mark.timeout(120)
def test_no_function_over_complexity_20():
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "ruff",
            "check",
            "--no-cache",
            "--select",
            "C901",
            "--config",
            f"lint.mccabe.max-complexity={MAX_COMPLEXITY}",
            str(SRC),
        ],  # fmt: skip
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert proc.returncode == 0, f"functions over complexity {MAX_COMPLEXITY}:\n{proc.stdout}{proc.stderr}"
