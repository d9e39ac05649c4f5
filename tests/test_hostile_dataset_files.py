"""Hostile data files, each answered with the file's one-line error (exit
code 2, no traceback) instead of a JSONDecodeError / ValueError / AttributeError or a silently wrong run:
damaged JSON or integer attributes of completion datasets and real-observation files, partial scans that hold
NaN or infinities, are not floating point or have the wrong number of points, and files without /samples."""

from __future__ import annotations

import re
import shutil

import h5py
import numpy as np
import pytest

from spotlights.data.store import int_attribute, json_attribute, open_dataset
from spotlights.errors import InputFileError, ProcessFailure, SpotlightsError

from builders import build_reference, small_cfg, write_box_meshes
from helpers import assert_user_error, run_cli
from learning_fixtures import make_checkpoint


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    """Three small models in two categories (the dataset tests' meshes)."""
    return write_box_meshes(tmp_path_factory.mktemp("meshes"))


@pytest.fixture(scope="module")
def reference(meshes, tmp_path_factory):
    """A 3-model, 18-sample dataset of ``meshes``."""
    return build_reference(meshes, tmp_path_factory.mktemp("ref") / "ref.h5")


def damaged(reference, tmp_path, change, name="bad.h5"):
    """A copy of the reference dataset in ``tmp_path`` with ``change(h5py.File)`` applied."""
    out = tmp_path / name
    shutil.copy(reference, out)
    with h5py.File(out, "a") as f:
        change(f)
    return out


def set_attr(key, value):
    def change(f):
        f.attrs[key] = value

    return change


def set_partial(edit):
    def change(f):
        p = f["samples/partial"][...]
        del f["samples/partial"]
        f["samples/partial"] = edit(p)

    return change


def with_nan(p):
    p = p.copy()
    p[:, :5] = np.nan
    return p


ATTRIBUTES = [
    ("config_json", "{bad", "damaged config_json attribute: not valid JSON"),
    ("config_json", "[1,2]", "damaged config_json attribute: a JSON list, expected a JSON object"),
    ("sensor_json", "{bad", "damaged sensor_json attribute: not valid JSON"),
    ("sensor_json", "3", "damaged sensor_json attribute: a JSON int, expected a JSON object"),
    ("views_per_model", "abc", "damaged views_per_model attribute: 'abc' is not an integer"),
    ("views_per_model", -4, "damaged views_per_model attribute: -4 is below 0"),
    ("seed", 1.5, "damaged seed attribute"),
    ("seed", [1, 2], "damaged seed attribute: '[1, 2]' is not an integer"),
    ("config_json", ["{}", "{}"], "damaged config_json attribute: not a JSON string"),
    ("skipped_json", "[1", "damaged skipped_json attribute: not valid JSON"),
    ("skipped_json", '{"a": 1}', "damaged skipped_json attribute: a JSON object, expected a JSON list"),
    ("skipped_json", "[1]", "damaged skipped_json attribute: expected a list of"),
    ("format_version", "abc", "damaged format_version attribute"),
]


@pytest.mark.timeout(120)
@pytest.mark.parametrize("key, value, message", ATTRIBUTES)
def test_damaged_attributes_are_the_files_one_line_error(reference, tmp_path, key, value, message):
    bad = damaged(reference, tmp_path, set_attr(key, value))
    for args in (
        ["dataset", "info", bad],
        ["dataset", "info", bad, "--json"],
        ["dataset", "show", bad, "--split", "test", "--index", "0", "--out", tmp_path / "s.png"],
        ["dataset", "export", bad, "--split", "val", "--index", "0", "--out", tmp_path / "s.npz"],
    ):
        assert_user_error(run_cli(*args), f"{bad}: {message}")
    with pytest.raises(InputFileError, match=re.escape(message)):
        open_dataset(bad)


@pytest.mark.timeout(120)
def test_damaged_attribute_stops_train(reference, tmp_path):
    bad = damaged(reference, tmp_path, set_attr("config_json", "[1,2]"))
    proc = run_cli("train", "--model", "pcn", "--data", bad, "--epochs", "1", "--out", tmp_path / "run", "-q")
    assert_user_error(proc, f"{bad}: damaged config_json attribute")


@pytest.mark.timeout(120)
def test_damaged_rig_json_names_the_rig(reference, tmp_path):
    bad = damaged(reference, tmp_path, lambda f: None)
    with h5py.File(bad, "a") as f:
        f["rigs/cap-64x32-60"].attrs["rig_json"] = "[1, 2]"
    with open_dataset(bad) as ds:
        with pytest.raises(InputFileError, match="/rigs/cap-64x32-60 rig_json attribute: a JSON list"):
            ds.rig_dict("cap-64x32-60")
        assert ds.rig_dict()["n_primary"] == 32  # the other rig reads


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    "edit, message",
    [
        (with_nan, "/samples/partial[6]: partial scans contain NaN or infinite coordinates"),
        (lambda p: np.where(np.arange(len(p))[:, None, None] == 7, np.inf, p), "/samples/partial[7]: partial scans"),
        (lambda p: p.astype(np.int8), "/samples/partial holds int8 values, expected floating-point coordinates"),
        (lambda p: p[:, :100], "/samples/partial has shape (18, 100, 3), expected (18, 256, 3)"),
        (lambda p: p[:, :, :2], "/samples/partial has shape (18, 256, 2), expected (18, 256, 3)"),
        (lambda p: p[:10], "/samples/partial has shape (10, 256, 3), expected (18, 256, 3)"),
    ],
)
def test_evaluate_refuses_partials_that_are_not_finite_float_scans(reference, tmp_path, edit, message):
    bad = damaged(reference, tmp_path, set_partial(edit))
    ckpt = make_checkpoint(tmp_path / "pcn.pt", "pcn")
    out = tmp_path / "report"
    proc = run_cli("evaluate", "--data", bad, "--checkpoint", ckpt, "--examples", "0", "--out", out, "-q")
    assert_user_error(proc, f"{bad}: {message}")
    assert not out.with_suffix(".md").exists()


@pytest.mark.timeout(120)
@pytest.mark.parametrize("lazy, workers", [(False, 0), (True, 0), (True, 2)])
def test_train_refuses_nan_partials(reference, tmp_path, lazy, workers):
    """With lazy reading in DataLoader worker processes (``workers`` 2) the file's error came back as torch's
    RuntimeError and its traceback: torch rebuilds a worker's exception from its message alone."""
    bad = damaged(reference, tmp_path, set_partial(with_nan))
    args = ["train", "--model", "pcn", "--data", bad, "--epochs", "1", "--out", tmp_path / "run", "-q"]
    if lazy:  # partials read one sample at a time (in this process, or in DataLoader workers)
        (tmp_path / "lazy.yaml").write_text(f"data:\n  partials_in_memory: false\n  num_workers: {workers}\n")
        args += ["--config", tmp_path / "lazy.yaml"]
    proc = run_cli(*args)
    assert_user_error(proc, f"{bad}: /samples/partial[0]: partial scans contain NaN or infinite")
    assert "DataLoader" not in proc.stderr and "Original Traceback" not in proc.stderr, proc.stderr
    assert not (tmp_path / "run").exists()


@pytest.mark.timeout(60)
def test_reader_checks_partials_where_it_reads_them(reference, tmp_path):
    bad = damaged(reference, tmp_path, set_partial(lambda p: np.where(np.arange(18)[:, None, None] == 6, np.nan, p)))
    with open_dataset(bad) as ds:  # the header is sound: the file opens
        with pytest.raises(InputFileError, match=r"partial\[6\]: partial scans contain NaN"):
            ds.partials([0, 6])
        with pytest.raises(InputFileError, match=r"partial\[6\]"):
            ds.partial(6)
        with pytest.raises(InputFileError, match=r"partial\[6\]"):
            ds.sample(6)
        assert np.isfinite(ds.partials(np.arange(6))).all() and np.isfinite(ds.partial(5)).all()
    with open_dataset(reference) as ds:
        assert ds.partials(np.arange(ds.n_samples)).shape == (18, 256, 3)


@pytest.mark.timeout(60)
@pytest.mark.parametrize("missing", ["samples", "samples/model", "models", "models/split", "rigs"])
def test_file_without_a_group_names_it(reference, tmp_path, missing):
    def change(f):
        del f[missing]

    bad = damaged(reference, tmp_path, change)
    proc = run_cli("dataset", "info", bad)
    assert_user_error(proc, f"{bad}: incomplete dataset file: missing /{missing}")
    assert "synchronously" not in proc.stderr


@pytest.mark.timeout(60)
def test_a_group_that_is_a_dataset_is_named(reference, tmp_path):
    def change(f):
        del f["samples"]
        f["samples"] = np.zeros(3)

    bad = damaged(reference, tmp_path, change)
    assert_user_error(run_cli("dataset", "info", bad), f"{bad}: /samples is not a group")


@pytest.mark.timeout(180)
def test_shards_are_checked_one_by_one(meshes, reference, tmp_path):
    from spotlights.data.synthetic import build_dataset

    index = tmp_path / "sh.json"
    build_dataset(small_cfg(meshes), index, shard_size=6, progress=False, log=lambda m: None)  # 3 shards
    with open_dataset(index) as a, open_dataset(reference) as b:
        assert a.config == b.config and a.info()["skipped"] == b.info()["skipped"] == []
    shard = tmp_path / "sh-00001-of-00003.h5"
    with h5py.File(shard, "a") as f:
        f.attrs["config_json"] = "{bad"
    assert_user_error(run_cli("dataset", "info", index), f"{shard}: damaged config_json attribute: not valid JSON")


def make_observations(tmp_path):
    """A small real-observation file (one scan, two vehicles) made by 'real extract'."""
    from spotlights.data.real import open_reader
    from spotlights.data.real.extract import ExtractConfig, extract, write_observations

    from builders import make_scene

    make_scene(tmp_path)
    obs = extract(open_reader(tmp_path / "scan.npy", "generic"), ExtractConfig(min_points=5), progress=False)
    return write_observations(tmp_path / "obs.h5", obs)


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    "key, value, message",
    [
        ("config_json", "{bad", "damaged config_json attribute: not valid JSON"),
        ("config_json", "[1, 2]", "damaged config_json attribute: a JSON list, expected a JSON object"),
        ("skipped_json", "[1", "damaged skipped_json attribute: not valid JSON"),
        ("skipped_labels_json", "null", "damaged skipped_labels_json attribute: a JSON null"),
        ("n_boxes", "many", "damaged n_boxes attribute: 'many' is not an integer"),
    ],
)
def test_damaged_real_observation_attributes(tmp_path, key, value, message):
    from spotlights.data.real.extract import read_observations

    path = make_observations(tmp_path)
    assert read_observations(path).meta["config"]["min_points"] == 5
    with h5py.File(path, "a") as f:
        f.attrs[key] = value
    with pytest.raises(InputFileError, match=re.escape(message)):
        read_observations(path)
    assert_user_error(run_cli("real", "show", path, "--out", tmp_path / "x.png"), f"{path}: {message}")
    assert_user_error(run_cli("view", path, "--out", tmp_path / "x.html"), f"{path}: {message}")


@pytest.mark.timeout(60)
def test_json_and_int_attribute_helpers():
    attrs = {"d": '{"a": 1}', "l": b"[1, 2]", "bad": "{", "num": 5, "deep": "[" * 100000, "n": np.int64(4)}
    assert json_attribute("f.h5", attrs, "d", dict) == {"a": 1}
    assert json_attribute("f.h5", attrs, "l", list) == [1, 2]
    assert json_attribute("f.h5", attrs, "absent", dict, {}) == {}
    for key, kind, message in (
        ("d", list, "f.h5: damaged d attribute: a JSON object, expected a JSON list"),
        ("bad", dict, "f.h5: damaged bad attribute: not valid JSON"),
        ("deep", list, "f.h5: damaged deep attribute: not valid JSON"),
        ("num", dict, "f.h5: damaged num attribute: not a JSON string"),
        ("absent", dict, "f.h5: damaged dataset file: no absent attribute"),
    ):
        with pytest.raises(InputFileError) as err:
            json_attribute("f.h5", attrs, key, kind)
        assert str(err.value) == message
    assert int_attribute("f.h5", attrs, "n", 0) == 4 and int_attribute("f.h5", attrs, "absent", 7) == 7
    assert int_attribute("f.h5", {"x": 3.0}, "x", 0) == 3
    for value in ("3", True, 2.5, float("nan"), b"x"):
        with pytest.raises(InputFileError, match="f.h5: damaged x attribute"):
            int_attribute("f.h5", {"x": value}, "x", 0)


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    "key, message", [("partial", "partial scans contain NaN"), ("box_size", "box sizes must be finite")]
)
def test_observations_with_nan_rows_name_the_file_and_row(tmp_path, key, message):
    """``real evaluate``/``real show`` said "partial scans contain NaN ..." without naming the file."""
    import h5py

    from spotlights.data.real.extract import read_observations

    src = make_observations(tmp_path)
    with h5py.File(src, "a") as f:
        a = f[f"observations/{key}"][...]
        a[1] = np.nan
        f[f"observations/{key}"][...] = a
    with pytest.raises(InputFileError, match=f"{src.name}: observations/{key}\\[1\\]: {message}"):
        read_observations(src)


class _Failing:
    """A map-style dataset whose item 1 raises ``error`` (in a DataLoader worker process)."""

    def __init__(self, error):
        self.error = error

    def __len__(self):
        return 3

    def __getitem__(self, i):
        if i == 1:
            raise self.error
        return i


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    "error, code",
    [
        (InputFileError("/data/d.h5", "/samples/partial[1]: NaN"), 2),  # torch rebuilt it as RuntimeError
        (SpotlightsError("/data/d.h5: a damaged sample"), 2),  # torch rebuilt it with the traceback as its message
        (ProcessFailure("a helper died: run again"), 1),
    ],
)
def test_worker_errors_come_out_as_their_one_line(error, code):
    from torch.utils.data import DataLoader

    from spotlights.learning.data import worker_batches

    loader = DataLoader(_Failing(error), batch_size=1, num_workers=1)
    with pytest.raises(SpotlightsError) as caught:
        list(worker_batches(loader))
    assert str(caught.value) == str(error) and caught.value.exit_code == code
    assert [int(b) for b in worker_batches(DataLoader(_Failing(error), batch_size=1, sampler=[0, 2]))] == [0, 2]
    with pytest.raises(RuntimeError, match="not ours"):  # other errors pass through as they are
        list(worker_batches(DataLoader(_Failing(RuntimeError("not ours")), batch_size=1, num_workers=1)))


class _ChainedFailing(_Failing):
    def __getitem__(self, i):
        try:
            raise InputFileError("/x.h5", "bad sample")
        except InputFileError as exc:
            raise RuntimeError("a bug while handling it") from exc


@pytest.mark.timeout(60)
def test_worker_errors_keep_a_bug_caused_by_an_input_error_and_a_whole_message():
    """A RuntimeError raised from an InputFileError is a bug, not the input's one line; a message of two lines
    comes out whole."""
    from torch.utils.data import DataLoader

    from spotlights.learning.data import worker_batches

    with pytest.raises(RuntimeError, match="a bug while handling it"):
        list(worker_batches(DataLoader(_ChainedFailing(None), batch_size=1, num_workers=1)))
    two = SpotlightsError("line one\nline two")
    with pytest.raises(SpotlightsError) as caught:
        list(worker_batches(DataLoader(_Failing(two), batch_size=1, num_workers=1)))
    assert str(caught.value) == "line one\nline two"
