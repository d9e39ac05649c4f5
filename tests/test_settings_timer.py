"""The one settings policy (unknown keys are errors with a suggestion) and the one stage timer."""

from __future__ import annotations

import dataclasses
import time

import pytest

from spotlights.errors import InputFileError, ParameterError
from spotlights.options import settings_from_dict
from spotlights.timing import StageTimer


@dataclasses.dataclass
class _Settings:
    views: int = 4
    rig: str = "box"


def test_settings_known_keys_build_the_dataclass():
    assert settings_from_dict(_Settings, {"views": 7}) == _Settings(views=7, rig="box")
    assert settings_from_dict(_Settings, None) == _Settings()


def test_settings_unknown_key_names_file_and_suggests():
    with pytest.raises(InputFileError) as e:
        settings_from_dict(_Settings, {"veiws": 7}, "build.yaml")
    msg = str(e.value)
    assert msg.startswith("build.yaml: ") and "'veiws'" in msg and "did you mean 'views'" in msg


def test_settings_label_and_non_mapping():
    with pytest.raises(ParameterError, match=r"^sensor: expected a mapping"):
        settings_from_dict(_Settings, [1, 2], "sensor")
    with pytest.raises(ParameterError, match=r"^sensor: unknown setting 'zzz'"):
        settings_from_dict(_Settings, {"zzz": 1}, "sensor")


def test_stage_timer_sums_repeated_stages_against_a_sleep():
    t = StageTimer()
    for _ in range(2):
        with t("sleep"):
            time.sleep(0.02)
    with t("nothing"):
        pass
    assert list(t.seconds) == ["sleep", "nothing"]
    assert t.counts == {"sleep": 2, "nothing": 1}
    assert 0.04 <= t.seconds["sleep"] < 1.0
    assert t.total == pytest.approx(t.seconds["sleep"] + t.seconds["nothing"])
    t.add("outside", 1.5)
    assert t.rounded(1)["outside"] == 1.5


def test_stage_timer_laps_split_straight_line_code_against_sleeps():
    t = StageTimer()
    time.sleep(0.02)
    first = t.lap("a")
    with t("inside"):  # a block inside a lap counts for both
        time.sleep(0.01)
    t.lap("b")
    t.lap("b")  # an immediate lap: about nothing
    assert list(t.seconds) == ["a", "inside", "b"] and t.counts["b"] == 2
    assert first == t.seconds["a"] and 0.02 <= first < 1.0
    assert 0.01 <= t.seconds["b"] < 1.0 and t.seconds["inside"] <= t.seconds["b"]
