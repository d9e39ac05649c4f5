"""``data.source_repeat``: the samples of a named mesh source come K times in each training pass."""

from __future__ import annotations

import shutil
from collections import Counter

import h5py
import numpy as np
import pytest

pytest.importorskip("torch")

from spotlights.errors import ParameterError  # noqa: E402
from spotlights.learning.config import MAX_SOURCE_REPEAT, data_config  # noqa: E402
from spotlights.learning.data import TorchCompletionDataset  # noqa: E402
from spotlights.learning.train import train  # noqa: E402
from spotlights.learning.training_run import repeated_items  # noqa: E402

from learning_fixtures import one_torch_thread, tiny_dataset_path, tiny_overrides  # noqa: E402

pytestmark = pytest.mark.timeout(300)
_single_thread = pytest.fixture(autouse=True)(one_torch_thread)


@pytest.fixture(scope="module")
def two_sources(tmp_path_factory):
    """The tiny dataset with /models/source: the first four models from 'small', the rest from 'large'."""
    base = tmp_path_factory.getbasetemp() / "source-repeat"
    base.mkdir(parents=True, exist_ok=True)
    path = base / "two_sources.h5"
    shutil.copy(tiny_dataset_path(base), path)
    with h5py.File(path, "r+") as f:
        n = len(f["models/name"])
        names = ["small" if i < 4 else "large" for i in range(n)]
        f["models"].create_dataset("source", data=np.array(names, dtype=object), dtype=h5py.string_dtype())
    return path


def test_each_item_of_a_named_source_comes_k_times_in_one_pass(two_sources):
    ds = TorchCompletionDataset(two_sources, "train", rig=False)
    src = ds.sources[ds.sample_models]
    assert {"small", "large"} <= set(src.tolist())
    items = repeated_items(ds, (("small", 3),))
    counts = Counter(items.tolist())
    for i in range(len(ds)):  # brute force: every item, its expected count from its model's source
        assert counts[i] == (3 if src[i] == "small" else 1)
    assert list(items) == sorted(items)
    assert list(repeated_items(ds, None)) == list(range(len(ds)))


def test_repeats_are_checked_and_name_the_key(two_sources):
    ds = TorchCompletionDataset(two_sources, "train", rig=False)
    with pytest.raises(ParameterError, match=r"data.source_repeat names source 'nope'.*sources: large, small"):
        repeated_items(ds, (("nope", 2),))
    for bad, pattern in [
        ([1, 2], "must be a mapping"),
        ({}, "must be a mapping"),
        ({"small": 0}, r"data.source_repeat.small must be >= 1"),
        ({"small": 1.5}, r"data.source_repeat.small must be an integer"),
        ({"small": MAX_SOURCE_REPEAT + 1}, rf"must be <= {MAX_SOURCE_REPEAT}"),
    ]:
        with pytest.raises(ParameterError, match=pattern):
            data_config({"data": {"source_repeat": bad}})
    assert data_config({"data": {"source_repeat": {"b": 2, "a": 1}}}).source_repeat == (("a", 1), ("b", 2))


def _weights(path, out, source_repeat):
    ov = tiny_overrides("pcn", epochs=1, steps_per_epoch=3)
    if source_repeat is not None:
        ov["data"]["source_repeat"] = source_repeat
    train("pcn", path, out, overrides=ov, progress=False, log=lambda *a: None)
    import torch

    state = torch.load(out / "last.pt", map_location="cpu", weights_only=False)["model_state"]
    return np.concatenate([v.detach().float().numpy().ravel() for v in state.values()])


def test_training_sees_the_repeated_stream(two_sources, tmp_path):
    plain = _weights(two_sources, tmp_path / "plain", None)
    once = _weights(two_sources, tmp_path / "once", {"small": 1})  # K = 1 everywhere: the plain stream
    heavy = _weights(two_sources, tmp_path / "heavy", {"small": 5})
    heavy2 = _weights(two_sources, tmp_path / "heavy2", {"small": 5})
    assert np.array_equal(plain, once)
    assert not np.array_equal(plain, heavy)
    assert np.array_equal(heavy, heavy2)
    with pytest.raises(ParameterError, match="data.source_repeat names source 'nope'"):
        _weights(two_sources, tmp_path / "bad", {"nope": 2})
    assert not (tmp_path / "bad" / "last.pt").exists()
