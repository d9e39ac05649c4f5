"""Hostile inputs left by the second fuzzing pass (stop 40) and answered in stop 41: a scene PLY cut short is not
trusted by ``--resume``, ..."""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.geometry.io import load_ply_fields, ply_has_faces, ply_is_whole, save_ply


@pytest.mark.timeout(60)
def test_ply_is_whole_counts_the_bytes_its_header_declares(tmp_path):
    """Independent truth: a binary PLY of K vertices with float32 x, y, z and a uchar holds header + 13 K bytes."""
    path = tmp_path / "frame.ply"
    save_ply(path, np.arange(30.0).reshape(10, 3), {"source": np.ones(10, np.uint8)})
    data = path.read_bytes()
    header = data.index(b"end_header\n") + len(b"end_header\n")
    assert len(data) == header + 10 * 13
    assert ply_is_whole(path)
    for cut in (1, 13, 10 * 13):  # a row's last byte, a whole row, every row
        path.write_bytes(data[:-cut])
        assert not ply_is_whole(path), cut
    path.write_bytes(data + b"\0")
    assert not ply_is_whole(path)
    path.write_bytes(data[: header - 3])  # the header itself cut
    assert not ply_is_whole(path)
    path.unlink()
    assert not ply_is_whole(path)
    save_ply(path, np.zeros((0, 3)))  # an empty frame's cloud is whole
    assert ply_is_whole(path)


@pytest.mark.timeout(60)
def test_ply_is_whole_reads_a_long_header_and_a_comment_that_names_end_header(tmp_path):
    """A busy frame's PLY has a header of many comment lines: over 64 KiB it was judged cut short (and completed
    again by every --resume); a comment holding the word end_header was taken for the header's end."""
    path = tmp_path / "busy.ply"
    comments = ["a comment that holds end_header inside"] + [f"object {k}: car, 4.5 x 1.8 x 1.5 m" for k in range(3000)]
    save_ply(path, np.arange(30.0).reshape(10, 3), {"source": np.ones(10, np.uint8)}, comments=comments)
    data = path.read_bytes()
    header = data.index(b"\nend_header\n") + len(b"\nend_header\n")
    assert header > 65536 and len(data) == header + 10 * 13  # independent truth: the bytes the header declares
    assert ply_is_whole(path)
    assert len(load_ply_fields(path)["x"]) == 10  # a reader that splits at the first end_header reads it too
    assert data.count(b"end_header") == 1 and b"holds end-header inside" in data
    path.write_bytes(data[:-1])
    assert not ply_is_whole(path)
    path.write_bytes(data[: header - 1])  # cut inside the header's last line
    assert not ply_is_whole(path)


@pytest.mark.timeout(60)
def test_ply_has_faces_reads_the_header_up_to_its_own_end(tmp_path):
    path = tmp_path / "mesh.ply"
    head = "ply\nformat ascii 1.0\ncomment end_header in a comment\nelement vertex 3\nproperty float x\n"
    head += "property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
    path.write_text(head + "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    assert ply_has_faces(path)
    path.write_text(head.replace("element face 1", "element face 0") + "end_header\n0 0 0\n1 0 0\n0 1 0\n")
    assert not ply_has_faces(path)
    save_ply(path, np.zeros((2, 3)), comments=["element face 5"])  # a comment is not the header's element line
    assert not ply_has_faces(path)


@pytest.mark.timeout(60)
def test_ply_is_whole_reads_other_plys_whole(tmp_path):
    path = tmp_path / "ascii.ply"
    head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    path.write_text(head + "0 0 0\n1 1 1\n2 2 2\n")
    assert ply_is_whole(path)
    path.write_text(head + "0 0 0\n1 1 1\n")
    assert not ply_is_whole(path)


@pytest.mark.timeout(60)
def test_resume_completes_again_a_frame_whose_ply_is_cut_short(tmp_path):
    """``real complete --resume`` trusted any non-empty scene PLY: one cut short by a crash or a full disk was kept."""
    import json
    from dataclasses import asdict

    from spotlights.completion.frame import SceneConfig
    from spotlights.completion.frames import done_frame

    cfg = asdict(SceneConfig())
    cfg["clip"] = str(cfg["clip"])
    f, ply = tmp_path / "frame.json", tmp_path / "frame.ply"
    f.write_text(json.dumps({"model": "sanet-hit", "checkpoint": "default", "config": cfg, "ply": str(ply)}))
    save_ply(ply, np.zeros((100, 3)), {"object": np.zeros(100, np.int32)})
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is not None
    ply.write_bytes(ply.read_bytes()[:-7])
    assert done_frame(f, SceneConfig(), "sanet-hit", "default") is None


@pytest.mark.timeout(60)
@pytest.mark.parametrize("mesh", ["car.ply", None, np.zeros((10, 3)), 3.0])
def test_encode_mesh_refuses_what_is_not_a_mesh(mesh):
    """A path, None or a point array gave an AttributeError deep in the ray caster."""
    import spotlights
    from spotlights.errors import ParameterError

    with pytest.raises(ParameterError, match="mesh must be a triangle mesh"):
        spotlights.encode_mesh(mesh, spotlights.make_rig(4, 8))


@pytest.mark.timeout(60)
def test_encode_mesh_refuses_bad_arrays_and_reads_a_rig_name():
    import trimesh

    import spotlights
    from spotlights.errors import ParameterError

    box = trimesh.creation.box(extents=(4.0, 1.8, 1.5))
    by_name = spotlights.encode_mesh(box, "cap-4x8-60")
    assert np.array_equal(by_name, spotlights.encode_mesh(box, spotlights.make_rig(4, 8, angle=60.0)))
    assert (by_name > 0).any()

    class Arrays:
        vertices = box.vertices
        faces = box.faces + len(box.vertices)  # indices past the last vertex

    with pytest.raises(ParameterError, match="faces must be \\(F, 3\\) indices of its 8 vertices"):
        spotlights.encode_mesh(Arrays(), "cap-4x8-60")
    with pytest.raises(ParameterError, match="rig must be a Rig"):
        spotlights.encode_mesh(box, 42)
    with pytest.raises(ParameterError, match="rig 'nonsense' not understood"):
        spotlights.encode_mesh(box, "nonsense")


@pytest.mark.timeout(60)
def test_read_frames_refuses_no_source_and_unknown_options(tmp_path):
    """``read_frames([], "kitti")`` raised IndexError; an option of another reader a TypeError."""
    import spotlights
    from spotlights.errors import ParameterError

    with pytest.raises(ParameterError, match="no source given"):
        spotlights.read_frames([], "kitti")
    with pytest.raises(ParameterError, match="foo are not options of the kitti reader \\(it takes: velodyne\\)"):
        spotlights.read_frames(tmp_path, "kitti", foo=1)
    with pytest.raises(ParameterError, match="not options of the av2 reader \\(it takes: none\\)"):
        spotlights.read_frames(tmp_path, "av2", sequences=["a"])
    with pytest.raises(ParameterError, match="unknown format 'kity'"):
        spotlights.read_frames(tmp_path, "kity")


@pytest.mark.timeout(300)
@pytest.mark.parametrize("failing", ["show", "html", "summary"])
def test_complete_removes_its_outputs_when_a_later_one_fails(tmp_path, monkeypatch, failing):
    """A failing ``--show``/``--html``/``--summary`` kept ``OUT.ply`` (a failing ``--per-object`` removed it): every
    output of the run is now all or nothing."""
    from spotlights.assets import asset_path
    from spotlights.completion import scan as scan_completion
    from spotlights.errors import OutputFileError

    from helpers import run_cli

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


@pytest.mark.timeout(300)
@pytest.mark.parametrize("bad_data", [False, True])
def test_a_run_stopped_by_a_nan_loss_leaves_nothing_and_names_the_cause(tmp_path, monkeypatch, capsys, bad_data):
    """A NaN loss on the first epoch left ``run/config.yaml`` behind and always advised a lower learning rate,
    also when the batch itself held NaN (the dataset's fault)."""
    import json

    import torch

    from spotlights.learning.models.sanet import SANet

    from learning_fixtures import cli, tiny_dataset_path, tiny_overrides

    real_loss = SANet.loss

    def nan_loss(self, outputs, batch, progress=1.0):
        loss, parts = real_loss(self, outputs, batch, progress)
        if bad_data:
            batch["partial"][0, 0, 0] = float("nan")
        return loss * torch.tensor(float("nan")), parts

    monkeypatch.setattr(SANet, "loss", nan_loss)
    data = tiny_dataset_path(tmp_path / "data")
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(json.dumps(tiny_overrides("sanet", epochs=1, batch_size=4)))
    proc = cli(capsys, "train", "--model", "sanet", "--data", data, "--config", cfg, "--out", tmp_path / "run", "-q")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert "the training loss became nan" in proc.stderr
    if bad_data:
        assert "partial hold NaN or infinite values: check the dataset" in proc.stderr and "lower" not in proc.stderr
    else:
        assert "lower train.lr" in proc.stderr
    assert not (tmp_path / "run").exists(), sorted(p.name for p in (tmp_path / "run").rglob("*"))
    # a folder that holds a kept best model and its config (no last.pt): the NaN stop puts the config back
    run = tmp_path / "kept"
    run.mkdir()
    (run / "config.yaml").write_text("model: {name: sanet}\n")
    (run / "best.pt").write_bytes(b"a kept best model")
    proc = cli(capsys, "train", "--model", "sanet", "--data", data, "--config", cfg, "--out", run, "-q")
    assert proc.returncode == 2 and "the training loss became nan" in proc.stderr, proc.stderr
    assert sorted(p.name for p in run.iterdir()) == ["best.pt", "config.yaml"]
    assert (run / "config.yaml").read_text() == "model: {name: sanet}\n"


@pytest.mark.timeout(120)
def test_a_failed_call_keeps_the_files_of_a_run_it_did_not_write(tmp_path, capsys):
    """The cleanup of a failed run removed ``config.yaml``, ``best.pt`` and ``log.csv`` of an existing run folder
    (one without ``last.pt``: a kept best model) on any input error: a wrong ``--data`` or "nothing to resume"."""
    from learning_fixtures import cli

    run = tmp_path / "run"
    run.mkdir()
    kept = {"config.yaml": b"model: {name: sanet}\n", "best.pt": b"a kept best model", "log.csv": b"epoch\n1\n"}
    for name, data in kept.items():
        (run / name).write_bytes(data)
    missing = tmp_path / "missing.h5"
    for extra in ([], ["--resume"]):
        proc = cli(capsys, "train", "--model", "sanet", "--data", missing, "--out", run, "-q", *extra)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert {p.name: p.read_bytes() for p in run.iterdir()} == kept, extra
    # --overwrite with a mistyped --data: the old run (here with its last.pt) goes only once the data is found
    kept["last.pt"] = b"a run to continue"
    (run / "last.pt").write_bytes(kept["last.pt"])
    proc = cli(capsys, "train", "--model", "sanet", "--data", missing, "--out", run, "-q", "--overwrite")
    assert proc.returncode == 2 and "missing.h5" in proc.stderr, proc.stderr
    assert {p.name: p.read_bytes() for p in run.iterdir()} == kept


@pytest.mark.timeout(60)
def test_a_removed_lock_file_still_excludes_and_leaves_nothing(tmp_path):
    """``dataset add-rig`` left ``.X.h5.lock`` beside the user's dataset; with ``remove=True`` the lock file goes,
    and a second holder is still refused while the first holds it (flock: two open files conflict even in one
    process)."""
    from spotlights.errors import SpotlightsError
    from spotlights.utils import exclusive_lock

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

    from spotlights.errors import SpotlightsError
    from spotlights.utils import exclusive_lock

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
    from spotlights.errors import SpotlightsError

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
    from spotlights.errors import SpotlightsError

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


@pytest.mark.timeout(60)
def test_a_truncated_checkpoint_or_an_onnx_file_is_named_as_such(tmp_path):
    from spotlights.errors import InputFileError
    from spotlights.learning.checkpoint import PRETRAINED, load_checkpoint, resolve_checkpoint

    data = resolve_checkpoint("paper").read_bytes()
    assert "paper" in PRETRAINED
    cut = tmp_path / "last.pt"
    for n in (0, 100, len(data) - 10):
        cut.write_bytes(data[:n])
        with pytest.raises(InputFileError, match="last.pt: truncated \\(its end is missing\\)") as err:
            load_checkpoint(cut)
        assert "internal" not in str(err.value)
    onnx = tmp_path / "m.onnx"
    onnx.write_bytes(b"\x08\x07onnx")
    with pytest.raises(InputFileError, match="m.onnx: is an ONNX model: .*--runtime onnx"):
        load_checkpoint(onnx)


@pytest.mark.timeout(120)
@pytest.mark.parametrize("scale", [1e-30, 1000.0])
def test_sequences_refuse_a_mesh_not_in_metres_before_writing(tmp_path, scale):
    """A tetrahedron of 1e-30 m drove past the sensor as scans of no points, exit 0."""
    import trimesh

    from helpers import assert_user_error, run_cli

    good = trimesh.creation.box(extents=(4.0, 1.8, 1.5))
    tiny = trimesh.creation.box(extents=(4.0, 1.8, 1.5))
    tiny.apply_scale(scale)
    folder = tmp_path / "meshes"
    folder.mkdir()
    good.export(folder / "a.ply")
    tiny.export(folder / "b.ply")
    for out in ("seqs", "seqs.h5"):
        proc = run_cli(
            "dataset", "sequences", "--meshes", folder, "--sequences", 2, "--frames", 2, "-q", "--out", tmp_path / out
        )
        assert_user_error(proc, "b.ply", "m long: a vehicle to drive past is 0.5-50 m")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["meshes"]
