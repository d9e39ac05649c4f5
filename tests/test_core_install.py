"""A core install (no extras): every command's ``--help`` works, and a command that needs an extra says in one line
which one to install (exit 2, no traceback, nothing written). The extras' packages are hidden from a child
interpreter by an import hook, as if they were not installed."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from spotlights.errors import EXTRAS

from helpers import src_pythonpath

#: run in the child: hide every extra's package, then run the CLI over each argument list of argv[1] (JSON)
CHILD = """
import importlib.abc, json, sys
HIDDEN = set(json.loads(sys.argv[2]))
class Hide(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in HIDDEN:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
sys.meta_path.insert(0, Hide())
from spotlights.cli import main
codes = []
for argv in json.loads(sys.argv[1]):
    try:
        codes.append(main(argv))
    except SystemExit as exc:
        codes.append(exc.code)
print("CODES", json.dumps(codes))
"""


def _core(argvs: list[list[str]], cwd) -> tuple[list, str]:
    env = {"PYTHONPATH": src_pythonpath(), "MPLBACKEND": "Agg", "PATH": "/usr/bin:/bin"}
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, json.dumps(argvs), json.dumps(sorted(EXTRAS))],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=300,
    )
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("CODES ")), None)
    assert line is not None, proc.stdout[-2000:] + proc.stderr[-2000:]
    return json.loads(line[6:]), proc.stderr


def _commands() -> list[list[str]]:
    """Every command and sub-command of the CLI, as argument lists."""
    import argparse

    from spotlights.cli import build_parser

    out = []

    def walk(parser, prefix):
        for action in parser._actions:  # noqa: SLF001 - argparse has no public walk
            if isinstance(action, argparse._SubParsersAction):  # noqa: SLF001
                for name, sub in action.choices.items():
                    out.append([*prefix, name])
                    walk(sub, [*prefix, name])

    walk(build_parser(), [])
    return [c for c in out if not any(len(o) > len(c) and o[: len(c)] == c for o in out)]


def test_every_help_works_without_the_extras(tmp_path):
    commands = _commands()
    assert ["study", "rigs"] in commands and ["complete"] in commands and len(commands) > 20
    codes, stderr = _core([["--help"]] + [[*c, "--help"] for c in commands], tmp_path)
    assert codes == [0] * (len(commands) + 1), (commands, stderr[-2000:])
    assert "Traceback" not in stderr


@pytest.mark.timeout(300)
def test_a_command_that_needs_an_extra_says_which_in_one_line(tmp_path):
    import trimesh

    from spotlights.experiments.rig_study import MIN_PER_CATEGORY

    meshes = tmp_path / "meshes"
    meshes.mkdir()
    for k in range(MIN_PER_CATEGORY):
        trimesh.creation.box(extents=(4.0 + 0.1 * k, 1.8, 1.5)).export(meshes / f"box{k}.ply")
    out = tmp_path / "rigs"
    codes, stderr = _core([["study", "rigs", "--meshes", str(meshes), "--out", str(out), "--quiet"]], tmp_path)
    assert codes == [2], stderr
    assert stderr.strip().splitlines() == [
        "spotlights: error: this needs the optional package pandas: pip install 'spotlights[real]' (or "
        "'spotlights[all]')"
    ]
    assert not out.exists() or not any(out.iterdir())
