"""No history in the product: names and text say what a thing is, git keeps when and by whom.

Every tracked text file (``git ls-files``; binary files skipped) is read, and its path and each of its lines are
matched against the patterns below: a numbered work step ("stop 38", "stops 33-41", "stop-39"), a numbered
issue of this project ("issue 27", "issue26"), an issue number used as a name token ("i27/", "_i26", "i27box"),
the people or runs that did the work ("the lead", "session", "this stop") and absolute paths of the machine
that ran something (``/work/...``, ``/root/...``, ``/tmp/<name>``). Real words pass: "stop" as a verb, "issue"
as a verb or noun without a number, upstream references (``pytorch#179291``, ``github.com/o/r/issues/12``),
ONNX Runtime's ``InferenceSession`` and ``SessionOptions``, Ray's session folders. Every offending
``file:line`` is printed.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# (name, pattern) - each pattern names one kind of history word
PATTERNS: list[tuple[str, re.Pattern[str]]] = [
    ("numbered stop", re.compile(r"(?<![A-Za-z])stops?[ _-]?#?\s*\d+(?![0-9])", re.IGNORECASE)),
    ("numbered issue", re.compile(r"(?<![A-Za-z])issues?[ _-]?#?\s*\d+(?![0-9])", re.IGNORECASE)),
    ("numbered reference", re.compile(r"(?:^|[\s(])#\d+\b|\bspotlights#\d+", re.IGNORECASE)),
    # an issue number as a name token: "i27/", "_i26", "-i35", "i27box", "(i26)"; not "i386" nor "pi3"
    ("iNN name", re.compile(r"(?<![A-Za-z0-9.])i\d{2}(?![0-9])(?=[A-Za-z_/.\-)\]`'\", ]|$)")),
    ("who did it", re.compile(r"\bthe lead\b(?! (?:vehicle|car|truck|object)s?\b)", re.IGNORECASE)),
    ("session", re.compile(r"\bsessions?\b", re.IGNORECASE)),
    ("when", re.compile(r"\b(?:this|each|every|earlier|later|next|previous|last|same) stops?\b", re.IGNORECASE)),
    ("machine path", re.compile(r"(?<![\w.~$}])/(?:work|root)/|(?<![\w.~$}])/tmp/[A-Za-z0-9_]")),
]

# real words that the patterns above would otherwise catch: (pattern name, regex on the matched line)
ALLOWED: list[tuple[str, re.Pattern[str]]] = [
    ("session", re.compile(r"InferenceSession|SessionOptions|session_options|sess_options|ort\.|onnxruntime")),
    ("session", re.compile(r"\bray\b.*\bsession|\bsession_\d|/session_|session_latest|ray_session", re.IGNORECASE)),
    # ONNX Runtime's session object, pytest's test session, an interpreter's interactive session
    (
        "session",
        re.compile(r"\.session\b|session's intra-op|scope=.session.|\b(?:test|pytest) session|interactive sessions?"),
    ),
    ("machine path", re.compile(r"/tmp/pytest-of-")),  # pytest's own folder for a failed test's files
    ("numbered issue", re.compile(r"github\.com/[\w.-]+/[\w.-]+/issues/\d+|(?!spotlights)[\w.-]+#\d+")),
]

# this file names the patterns it checks for
SKIP = {"tests/test_history.py"}
# (pattern name, file) where the word is a term of the tool the file configures: pytest's session
FILE_ALLOWED = {("session", "tests/conftest.py"), ("session", "pyproject.toml")}


def _tracked_files() -> list[str]:
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the tracked files are not known")
    return [p for p in out.stdout.decode("utf-8", "replace").split("\0") if p and not p.startswith(".git/")]


def _text(path: Path) -> str | None:
    """The file's text, or None for a binary file (a NUL byte or not UTF-8) or one that is gone."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def _allowed(kind: str, line: str) -> bool:
    return any(kind == k and rx.search(line) for k, rx in ALLOWED)


def history_hits(line: str) -> list[str]:
    """The kinds of history word ``line`` holds (empty when it holds none)."""
    return [kind for kind, rx in PATTERNS if rx.search(line) and not _allowed(kind, line)]


def _hits_across(line: str, following: str) -> list[str]:
    """The kinds of history word that start on ``line`` and end on ``following`` (a phrase broken by the wrap)."""
    joined = line.rstrip() + " " + following.lstrip()
    cut = len(line.rstrip())
    return [
        kind
        for kind, rx in PATTERNS
        if any(m.start() < cut < m.end() for m in rx.finditer(joined)) and not _allowed(kind, joined)
    ]


def offenders(prefixes: tuple[str, ...] = ("",)) -> list[str]:
    """``file:line: kind: text`` for every history word in the tracked files under ``prefixes``."""
    found = []
    for rel in _tracked_files():
        if rel in SKIP or not rel.startswith(prefixes):
            continue
        for kind in history_hits(rel):
            found.append(f"{rel}:0: {kind} in the file's name")
        text = _text(REPO / rel)
        if text is None:
            continue
        lines = text.splitlines()
        for no, line in enumerate(lines, 1):
            following = lines[no] if no < len(lines) else ""
            for kind in history_hits(line) + _hits_across(line, following):
                if (kind, rel) in FILE_ALLOWED:
                    continue
                found.append(f"{rel}:{no}: {kind}: {line.strip()[:160]}")
    return found


@pytest.mark.parametrize(
    "line",
    [
        "measured in stop 38",
        "Across stops 33-41",
        "the stop-39 control",
        "tests/test_hostile_inputs_stop41.py",
        "issue 27's target",
        "def test_issue27_rows():",
        "fixed in issue #27",
        "see #27 for the numbers",
        "as spotlights#27 asked",
        "docs/results/i27/classes.json",
        "table1_i26.json",
        "runs/i27box/best.pt",
        "the lead decides",
        "in this session",
        "new in this stop",
        "the comparisons of earlier stops",
        "python x.py --against /work/main/src",
        "--out /tmp/before/x.json",
        "/root/out/a.ply",
    ],
)
def test_history_words_are_caught(line):
    assert history_hits(line), f"{line!r} holds a history word the check should catch"


def test_a_history_word_broken_by_the_line_wrap_is_caught():
    assert _hits_across("the class model, its fallback since stop", "35 (`--fallback auto`)") == ["numbered stop"]
    assert _hits_across("a ray stops at the first hit;", "12 rays miss") == []


@pytest.mark.parametrize(
    "line",
    [
        "Ctrl-C stops the run; stop the worker first",
        "a ray stops at the first hit",
        "this may issue a warning; see the issue tracker",
        "upstream: pytorch#179291 and https://github.com/pytorch/pytorch/issues/179291",
        "sess = onnxruntime.InferenceSession(path, sess_options=opts)",
        "outputs = self.session.run(self.outputs, feed)",
        '@pytest.fixture(scope="session", autouse=True)',
        "one --quick run per test session (module fixture)",
        "Ray writes its session folders under the temp dir (ray/session_latest)",
        "int16 i386 pi32 xi27",
        "tmp = tempfile.mkdtemp(); os.path.join(tmp, 'x')",
        "SITE=${GPU_SITE:-${TMPDIR:-/tmp}/spotlights-site}",
        "unit frame (x forward, y left, z up); i.e. 12 points",
        "the lead vehicle",
    ],
)
def test_real_words_pass(line):
    assert not history_hits(line), f"{line!r} is a real word, not history: {history_hits(line)}"


def test_no_history_in_tracked_files():
    """Fails on any tracked text file whose name or text records when or by whom something was done."""
    found = offenders()
    assert not found, f"{len(found)} history words in tracked files:\n" + "\n".join(found)
