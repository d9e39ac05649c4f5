"""Hostile inputs found by the third fuzzing pass (stop 42): encodings whose arrays have the wrong type or shape,
JSON integers beyond 64 bits, and two ``train`` runs writing one run folder at once."""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.errors import InputFileError, SpotlightsError
from spotlights.geometry.encode import load_encoding

from helpers import assert_user_error, run_cli


def _encoding(**changes) -> dict:
    """The arrays of a valid 4 x 8 cap encoding (written without the ``rig`` key: the old layout), then ``changes``
    (a value None removes the key)."""
    arrays = {
        "depths": np.full(32, 0.5, np.float32),
        "center": np.zeros(3),
        "radius": np.float64(2.0),
        "rotation": np.eye(3),
        "primary": np.int64(4),
        "secondary": np.int64(8),
        "angle": np.float64(60.0),
    }
    arrays.update(changes)
    return {k: v for k, v in arrays.items() if v is not None}


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    "changes, message",
    [
        ({}, None),  # the valid one reads
        ({"depths": np.array(["a"] * 32)}, "depths holds <U1 values, expected real numbers"),
        ({"depths": np.ones(32, bool)}, "depths holds bool values"),
        ({"depths": np.full(32, 0.5 + 0j, np.complex64)}, "depths holds complex64 values"),
        ({"radius": np.ones(5)}, "radius must be a real number, got a float64 array of shape (5,)"),
        ({"primary": np.arange(3)}, "primary must be a whole number"),
        ({"primary": np.float64(4.7)}, "primary must be a whole number"),
        ({"angle": np.str_("sixty")}, "angle must be a real number"),
        ({"rotation": np.eye(2)}, "invalid rig or normalisation"),
        ({"rig": np.str_("[1, 2]")}, "invalid rig or normalisation"),
    ],
)
def test_an_encoding_with_wrong_arrays_is_the_files_one_line_error(tmp_path, changes, message):
    """These were TypeErrors and ValueErrors from deep in the reader (exit 1, a traceback) in decode, show and view."""
    path = tmp_path / "e.npz"
    np.savez(path, **_encoding(**changes))
    if message is None:
        enc = load_encoding(path)
        assert enc.rig.n_rays == 32 and float(enc.depths[0]) == 0.5
        return
    with pytest.raises(InputFileError) as err:
        load_encoding(path)
    assert message in str(err.value) and str(err.value).startswith(str(path)), str(err.value)
    proc = run_cli("decode", path, "--out", tmp_path / "p.ply")
    assert_user_error(proc, message)
    assert not (tmp_path / "p.ply").exists()


@pytest.mark.timeout(60)
def test_a_box_file_with_an_integer_beyond_64_bits_is_one_line(tmp_path):
    """``"center": [10**400, 0, 0]`` in a generic box file was an OverflowError traceback (float64 cannot hold it)."""
    boxes = tmp_path / "boxes.json"
    boxes.write_text('[{"center": [1' + "0" * 400 + ', 0, 0], "size": [4, 2, 1.5], "yaw": 0, "label": "car"}]')
    np.save(tmp_path / "scan.npy", np.zeros((10, 3), np.float32))
    proc = run_cli("complete", tmp_path / "scan.npy", "--box", boxes, "--out", tmp_path / "c.ply", "-q")
    assert_user_error(proc, f"{boxes}: holds an integer beyond 64 bits")
    assert not (tmp_path / "c.ply").exists()


@pytest.mark.timeout(120)
def test_two_trainings_into_one_run_folder_are_refused(tmp_path):
    """Two ``train`` runs into one ``--out`` both exited 0 and both reported their checkpoints; the folder held one
    model's files (or a mix). The second is now refused while the first holds the folder's lock."""
    from spotlights.learning.train import train
    from spotlights.utils import exclusive_lock

    from learning_fixtures import tiny_dataset_path, tiny_overrides

    data = tiny_dataset_path(tmp_path / "data")
    run = tmp_path / "run"
    run.mkdir()
    with exclusive_lock(run / ".train.lock", "held by the test"):  # what a running 'spotlights train' holds
        with pytest.raises(SpotlightsError, match="another 'spotlights train' is writing this run folder"):
            train("pcn", data, run, overrides=tiny_overrides("pcn", epochs=1), progress=False, log=lambda *a: None)
    assert sorted(p.name for p in run.iterdir()) == [".train.lock"]  # the refused run wrote nothing
    res = train("pcn", data, run, overrides=tiny_overrides("pcn", epochs=1), progress=False, log=lambda *a: None)
    assert res["epochs"] == 1 and not (run / ".train.lock").exists()  # the lock goes with the run
    assert sorted(p.name for p in run.iterdir()) == [
        "best.pt",
        "config.yaml",
        "last.pt",
        "log.csv",
    ]


@pytest.mark.timeout(30)
def test_an_unwritable_folder_is_named_by_the_output_not_its_temporary(tmp_path, monkeypatch):
    """Writing into a folder the user may not write named the hidden temporary
    (``.summary.json.15598-5lueg2kh.part.json: permission denied``) instead of ``summary.json``."""
    import errno
    import tempfile

    from spotlights.errors import OutputFileError
    from spotlights.utils import atomic_output

    def refused(prefix="", suffix="", dir=None):
        name = f"{dir}/{prefix}abcd1234{suffix}"
        raise PermissionError(errno.EACCES, "Permission denied", name)

    monkeypatch.setattr(tempfile, "mkstemp", refused)
    target = tmp_path / "summary.json"
    with pytest.raises(OutputFileError) as err:
        with atomic_output(target) as tmp:
            tmp.write_text("{}")
    assert str(err.value).startswith(f"{target}: cannot write") and ".part" not in str(err.value), str(err.value)
