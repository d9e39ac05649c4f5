"""benchmarks/generalisation.py's body-type hold-out: the cut of one test split into held-out and other
categories, against hand-computed scan-weighted means."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

pytest.importorskip("torch")

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("generalisation", ROOT / "benchmarks" / "generalisation.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_split_by_category_weights_each_category_by_its_scans():
    row = {
        "scans_per_category": {"hatchback": 50, "sedan": 150, "suv": 150},
        "accuracy_per_category": {"hatchback": 0.020, "sedan": 0.012, "suv": 0.030},
        "completeness_per_category": {"hatchback": 0.030, "sedan": 0.018, "suv": 0.040},
    }
    inside, held = _bench().split_by_category(row, ["suv"])
    assert inside["categories"] == ["hatchback", "sedan"] and inside["scans"] == 200
    assert inside["accuracy"] == pytest.approx((50 * 0.020 + 150 * 0.012) / 200)  # 0.014
    assert inside["completeness"] == pytest.approx((50 * 0.030 + 150 * 0.018) / 200)
    assert held["accuracy"] == pytest.approx(0.030) and held["scans"] == 150
    inside, held = _bench().split_by_category(row, ["pickup"])  # a category with no scans
    assert held["accuracy"] is None and held["scans"] == 0
