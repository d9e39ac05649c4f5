"""Outputs that cannot be written: a rerun recording named like a folder, inside a file, in a read-only folder, or
on a disk that fills up; a sharded build and a sequence set on a full disk. One line naming the output (exit 2),
and nothing left behind: no temporary, no finished shard without its index, no empty or half folder.

A full disk is simulated in this process: the writer of the output raises what a full disk raises (``ENOSPC``, or
rerun's "File-writer thread shut down prematurely"), so the tests need no small file system."""

from __future__ import annotations

import errno
import json
import os

import numpy as np
import pytest

from helpers import assert_user_error, run_cli, write_box_scan

TINY_BUILD = ["--views", "3", "--gt-points", "64", "--gt-dense", "256", "--quiet", "--seed", "4", "--workers", "1"]


def _scene(root):
    """A multi-frame generic scene of two frames (one car, track "a"): what ``--rerun`` records."""
    paths = write_box_scan(root)
    box = json.loads(paths["box"].read_text())
    scene = root / "scene"
    scene.mkdir()
    for k in range(2):
        (scene / f"f{k}.npy").write_bytes(paths["scan"].read_bytes())
        (scene / f"f{k}.json").write_text(json.dumps({"boxes": [dict(box, label="car", track_id="a")]}))
    return scene


def _leftovers(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".part" in p.name or p.name.startswith("."))


def test_rerun_recording_named_like_a_folder_or_inside_a_file(tmp_path):
    pytest.importorskip("rerun")
    scene = _scene(tmp_path)
    (tmp_path / "d.rrd").mkdir()
    (tmp_path / "afile").write_text("x")
    for target, fragment in ((tmp_path / "d.rrd", "is a folder"), (tmp_path / "afile" / "x.rrd", "is not a folder")):
        proc = run_cli("complete", scene, "--out", tmp_path / "out", "--rerun", target, "-q")
        assert_user_error(proc, str(target), fragment)
        assert ".part" not in proc.stderr  # the recording is named, not its temporary
        assert not (tmp_path / "out").exists()  # refused before any work
        assert _leftovers(tmp_path) == [] and list((tmp_path / "d.rrd").iterdir()) == []


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only folder")
def test_rerun_recording_in_a_read_only_folder(tmp_path):
    pytest.importorskip("rerun")
    scene = _scene(tmp_path)
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        proc = run_cli("complete", scene, "--out", tmp_path / "out", "--rerun", ro / "x.rrd", "-q")
        assert_user_error(proc, str(ro / "x.rrd"))
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)


@pytest.mark.parametrize("where", ["save", "flush"])
def test_rerun_recording_on_a_full_disk_is_one_line_and_no_temporary(tmp_path, monkeypatch, where):
    rr = pytest.importorskip("rerun")
    scene = _scene(tmp_path)
    real = getattr(rr.RecordingStream, where)

    def full_disk(self, *args, **kwargs):
        real(self, *args, **kwargs)  # the temporary exists: it must go
        if where == "save":
            raise RuntimeError("Failed to create file: No space left on device (os error 28)")
        raise RuntimeError("File-writer thread shut down prematurely")

    monkeypatch.setattr(rr.RecordingStream, where, full_disk)
    (tmp_path / "rec").mkdir()
    proc = run_cli("complete", scene, "--out", tmp_path / "out", "--rerun", tmp_path / "rec" / "x.rrd", "-q")
    assert_user_error(proc, str(tmp_path / "rec" / "x.rrd"), "recording")
    assert "Traceback" not in proc.stderr and ".part" not in proc.stderr
    assert list((tmp_path / "rec").iterdir()) == []  # no temporary, no recording


def test_sharded_build_on_a_full_disk_leaves_no_shard(tmp_path, monkeypatch):
    from spotlights.data.synthetic import runner

    real = runner.write_output_file
    calls = []

    def full_at_the_second_shard(path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real(path, *args, **kwargs)

    monkeypatch.setattr(runner, "write_output_file", full_at_the_second_shard)
    out = tmp_path / "set.json"
    proc = run_cli(
        "dataset", "build", "--procedural", "1", "--classes", "car,bus", "--shard-size", "3", "--out", out, *TINY_BUILD
    )
    assert len(calls) == 2, proc.stderr  # two shards of one model each: the first was written, the second refused
    assert_user_error(proc, "set-00001-of-00002.h5", "no space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == [], sorted(p.name for p in tmp_path.iterdir())


def _box_mesh(root):
    import trimesh

    folder = root / "meshes"
    folder.mkdir()
    trimesh.creation.box(extents=(4.0, 1.8, 1.5)).export(folder / "a.ply")
    return folder


def test_sequences_on_a_full_disk_leave_no_folder(tmp_path, monkeypatch):
    from spotlights.data.synthetic import sequences

    meshes = _box_mesh(tmp_path)
    real = sequences.atomic_output
    writes = []

    def full_disk_in_the_second_sequence(path, *args, **kwargs):
        writes.append(path)
        if "seq0001" in str(path) and len([w for w in writes if "seq0001" in str(w)]) == 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real(path, *args, **kwargs)

    monkeypatch.setattr(sequences, "atomic_output", full_disk_in_the_second_sequence)
    out = tmp_path / "seqs"
    proc = run_cli("dataset", "sequences", "--meshes", meshes, "--sequences", 2, "--frames", 2, "-q", "--out", out)
    assert any("seq0001" in str(w) for w in writes), proc.stderr
    assert_user_error(proc, "seq0001", "no space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["meshes"]  # no seqs/, no empty seq0001/, no seq0000/


def test_sequences_still_written_whole(tmp_path):
    meshes = _box_mesh(tmp_path)
    out = tmp_path / "seqs"
    proc = run_cli("dataset", "sequences", "--meshes", meshes, "--sequences", 2, "--frames", 2, "-q", "--out", out)
    assert proc.returncode == 0, proc.stderr
    for name in ("seq0000", "seq0001"):
        seq = json.loads((out / name / "sequence.json").read_text())
        assert [f["scan"] for f in seq["frames"]] == ["0000.npy", "0001.npy"]
        assert np.load(out / name / "gt.npy").shape == (2048, 3)
