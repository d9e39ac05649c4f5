"""One CLI style: walks every sub-command's parser.

Every option has help text; every command that writes has ``-o/--out``; every command with
a progress bar has ``-q/--quiet`` (``--no-progress`` stays as a hidden alias); ``-q`` also
silences the summary lines; every example in ``--help`` and in the docs parses.
"""

from __future__ import annotations

import argparse
import re
import shlex

import pytest
import trimesh

from spotlights.cli import EPILOG, build_parser, main

from helpers import REPO

# Commands that write nothing (info prints; add-rig extends its FILE in place, atomically).
NO_OUTPUT = {"dataset info", "dataset add-rig"}
# Commands that show a progress bar (or progress lines) while they work.
PROGRESS = {
    "encode",
    "dataset build",
    "dataset add-rig",
    "real extract",
    "real evaluate",
    "real complete",
    "analyze density",
    "study rigs",
    "train",
    "evaluate",
    "reproduce",
    "bench models",
}


def _commands(parser=None, prefix="") -> dict[str, argparse.ArgumentParser]:
    parser = parser or build_parser()
    out = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                inner = _commands(sub, f"{prefix}{name} ")
                out.update(inner or {f"{prefix}{name}": sub})
    return out


COMMANDS = _commands()


def _options(p: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {s: a for a in p._actions for s in a.option_strings}


def test_the_walk_finds_every_command():
    assert {
        "encode",
        "decode",
        "show",
        "demo",
        "dataset build",
        "dataset info",
        "train",
        "evaluate",
        "complete",
        "real extract",
        "real evaluate",
        "real show",
        "analyze density",
        "study rigs",
        "reproduce",
        "bench models",
    } <= set(COMMANDS)
    assert PROGRESS <= set(COMMANDS) and NO_OUTPUT <= set(COMMANDS)


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_option_has_help(command):
    missing = [
        a.option_strings[0] if a.option_strings else a.dest
        for a in COMMANDS[command]._actions
        if not isinstance(a, argparse._SubParsersAction) and a.help is None
    ]
    assert not missing, f"{command}: options without help text: {missing}"


@pytest.mark.parametrize("command", sorted(set(COMMANDS) - NO_OUTPUT))
def test_writers_have_o_and_out(command):
    opts = _options(COMMANDS[command])
    assert "--out" in opts and "-o" in opts and opts["-o"] is opts["--out"], command


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_progress_commands_have_q_and_quiet(command):
    opts = _options(COMMANDS[command])
    if command in PROGRESS:
        assert "--quiet" in opts and "-q" in opts and opts["-q"] is opts["--quiet"], command
    if "--no-progress" in opts:  # kept for older scripts, hidden, the same switch
        assert opts["--no-progress"].help == argparse.SUPPRESS and opts["--no-progress"].dest == "quiet", command
    if "--quiet" in opts:
        assert "-q" in opts, command


def test_no_progress_is_an_alias_of_quiet():
    args = build_parser().parse_args(["train", "--model", "sanet", "--data", "x.h5", "--no-progress"])
    assert args.quiet is True
    args = build_parser().parse_args(["reproduce", "-o", "r", "--no-progress"])
    assert args.quiet is True


def test_quiet_silences_summary_lines(tmp_path, capsys):
    mesh = tmp_path / "box.ply"
    trimesh.creation.box(extents=[2, 1, 1]).export(mesh)
    assert main(["encode", str(mesh), "-o", str(tmp_path / "a.npz")]) == 0
    assert "hit ratio" in capsys.readouterr().out
    assert main(["encode", str(mesh), "-o", str(tmp_path / "b.npz"), "-q"]) == 0
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""
    assert (tmp_path / "b.npz").read_bytes() == (tmp_path / "a.npz").read_bytes()


def _examples(text: str) -> list[str]:
    """Command lines ``spotlights ...`` in a text (comments after two spaces and # dropped)."""
    lines = []
    for line in text.splitlines():
        line = line.strip().lstrip("$ ").strip()
        if not line.startswith("spotlights "):
            continue
        line = re.split(r"\s+#", line)[0]
        if re.search(r"\{[^}]*,[^}]*\}|\[--", line):
            continue  # a usage synopsis ({a,b} choices, [--optional]), not an example
        lines.append(line)
    return lines


def _parses(line: str) -> str | None:
    """None when ``line`` parses with the real parser, else argparse's complaint."""
    import contextlib
    import io

    argv = shlex.split(line)[1:]
    argv = [a for a in argv if a not in ("\\",)]
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            build_parser().parse_args(argv)
    except SystemExit as exc:
        return None if exc.code == 0 else err.getvalue().strip().splitlines()[-1]
    return None


def test_help_examples_parse():
    texts = [EPILOG] + [p.epilog or "" for p in COMMANDS.values()]
    bad = {line: why for t in texts for line in _examples(t) if (why := _parses(line))}
    assert not bad, bad


def test_docs_examples_parse():
    """Every ``spotlights ...`` line inside a code block of the README and docs/ parses."""
    bad = {}
    for path in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        text = path.read_text()
        blocks = re.findall(r"```(?:bash|sh|console|shell)?\n(.*?)```", text, flags=re.S)
        joined = "\n".join(b.replace("\\\n", " ") for b in blocks)
        for line in _examples(joined):
            why = _parses(line)
            if why:
                bad[f"{path.name}: {line}"] = why
    assert not bad, bad
