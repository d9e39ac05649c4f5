"""Every command of the README runs as written from the checkout.

The ```bash blocks are read from README.md and each ``spotlights ...`` line is run in order, in
process (``helpers.run_cli``), as written, in a copy of the checkout (its tracked files) with the shared
data beside it as ``../shared`` (``$SPOTLIGHTS_SHARED`` where set): later commands read what earlier ones
wrote, as they would in the checkout, and the checkout itself is never written (checked: no file of its own
appears or changes among its untracked files and ``out/``). Skipped,
with the reason: the two install commands (``make demo``, ``make test``: tests/test_setup.py),
a command whose shared data is absent (and those reading its outputs), a command that serves a
port. A line of another kind fails the test: whoever adds one says here how to check it.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
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


def _argument(arg: str) -> str:
    """An argument as written; a path into the shared data that is absent skips the command."""
    if arg.startswith("../shared/") and not (SHARED / arg[len("../shared/") :]).exists():
        pytest.skip(f"shared data not found at {SHARED} (set SPOTLIGHTS_SHARED to the folder holding data/)")
    return arg


def checkout_state() -> dict[str, int]:
    """The checkout's files a README command could write: its untracked, not ignored files and everything under its
    ``out/`` (git-ignored), each with its modification time. Tracked files are left out: they change while the suite
    runs whenever someone edits the checkout, and no README command writes one."""
    untracked = subprocess.run(
        ["git", "ls-files", "--others", "--exclude-standard"], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout.split()
    files = [REPO / f for f in untracked] + [p for p in (REPO / "out").rglob("*") if p.is_file()]
    return {str(f.relative_to(REPO)): f.stat().st_mtime_ns for f in files if f.exists()}


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A copy of the checkout's tracked files, the shared data beside it as ``../shared``: every command runs
    here as written. After the module, the checkout is as it was."""
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("the README's commands run in a copy of a git checkout (git and .git needed)")
    before = checkout_state()
    root = tmp_path_factory.mktemp("readme")
    copy = root / "checkout"
    files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True).stdout
    for name in filter(None, files.decode().split("\0")):
        src = REPO / name
        if src.is_file():
            (copy / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, copy / name)
    if SHARED.exists():
        os.symlink(SHARED, root / "shared")
    yield copy
    assert checkout_state() == before, "the README's commands changed the checkout"


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


def test_readme_python_example_runs(monkeypatch, work):
    """The README's Python block, run in the copy of the checkout: the paper's rig has 32 x 64 rays."""
    import numpy as np

    (code,) = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    monkeypatch.chdir(work)
    ns: dict = {}
    exec(compile(code, "README.md", "exec"), ns)
    assert ns["depths"].shape == (32 * 64,) and ns["depths"].dtype == np.float32
    assert 0 <= ns["depths"].min() and ns["depths"].max() <= 1 and (ns["depths"] > 0).any()
    assert ns["points"].shape == (32 * 64, 3) and ns["mask"].sum() == (ns["depths"] > 0).sum()
