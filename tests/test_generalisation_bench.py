"""benchmarks/generalisation.py's body-type hold-out: the cut of one test split into held-out and other
categories, against hand-computed scan-weighted means."""

from __future__ import annotations

import pytest

from helpers import load_script

pytest.importorskip("torch")


def _bench():
    return load_script("benchmarks/generalisation.py")


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


def test_a_hold_out_is_refused_when_its_category_was_trained_on_or_is_not_in_test(tmp_path):
    from learning_fixtures import write_tiny_dataset

    layout = (("sedan", "train"), ("hatchback", "train"), ("sedan", "val"), ("sedan", "test"), ("suv", "test"))
    path = write_tiny_dataset(tmp_path / "d.h5", views=2, layout=layout, n_gt=64, n_dense=64)
    bench = _bench()
    assert bench.held_out_category_problem(path, ["suv"]) is None  # suv only in test: a true hold-out
    assert "train split has sedan models" in bench.held_out_category_problem(path, ["sedan", "suv"])
    assert "test split has no van models" in bench.held_out_category_problem(path, ["van"])
