"""Hostile outcomes for outputs: resumed runs that check what they skip, all-or-nothing outputs, locks, builds
stopped part-way, unwritable folders."""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.errors import SpotlightsError
from spotlights.geometry.io import save_ply

from helpers import run_cli


def test_resume_completes_again_a_frame_whose_json_is_not_a_summary_or_whose_ply_is_gone(tmp_path):
    """``real complete --resume`` skips a frame only when its JSON is a summary of the same run and its scene PLY is
    there (a JSON list raised AttributeError; a deleted or emptied PLY was skipped, the output left incomplete)."""
    import json
    from dataclasses import asdict

    from spotlights.completion.frame import SceneConfig
    from spotlights.completion.frame_selection import done_frame

    cfg = asdict(SceneConfig())
    cfg["clip"] = str(cfg["clip"])
    f = tmp_path / "frame.json"
    ply = tmp_path / "frame.ply"
    f.write_text(json.dumps({"model": "sanet-hit", "checkpoint": "default", "config": cfg, "ply": str(ply)}))
    from spotlights.geometry.io import save_ply

    save_ply(ply, np.zeros((3, 3)), {"source": np.zeros(3, np.uint8)})
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is not None
    ply.write_bytes(b"")
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is None
    ply.unlink()
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is None
    f.write_text("[1, 2]")
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is None


@pytest.mark.timeout(60)
def test_resume_completes_again_a_frame_whose_ply_is_cut_short(tmp_path):
    """``real complete --resume`` trusted any non-empty scene PLY: one cut short by a crash or a full disk was kept."""
    import json
    from dataclasses import asdict

    from spotlights.completion.frame import SceneConfig
    from spotlights.completion.frame_selection import done_frame

    cfg = asdict(SceneConfig())
    cfg["clip"] = str(cfg["clip"])
    f, ply = tmp_path / "frame.json", tmp_path / "frame.ply"
    f.write_text(json.dumps({"model": "sanet-hit", "checkpoint": "default", "config": cfg, "ply": str(ply)}))
    save_ply(ply, np.zeros((100, 3)), {"object": np.zeros(100, np.int32)})
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is not None
    ply.write_bytes(ply.read_bytes()[:-7])
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is None


@pytest.mark.timeout(300)
@pytest.mark.parametrize("failing", ["show", "html", "summary"])
def test_complete_removes_its_outputs_when_a_later_one_fails(tmp_path, monkeypatch, failing):
    """A failing ``--show``/``--html``/``--summary`` kept ``OUT.ply`` (a failing ``--per-object`` removed it): every
    output of the run is now all or nothing."""
    from spotlights.assets import asset_path
    from spotlights.completion import scan as scan_completion
    from spotlights.errors import OutputFileError

    def boom(*args, **kwargs):
        raise OutputFileError(tmp_path / "x", "cannot write (no space left on device)")

    target = {"show": "render_result", "html": "render_result_html", "summary": "write_json"}[failing]
    monkeypatch.setattr(scan_completion, target, boom)
    args = ["complete", str(asset_path("demo_scan.pcd")), "--box", str(asset_path("demo_scan_box.json"))]
    args += ["--out", str(tmp_path / "o.ply"), "--per-object", str(tmp_path / "objects"), "-q"]
    args += ["--summary", str(tmp_path / "s.json"), "--show", str(tmp_path / "p.png")]
    if failing == "html":
        pytest.importorskip("plotly")
        args += ["--html", str(tmp_path / "p.html")]
    proc = run_cli(*args)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    left = sorted(p.name for p in tmp_path.rglob("*") if p.is_file())
    assert left == [], left


@pytest.mark.timeout(60)
def test_a_removed_lock_file_still_excludes_and_leaves_nothing(tmp_path):
    """``dataset add-rig`` left ``.X.h5.lock`` beside the user's dataset; with ``remove=True`` the lock file goes,
    and a second holder is still refused while the first holds it (flock: two open files conflict even in one
    process)."""
    from spotlights.locks import exclusive_lock

    lock = tmp_path / ".d.h5.lock"
    with exclusive_lock(lock, "busy", remove=True):
        assert lock.exists()
        with pytest.raises(SpotlightsError, match="busy"):
            with exclusive_lock(lock, "busy", remove=True):
                pass
        assert lock.exists()  # the refused one removed nothing
    assert not lock.exists()
    with exclusive_lock(lock, "busy"):  # the default keeps the file
        pass
    assert lock.exists()


@pytest.mark.timeout(60)
def test_a_lock_on_a_file_removed_meanwhile_is_taken_again_on_the_new_file(tmp_path, monkeypatch):
    """The race ``remove=True`` opens: a process opened the lock file, then its holder removed it and a third process
    made a new one. Locking the removed file would let two processes in; the lock is taken on the file at the path."""
    import os

    from spotlights.locks import exclusive_lock

    lock = tmp_path / ".d.h5.lock"
    real_open = open
    swapped = []

    def open_then_swap(file, *a, **kw):  # between our open and our flock, the file at the path is replaced
        fh = real_open(file, *a, **kw)
        if os.fspath(file) == os.fspath(lock) and not swapped:
            os.unlink(lock)
            swapped.append(real_open(lock, "a"))  # the third process's new lock file...
            import fcntl

            fcntl.flock(swapped[0], fcntl.LOCK_EX | fcntl.LOCK_NB)  # ...which it holds
        return fh

    monkeypatch.setattr("builtins.open", open_then_swap)
    with pytest.raises(SpotlightsError, match="busy"):  # not let in on the removed file
        with exclusive_lock(lock, "busy", remove=True):
            pass
    monkeypatch.undo()
    swapped[0].close()
    with exclusive_lock(lock, "busy", remove=True):
        pass
    assert not lock.exists()


@pytest.mark.timeout(180)
def test_a_build_stopped_by_its_input_leaves_no_parts(tmp_path):
    """An input error found while simulating (here: no view of a small box gives the asked returns) left
    ``FILE.parts/`` behind, and the corrected rerun was refused as "another plan" until --overwrite."""
    import trimesh

    from spotlights.data.synthetic import BuildConfig, build_dataset

    root = tmp_path / "meshes" / "boxes"
    root.mkdir(parents=True)
    for k, ext in enumerate(((4.0, 1.8, 1.5), (0.04, 0.02, 0.02))):  # the second one: too small to be seen
        trimesh.creation.box(extents=ext).export(root / f"box_{k}.ply")
    out = tmp_path / "d.h5"
    bad = BuildConfig(meshes=str(tmp_path / "meshes"), views=2, split="1/1/0", seed=0)
    saved = []
    real_save = np.savez

    def counting_savez(file, *args, **kwargs):
        saved.append(str(file))
        return real_save(file, *args, **kwargs)

    np.savez = counting_savez  # the first mesh's unit is saved before the second one fails
    try:
        with pytest.raises(SpotlightsError, match="box_1.*no pose out of"):
            build_dataset(bad, out, workers=1, progress=False, log=lambda m: None)
    finally:
        np.savez = real_save
    assert saved, "no unit was saved before the failure: the case tests nothing"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["meshes"]
    (root / "box_1.ply").write_bytes((root / "box_0.ply").read_bytes())  # the input corrected
    good = BuildConfig(meshes=str(tmp_path / "meshes"), views=2, split="1/1/0", seed=0)
    build_dataset(good, out, workers=1, progress=False, log=lambda m: None)
    assert out.is_file() and not (tmp_path / "d.h5.parts").exists()


@pytest.mark.timeout(120)
def test_a_build_stopped_by_an_unreadable_part_keeps_the_others(tmp_path, monkeypatch):
    """The cleanup above first took every SpotlightsError for an input error: an unreadable part found while
    writing the file (or a Ray node that cannot run the build) removed all the saved units a rerun resumes from."""
    import trimesh

    from spotlights.data.synthetic import BuildConfig, build_dataset, consolidate

    root = tmp_path / "meshes" / "boxes"
    root.mkdir(parents=True)
    for k in range(2):
        trimesh.creation.box(extents=(4.0 + k, 1.8, 1.5)).export(root / f"box_{k}.ply")
    out = tmp_path / "d.h5"
    cfg = BuildConfig(meshes=str(tmp_path / "meshes"), views=2, split="1/1/0", seed=0)

    def unreadable(parts, unit, recompute=None):
        raise SpotlightsError(f"{parts / consolidate.part_name(unit)}: unreadable part, deleted; run the build again")

    monkeypatch.setattr(consolidate, "read_part", unreadable)
    with pytest.raises(SpotlightsError, match="unreadable part"):
        build_dataset(cfg, out, workers=1, progress=False, log=lambda m: None)
    parts = sorted(p.name for p in (tmp_path / "d.h5.parts").glob("*.npz"))
    assert len(parts) >= 2, parts  # every unit computed is kept for the rerun
    assert not out.exists()


@pytest.mark.timeout(30)
def test_an_unwritable_folder_is_named_by_the_output_not_its_temporary(tmp_path, monkeypatch):
    """Writing into a folder the user may not write named the hidden temporary
    (``.summary.json.15598-5lueg2kh.part.json: permission denied``) instead of ``summary.json``."""
    import errno
    import tempfile

    from spotlights.errors import OutputFileError
    from spotlights.outputs import atomic_output

    def refused(prefix="", suffix="", dir=None):
        name = f"{dir}/{prefix}abcd1234{suffix}"
        raise PermissionError(errno.EACCES, "Permission denied", name)

    monkeypatch.setattr(tempfile, "mkstemp", refused)
    target = tmp_path / "summary.json"
    with pytest.raises(OutputFileError) as err:
        with atomic_output(target) as tmp:
            tmp.write_text("{}")
    assert str(err.value).startswith(f"{target}: cannot write") and ".part" not in str(err.value), str(err.value)
