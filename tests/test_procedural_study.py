"""The procedural study (docs/studies/procedural.md) quotes the committed results it comes from."""

from __future__ import annotations

import json
import re

from helpers import REPO

RESULTS = REPO / "docs" / "results" / "procedural"
STUDY = REPO / "docs" / "studies" / "procedural.md"


def _text() -> str:
    return re.sub(r"\s+", " ", STUDY.read_text())


def test_study_quotes_the_shape_statistics_and_the_speed():
    stats = json.loads((RESULTS / "shape_stats.json").read_text())
    text = _text()
    speed = stats["generation_one_core"]
    assert f"**{speed['bodies_per_second_all_types']:.1f} bodies per second**" in text
    ab, tb = speed["per_body"]["articulated_bus"], speed["per_body"]["trailer_box"]
    assert f"articulated buses {ab['bodies_per_second']:.1f}/s, {ab['faces_median']:,} faces" in text
    assert f"box trailers {tb['bodies_per_second']:,.1f}/s, {tb['faces_median']:,} faces" in text
    # every row of the study's table is the Markdown the benchmark wrote from the JSON
    table = (RESULTS / "shape_stats.md").read_text().splitlines()
    rows = [
        r for r in STUDY.read_text().splitlines() if r.startswith("| ") and r.split(" | ")[0][2:] in stats["groups"]
    ]
    assert len(rows) >= 10
    for row in rows:
        assert row in table, row


def test_study_quotes_the_realism_run():
    res = json.loads((RESULTS / "realism.json").read_text())
    table = (RESULTS / "realism.md").read_text()
    text = _text()
    assert re.sub(r"\s+", " ", table).strip() in text
    assert f"**{res['ratio_procedural_over_apollo_on_apollo_test']:.2f}x**" in text
    assert f"{res['cpu_minutes_total']:.1f} CPU minutes" in text
