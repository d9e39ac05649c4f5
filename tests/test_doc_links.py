"""Every relative link of the Markdown docs resolves, and every reference page stays short.

Links are ``[text](target)`` and ``![alt](target)`` outside code blocks and code spans, in README.md and every
tracked ``.md`` file under ``docs/``. A target with a scheme (``https:``, ``mailto:``) is skipped; a relative target must name a file or folder,
relative to the page, and its anchor (``page.md#section``, or ``#section`` on the same page) one of that page's
headings.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
MAX_LINES = 500  # a reference or study page under docs/ (docs/results/ holds generated reports)


def _pages() -> list[str]:
    try:
        out = subprocess.run(["git", "ls-files", "-z", "README.md", "docs"], cwd=REPO, capture_output=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the tracked pages are not known")
    return [p for p in out.stdout.decode().split("\0") if p.endswith(".md")]


def _links(text: str) -> list[tuple[int, str]]:
    """(line number, target) of every link outside fenced code blocks and inline code spans."""
    found, fence = [], False
    for no, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            fence = not fence
            continue
        if fence:
            continue
        for m in LINK.finditer(re.sub(r"`[^`]*`", "", line)):
            found.append((no, m.group(1)))
    return found


def _anchors(text: str) -> set[str]:
    """GitHub's anchors of a page's headings: lower case, punctuation dropped, spaces as hyphens, ``-N`` for
    the N-th repeat of a heading."""
    seen: dict[str, int] = {}
    anchors, fence = set(), False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fence = not fence
        m = None if fence else re.match(r"^#{1,6} (.*)$", line)
        if m:
            slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            anchors.add(slug if n == 0 else f"{slug}-{n}")
    return anchors


def test_heading_anchors_by_hand():
    text = "# Speed and size (`spotlights bench models`)\n```\n# not a heading\n```\n## Notes\n## Notes\n"
    assert _anchors(text) == {"speed-and-size-spotlights-bench-models", "notes", "notes-1"}


def test_the_link_parser_on_a_hand_written_page():
    text = "see [a](a.md#x) and ![p](img/p.png)\n```\n[no](inside.md)\n```\n`[no](span.md)` [w](https://x.org)\n"
    assert _links(text) == [(1, "a.md#x"), (1, "img/p.png"), (5, "https://x.org")]


def test_every_relative_link_resolves():
    broken = []
    for page in _pages():
        path = REPO / page
        for no, target in _links(path.read_text(encoding="utf-8")):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target):
                continue
            rel, _, anchor = target.partition("#")
            dest = path.parent / rel if rel else path
            if not dest.exists():
                broken.append(f"{page}:{no}: {target}")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest.read_text(encoding="utf-8")):
                broken.append(f"{page}:{no}: {target} (no such heading)")
    assert not broken, f"{len(broken)} links resolve to nothing:\n" + "\n".join(broken)


def test_every_doc_page_is_at_most_500_lines():
    long = []
    for page in _pages():
        if page.startswith("docs/") and not page.startswith("docs/results/"):
            n = len((REPO / page).read_text(encoding="utf-8").splitlines())
            if n > MAX_LINES:
                long.append(f"{page}: {n} lines")
    assert not long, f"pages over {MAX_LINES} lines (split them by topic):\n" + "\n".join(long)
