"""The ``spotlights`` command's entry point (``spotlights.entry.main``: the console script and ``python -m
spotlights``): a Ctrl-C while the command line's modules load gives one line and exit code 130, never a traceback."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap

import pytest

# A Ctrl-C sent to the process at the moment `spotlights.cli` starts to load (an import hook sends it), then the
# entry point called as the console script calls it. Deterministic: no race with a timer.
CHILD = textwrap.dedent(
    """
    import importlib.abc, os, signal, sys

    class CtrlCOnImport(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "spotlights.cli":
                sys.meta_path.remove(self)
                os.kill(os.getpid(), signal.SIGINT)
            return None

    sys.meta_path.insert(0, CtrlCOnImport())
    sys.argv = ["spotlights", "--version"]
    from {module} import main
    sys.exit(main())
    """
)


def _as_from_a_terminal() -> None:
    """Child processes start with SIGINT at its default, as a command typed in a terminal does: a test run launched
    as a background job (``make test &``) passes SIG_IGN down, and Python then keeps ignoring Ctrl-C (rightly so
    for a background command), which would leave nothing to test."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _run(module: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", CHILD.format(module=module)],
        capture_output=True,
        text=True,
        timeout=60,
        preexec_fn=_as_from_a_terminal,
    )


@pytest.mark.timeout(90)
def test_ctrl_c_while_the_command_line_loads_gives_one_line_and_130():
    r = _run("spotlights.entry")
    assert r.returncode == 130, (r.returncode, r.stderr)
    assert r.stderr.strip().splitlines() == ["spotlights: interrupted"]
    assert "Traceback" not in r.stderr and r.stdout == ""


@pytest.mark.timeout(90)
def test_the_same_ctrl_c_through_cli_main_directly_is_a_traceback():
    """The check above can fail: importing ``spotlights.cli`` unguarded (the console script's target before) lets
    the same Ctrl-C out as a traceback."""
    r = _run("spotlights.cli")
    assert r.returncode != 130 and "KeyboardInterrupt" in r.stderr


@pytest.mark.timeout(90)
def test_the_console_script_and_python_m_use_the_guarded_entry():
    import tomllib
    from pathlib import Path

    project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    assert project["project"]["scripts"]["spotlights"] == "spotlights.entry:main"
    main = (Path(__file__).resolve().parents[1] / "src" / "spotlights" / "__main__.py").read_text()
    assert "from .entry import main" in main
    r = subprocess.run([sys.executable, "-m", "spotlights", "--version"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.strip()


FAKE_HEAVY = textwrap.dedent(
    """
    import os, signal, time
    os.kill(os.getpid(), signal.SIGINT)  # a Ctrl-C in the middle of this package's first import
    total = sum(range(100000))  # bytecodes run: an interrupt not deferred is raised here
    time.sleep(0.05)
    open(os.environ["MARKER"], "w").write(str(total))  # the import ran to its end
    """
)

IMPORTER = textwrap.dedent(
    """
    import sys
    from spotlights.entry import guard_imports
    if sys.argv[1] == "guarded":
        guard_imports(["fakeheavy"])
    try:
        import fakeheavy
    except KeyboardInterrupt:
        print("interrupted")
    """
)


@pytest.mark.timeout(90)
@pytest.mark.parametrize("mode", ["guarded", "plain"])
def test_a_ctrl_c_during_a_guarded_import_comes_once_the_import_is_complete(tmp_path, mode):
    """guard_imports: the package's first import runs to its end (the marker is written), then the Ctrl-C comes as
    a KeyboardInterrupt; without the guard it lands in the middle (no marker). (torch's C++ initialisers abort the
    process on an interrupt in their middle; this package stands in for them.)"""
    import os

    (tmp_path / "fakeheavy").mkdir()
    (tmp_path / "fakeheavy" / "__init__.py").write_text(FAKE_HEAVY)
    marker = tmp_path / "marker"
    env = {**os.environ, "MARKER": str(marker), "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    r = subprocess.run(
        [sys.executable, "-c", IMPORTER, mode],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        cwd=tmp_path,
        preexec_fn=_as_from_a_terminal,
    )
    assert r.returncode == 0 and r.stdout.strip() == "interrupted", (r.returncode, r.stdout, r.stderr)
    assert marker.exists() == (mode == "guarded")


@pytest.mark.timeout(90)
def test_outside_guarded_imports_a_ctrl_c_is_a_keyboard_interrupt_even_when_guarded_twice():
    code = textwrap.dedent(
        """
        import os, signal
        from spotlights.entry import guard_imports
        guard_imports()
        guard_imports(["json"])
        try:
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(100000):
                pass
        except KeyboardInterrupt:
            print("interrupted")
        """
    )
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, preexec_fn=_as_from_a_terminal
    )
    assert r.returncode == 0 and r.stdout.strip() == "interrupted", (r.returncode, r.stderr[-500:])
