"""One way to declare a command's options: fields made with ``spotlights.options.option`` and added by
``add_options``; no command module calls ``add_argument`` itself."""

from __future__ import annotations

import argparse
import ast
from dataclasses import dataclass

import pytest

from spotlights.cli import add_options
from spotlights.options import option

from helpers import REPO

CLI = REPO / "src" / "spotlights" / "cli"

# The plumbing that may call add_argument: add_options (through _add_field_option) and add_quiet, and the global
# options of `spotlights`.
ALLOWED = {("_util.py", "_add_field_option"), ("_util.py", "add_quiet"), ("__init__.py", "build_parser")}


def add_argument_calls(source: str) -> list[tuple[int, str | None]]:
    """(line, enclosing top-level function or None) of every ``X.add_argument(...)`` call in ``source``."""
    found = []
    tree = ast.parse(source)
    for top in tree.body:
        name = top.name if isinstance(top, (ast.FunctionDef, ast.AsyncFunctionDef)) else None
        for node in ast.walk(top):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "add_argument":
                found.append((node.lineno, name))
    return found


def test_the_check_finds_add_argument_calls():
    src = (
        "def register(sub):\n    p = sub.add_parser('x')\n    p.add_argument('--a')\n\n"
        "class C:\n    def f(self, g):\n        g.add_argument('b')\n\nPARSER.add_argument('--c')\n"
    )
    assert add_argument_calls(src) == [(3, "register"), (7, None), (9, None)]
    assert add_argument_calls("p.add_argument_group('t')\np.add_mutually_exclusive_group()\n") == []


def test_no_command_module_calls_add_argument():
    bad = [
        f"src/spotlights/cli/{f.name}:{line} ({where or 'module level'})"
        for f in sorted(CLI.glob("*.py"))
        for line, where in add_argument_calls(f.read_text())
        if (f.name, where) not in ALLOWED
    ]
    assert not bad, "declare options as option() fields and add them with add_options:\n" + "\n".join(bad)


# ------------------------------------------------------------------------------- what add_options declares

GROUP = "the section"


@dataclass(kw_only=True)
class Toy:
    files: list[str] = option("files", nargs="+", metavar="FILE", help="positional files")
    out: str = option("--out", "-o", metavar="PATH", help="a required option")
    keep: bool = option(default=True, action=argparse.BooleanOptionalAction, help="on unless --no-keep")
    worker: bool = option("--no-worker", default=True, action="store_false", help="dest is the field")
    pair: list[int] = option(default=[1, 2], type=int, nargs=2, metavar=("A", "B"), group=GROUP, help="two ints")
    clip: float | None = option(default=None, type=float, mutex="clip", group=GROUP, help="a clip")
    no_clip: bool = option(default=False, action="store_true", mutex="clip", group=GROUP, help="no clip")
    tags: list[str] | None = option(default=None, action="append", metavar="TAG", help="repeatable")


@dataclass(kw_only=True)
class More:
    level: int = option(default=3, type=int, group=GROUP, help="joins the existing section")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="toy")
    add_options(p, Toy)
    add_options(p, More)
    return p


def test_fields_become_options_with_their_defaults():
    ns = vars(_parser().parse_args(["a.txt", "-o", "x"]))
    assert ns == {
        "files": ["a.txt"],
        "out": "x",
        "keep": True,
        "worker": True,
        "pair": [1, 2],
        "clip": None,
        "no_clip": False,
        "tags": None,
        "level": 3,
    }


def test_positionals_nargs_boolean_optional_store_false_append():
    argv = ["a", "b", "--out=y", "--no-keep", "--no-worker", "--pair", "5", "6", "--tags", "t1", "--tags", "t2"]
    ns = _parser().parse_args(argv + ["--clip", "0.5", "--level", "7"])
    assert (ns.files, ns.out, ns.keep, ns.worker, ns.pair, ns.tags) == (
        ["a", "b"],
        "y",
        False,
        False,
        [5, 6],
        ["t1", "t2"],
    )
    assert (ns.clip, ns.level) == (0.5, 7)


def test_required_and_mutually_exclusive():
    with pytest.raises(SystemExit):
        _parser().parse_args(["a"])  # -o is required
    with pytest.raises(SystemExit):
        _parser().parse_args(["a", "-o", "x", "--clip", "0.2", "--no-clip"])


def test_a_section_is_shared_by_later_calls():
    text = _parser().format_help()
    assert text.count(f"{GROUP}:") == 1
    section = text.split(f"{GROUP}:")[1]
    assert "--pair A B" in section and "--no-clip" in section and "--level LEVEL" in section


def test_a_positional_is_named_as_its_field():
    @dataclass
    class Wrong:
        name: str = option("other", help="a positional whose name is not its field's")

    with pytest.raises(ValueError, match="positional"):
        add_options(argparse.ArgumentParser(), Wrong)


def test_verbose_goes_before_or_after_the_command():
    """``-v`` counts before the command (the program's option) and after it (every command's), ``-vv`` too."""
    from spotlights.cli import build_parser

    p = build_parser()
    base = ["track", "x.json", "--format", "generic", "--out", "o.json"]
    assert [p.parse_args(a).verbose for a in (base, [*base, "-v"], ["-v", *base], [*base, "-vv"])] == [0, 1, 1, 2]
    deep = ["dataset", "info", "d.h5"]
    assert p.parse_args(deep).verbose == 0 and p.parse_args([*deep, "--verbose"]).verbose == 1
