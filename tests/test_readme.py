"""Every command of the README runs as written from the checkout.

The ```bash blocks are read from README.md and each ``spotlights ...`` line is run in order, in
process (``helpers.run_cli``), in one temporary folder: the paths that name files of the checkout
(``src/spotlights/assets/...``) or of the shared data (``../shared/data/...``, or
``$SPOTLIGHTS_SHARED``) are made absolute, every other path (the outputs) lands in the temporary
folder, so later commands read what earlier ones wrote, as they would in the checkout. Skipped,
with the reason: the two install commands (``make demo``, ``make test``: tests/test_setup.py),
a command whose shared data is absent (and those reading its outputs), a command that serves a
port. A line of another kind fails the test: whoever adds one says here how to check it.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from helpers import REPO, SHARED, has_module, run_cli

README = REPO / "README.md"
OUTPUT_OPTIONS = ("--out", "-o", "--show", "--html", "--summary", "--per-object")
SKIPPED: dict[str, str] = {}  # command -> why it was skipped (its outputs are missing for later ones)


def readme_commands() -> list[str]:
    """The command lines of the README's ```bash blocks, in order (continuations joined, comments cut)."""
    lines = []
    for block in re.findall(r"```bash\n(.*?)```", README.read_text(), flags=re.S):
        text = re.sub(r"\\\n\s*", " ", block)
        for line in text.splitlines():
            line = line.split(" #")[0].strip()
            if line and not line.startswith("#"):
                lines.append(line)
    return lines


COMMANDS = readme_commands()


def test_the_readme_has_commands_of_every_kind():
    kinds = {c.split()[0] + " " + c.split()[1] for c in COMMANDS}
    assert {"make demo", "make test", "spotlights complete", "spotlights encode", "spotlights view"} <= kinds, kinds
    assert not [c for c in COMMANDS if c.split()[0] not in ("make", "spotlights")], COMMANDS


def _argument(arg: str) -> Path | str:
    """An argument as run from the checkout: shared data and checkout files absolute, the rest as written."""
    if arg.startswith("../shared/"):
        path = SHARED / arg[len("../shared/") :]
        if not path.exists():
            pytest.skip(f"shared data not found at {path} (set SPOTLIGHTS_SHARED to the folder holding data/)")
        return path
    if not arg.startswith("-") and (REPO / arg).exists():
        return REPO / arg
    return arg


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """The folder standing in for the checkout's root: every command's outputs land here."""
    return tmp_path_factory.mktemp("readme")


def _param(i: int, command: str):
    """A parameter per command; a whole frame or dataset (seconds: model, pictures) is marked slow."""
    slow = command.startswith("spotlights real") or "--show" in command
    return pytest.param(command, id=f"{i}-{' '.join(command.split()[:2])}", marks=[pytest.mark.slow] if slow else [])


@pytest.mark.parametrize("command", [_param(i, c) for i, c in enumerate(COMMANDS)])
def test_readme_command_runs_as_written(command, work):
    words = shlex.split(command)
    if words[0] == "make":
        pytest.skip("an install command: tests/test_setup.py checks what it runs")
    assert words[0] == "spotlights", command
    if words[1] == "view" and not has_module("plotly"):  # not recorded: no later command reads its page
        pytest.skip("plotly (the viewer extra) is not installed")
    if "--serve" in words:
        SKIPPED[command] = "serves a port"
        pytest.skip("serves a port until stopped (tests/test_viz.py serves the page on a free port)")
    try:
        args = [_argument(a) for a in words[1:]]
    except pytest.skip.Exception as exc:
        SKIPPED[command] = str(exc)
        raise
    proc = run_cli(*args, cwd=work)
    if proc.returncode != 0 and SKIPPED:
        pytest.skip(f"reads the output of a skipped command ({next(iter(SKIPPED.values()))}): {proc.stderr[-300:]}")
    assert proc.returncode == 0, (command, proc.stderr[-3000:])
    assert "Traceback" not in proc.stderr, proc.stderr
    for opt, value in zip(words, words[1:]):
        if opt in OUTPUT_OPTIONS:
            out = work / value
            assert out.exists() and (out.is_dir() or out.stat().st_size > 0), (command, value)


def test_readme_python_example_runs(monkeypatch):
    """The README's Python block, run from the checkout: the paper's rig has 32 x 64 rays."""
    import numpy as np

    (code,) = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    monkeypatch.chdir(REPO)
    ns: dict = {}
    exec(compile(code, "README.md", "exec"), ns)
    assert ns["depths"].shape == (32 * 64,) and ns["depths"].dtype == np.float32
    assert 0 <= ns["depths"].min() and ns["depths"].max() <= 1 and (ns["depths"] > 0).any()
    assert ns["points"].shape == (32 * 64, 3) and ns["mask"].sum() == (ns["depths"] > 0).sum()
