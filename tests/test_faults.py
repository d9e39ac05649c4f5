"""Fault injection: every writer on a full disk, a SIGKILLed build's processes, leftovers of killed
runs, shard indexes that lie, resumes on other data, opsets the exporter cannot write, Ray
addresses where nothing answers. Each failure is one line, exit code 2, nothing left behind."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import trimesh

from spotlights.cli import main
from spotlights.data.synthetic import BuildConfig, build_dataset

from builders import scan_folder, three_frames
from helpers import REPO, assert_user_error, run_cli

# the tiny build of these tests: parts of ~19 KB, a dataset file of ~120 KB, shards of ~73 KB
BUILD = ["--views", "8", "--split", "1/1/1", "--points", "128", "--gt-points", "256", "--gt-dense", "512", "-q"]
LIMIT = 40_000  # bytes per file: every part fits, no dataset file, shard or checkpoint does

# Runs the CLI with files limited to LIMIT bytes (RLIMIT_FSIZE): writes past it fail with EFBIG
# in this process and in its workers, as writes on a full disk fail with ENOSPC (no root needed).
LIMITED = """
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[1]), int(sys.argv[1])))
from spotlights.cli import main
sys.exit(main(sys.argv[2:]))
"""


def _env(tmp: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(REPO / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.update(MPLBACKEND="Agg", OMP_NUM_THREADS="1", TMPDIR=str(tmp))  # TMPDIR: multiprocessing's pymp-* folders
    return env


def run_limited(limit: int, *args, cwd: Path, tmp: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", LIMITED, str(limit), *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=_env(tmp),
        timeout=300,
    )


def listing(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    """Three box-like models in two categories."""
    root = tmp_path_factory.mktemp("meshes")
    for rel, ext in (
        ("a/box_a.ply", (4.5, 1.8, 1.5)),
        ("a/box_b.ply", (4.0, 1.7, 1.6)),
        ("b/box_c.ply", (3.9, 1.7, 1.4)),
    ):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        trimesh.creation.box(extents=ext).export(root / rel)
    return root


@pytest.fixture(scope="module")
def built(meshes, tmp_path_factory):
    """The tiny build as one file and as three shards (inputs of merge, train, add-rig)."""
    root = tmp_path_factory.mktemp("built")
    for out, extra in (("cars.h5", []), ("cars.json", ["--shard-size", "8"])):
        assert (
            main(
                [
                    "dataset",
                    "build",
                    "--meshes",
                    str(meshes),
                    "--out",
                    str(root / out),
                    "--workers",
                    "1",
                    *BUILD,
                    *extra,
                ]
            )
            == 0
        )
    assert (root / "cars.h5").stat().st_size > LIMIT and (root / "cars-00000-of-00003.h5").stat().st_size > LIMIT
    return root


# ---------------------------------------------------------------- full disk, every writer


def _writer_case(name: str, meshes: Path, built: Path, work: Path) -> list:
    """The CLI arguments of one writer, its output under ``work``."""
    if name == "build":  # two workers: the pool, its fork server and its pymp-* folder must go too
        return ["dataset", "build", "--meshes", meshes, "--out", work / "o.h5", "--workers", "2", *BUILD]
    if name == "build-shards":
        return [
            "dataset",
            "build",
            "--meshes",
            meshes,
            "--out",
            work / "o.json",
            "--shard-size",
            "8",
            "--workers",
            "1",
            *BUILD,
        ]
    if name == "merge":
        return ["dataset", "merge", built / "cars.json", "--out", work / "m.h5", "-q"]
    if name == "add-rig":
        shutil.copy(built / "cars.h5", work / "c.h5")
        return ["dataset", "add-rig", work / "c.h5", "--rig", "8x16@60", "--meshes", meshes, "--workers", "1", "-q"]
    if name == "real-extract":
        return [
            "real",
            "extract",
            scan_folder(work.parent / "scans"),
            "--format",
            "generic",
            "--out",
            work / "r.h5",
            "-q",
        ]
    if name == "train":
        return [
            "train",
            "--model",
            "pcn",
            "--data",
            built / "cars.h5",
            "--out",
            work / "run",
            "--epochs",
            "1",
            "--batch-size",
            "4",
            "--threads",
            "1",
            "--device",
            "cpu",
            "-q",
        ]
    raise AssertionError(name)


@pytest.mark.parametrize("writer", ["build", "build-shards", "merge", "add-rig", "real-extract", "train"])
def test_every_writer_fails_cleanly_when_a_write_fails(writer, meshes, built, tmp_path):
    """A write that fails (files limited to 40 kB: EFBIG, as ENOSPC on a full disk) is one line, exit 2,
    nothing left: no half-written file, no parts, no pymp-* folder; HDF5 writers used to segfault (-11)."""
    # the child's TMPDIR: a short path (the suite's private temporary folder, tests/conftest.py), since
    # multiprocessing's socket paths inside it must stay under 107 bytes (pytest-xdist's tmp_path is deeper)
    work, tmp = tmp_path / "work", Path(tempfile.mkdtemp(prefix="w-"))
    work.mkdir()
    args = _writer_case(writer, meshes, built, work)
    before = listing(work)
    proc = run_limited(LIMIT if writer != "real-extract" else 4096, *args, cwd=tmp_path, tmp=tmp)
    assert_user_error(proc, "cannot write")
    assert "Segmentation" not in proc.stderr and "Exception ignored" not in proc.stderr, proc.stderr
    left = listing(work) - before  # add-rig's lock file is removed too (exclusive_lock(remove=True))
    assert not left and before <= listing(work), (left, proc.stderr)
    assert not list(tmp.glob("pymp-*")), "multiprocessing's folder left behind"


@pytest.mark.timeout(300)
def test_real_complete_fails_cleanly_when_a_frame_write_fails(tmp_path):
    """``real complete`` writes each frame's PLY and JSON on a thread while the next frame is completed: a write
    that fails there (files limited to 40 kB: EFBIG, as ENOSPC) still ends the run with one line, exit 2, and
    nothing left (no frame could be written: no output folder either)."""
    scans = three_frames(tmp_path / "scans")
    work, tmp = tmp_path / "work", Path(tempfile.mkdtemp(prefix="w-"))
    work.mkdir()
    args = ["real", "complete", scans, "--format", "generic", "--out", work / "out", "--no-pictures", "-q"]
    proc = run_limited(LIMIT, *args, cwd=tmp_path, tmp=tmp)
    assert_user_error(proc, "cannot write")
    assert not listing(work), (listing(work), proc.stderr)


@pytest.mark.timeout(300)
@pytest.mark.parametrize("pictures", [False, "0", "2"])
def test_a_failed_frame_write_stops_the_run_at_the_next_frame(tmp_path, monkeypatch, pictures):
    """The second frame's PLY fails on the writer thread (each frame's PLY and JSON are written there, while the
    next frame is completed): the run stops with that error before the third frame writes anything, its picture
    included; the first frame's PLY, JSON (and PNG) stay (a resumed run continues from them), the second has
    none of its files (nor a temporary). With 2 picture processes (``--picture-workers 2``: two frames in flight)
    the third frame may be completed and queued, but writes nothing either."""
    import threading

    from spotlights.cli import main
    from spotlights.completion import frames as frame_completion
    from spotlights.errors import OutputFileError

    scans = three_frames(tmp_path / "scans")
    real_write, calls = frame_completion.write_scene, []

    def failing(result, out, *a, **k):
        calls.append((Path(out).name, threading.current_thread().name.rsplit("_", 1)[0]))
        if len(calls) == 2:
            raise OutputFileError(out, "cannot write (no space left on device)")
        return real_write(result, out, *a, **k)

    monkeypatch.setattr(frame_completion, "write_scene", failing)
    out = tmp_path / "out"
    args = ["real", "complete", str(scans), "--format", "generic", "--out", str(out), "-q"]
    code = main(args + (["--picture-workers", pictures] if pictures else ["--no-pictures"]))
    assert code == 2
    # the third frame's files were never started; the writes ran on the writer thread, not the frame loop's
    assert calls == [("f0.ply", "spotlights-write"), ("f1.ply", "spotlights-write")]
    names = {p.name for p in out.rglob("*")}
    assert {"f0.ply", "f0.json"} | ({"f0.png"} if pictures else set()) <= names
    assert not names & {"f1.ply", "f1.png", "f1.json", "f2.ply", "f2.png", "f2.json", "summary.json"}, names
    assert not [n for n in names if ".part" in n], names


def test_build_on_a_full_tmpfs(meshes, tmp_path):
    """The same on a real full disk (ENOSPC): a 1 MiB tmpfs; needs root and mount (else skipped)."""
    if os.geteuid() != 0 or not shutil.which("mount"):
        pytest.skip("mounting a tmpfs needs root")
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("mount -t tmpfs is not allowed here")
    try:
        tmp = tmp_path / "tmp"
        tmp.mkdir()
        # default ground truth (16,384 dense points): the parts fit in 1 MiB, the dataset file does not
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "spotlights",
                "dataset",
                "build",
                "--meshes",
                str(meshes),
                "--out",
                str(disk / "o.h5"),
                "--views",
                "20",
                "--split",
                "1/1/1",
                "--workers",
                "2",
                "-q",
            ],
            capture_output=True,
            text=True,
            env=_env(tmp),
            timeout=300,
        )
        assert_user_error(proc, "o.h5: cannot write (no space left on device)")
        assert list(disk.iterdir()) == [] and not list(tmp.glob("pymp-*"))
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


# ---------------------------------------------------------------- a SIGKILLed build leaves no process


def _children() -> dict[int, list[int]]:
    """Parent pid -> child pids of every live (non-zombie) process, from /proc."""
    tree: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        state, ppid = stat.rsplit(")", 1)[1].split()[:2]
        if state != "Z":
            tree.setdefault(int(ppid), []).append(int(entry))
    return tree


def _descendants(pid: int) -> set[int]:
    tree, out, todo = _children(), set(), [pid]
    while todo:
        for c in tree.get(todo.pop(), []):
            out.add(c)
            todo.append(c)
    return out


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc; the parent-death signal is Linux's")
def test_sigkill_of_a_build_leaves_no_process(meshes, tmp_path):
    """SIGKILL of the build process alone: its fork server, workers and resource tracker die with it
    (they used to live on for minutes)."""
    out = tmp_path / "o.h5"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "spotlights",
            "dataset",
            "build",
            "--meshes",
            str(meshes),
            "--out",
            str(out),
            "--views",
            "20000",
            "--block",
            "20",
            "--split",
            "1/1/1",
            "--workers",
            "2",
            "-q",
        ],
        env=_env(tmp_path),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    family: set[int] = set()
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            family |= _descendants(proc.pid)
            if len(family) >= 4 and any((tmp_path / "o.h5.parts").glob("obs-*.npz")):
                break  # tracker, fork server and two workers, and the workers are saving units
            time.sleep(0.2)
        assert proc.poll() is None and len(family) >= 4, (proc.poll(), family)
        family |= _descendants(proc.pid)
        proc.kill()
        proc.wait()
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(_alive(p) for p in family):
            time.sleep(0.2)
        assert not [p for p in family if _alive(p)], "processes outlived the killed build"
    finally:
        for p in family:  # never leak them into the rest of the suite
            if _alive(p):
                os.kill(p, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()


# ---------------------------------------------------------------- leftovers of killed runs


def test_parts_left_beside_a_finished_build_are_swept(meshes, tmp_path):
    """A kill between the final rename and the removal of OUT.parts: the next run removes them."""
    cfg = BuildConfig(meshes=str(meshes), views=4, split="1/1/1", gt_points=256, gt_dense=512)
    out = tmp_path / "o.h5"
    build_dataset(cfg, out, workers=1, progress=False, keep_parts=True, log=lambda m: None)
    assert (tmp_path / "o.h5.parts").is_dir()  # the state such a kill leaves
    rep = build_dataset(cfg, out, workers=1, progress=False, resume=True, log=lambda m: None)
    assert rep.already_complete and not (tmp_path / "o.h5.parts").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.h5"]


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_real_complete_sweeps_a_killed_runs_temporaries(tmp_path):
    """A SIGKILLed `real complete` leaves a 0-byte .FRAME.png.PID-X.part.png: the next run removes it,
    and leaves alone names that are not ours."""
    src = scan_folder(tmp_path / "scans")
    out = tmp_path / "out"
    (out / "scans").mkdir(parents=True)  # frames of a folder go to OUT/<folder name>/
    stale = out / "scans" / f".f0.png.{_dead_pid()}-k1ll3d.part.png"
    stale.touch()
    other = out / ".notes.part"  # someone else's file (no PID)
    other.touch()
    proc = run_cli(
        "real", "complete", src, "--format", "generic", "--out", out, "--no-pictures", "-q", "--device", "cpu"
    )
    assert proc.returncode == 0, proc.stderr
    assert not stale.exists() and other.exists()
    assert (out / "scans" / "f0.ply").exists()


def test_complete_per_object_into_an_unwritable_folder_writes_nothing(tmp_path):
    """--per-object where no folder can be made: one line, exit 2, and no --out file either."""
    scans = scan_folder(tmp_path / "scans")
    (tmp_path / "afile").write_text("not a folder")
    proc = run_cli(
        "complete",
        scans / "f0.npy",
        "--boxes",
        scans / "f0.json",
        "--out",
        tmp_path / "o.ply",
        "--per-object",
        tmp_path / "afile" / "objects",
        "--device",
        "cpu",
        "-q",
    )
    assert_user_error(proc, "afile")
    assert not (tmp_path / "o.ply").exists()


# ---------------------------------------------------------------- silent wrong: refused


def _bad_index(built: Path, tmp_path: Path, order: list[int]) -> Path:
    idx = json.loads((built / "cars.json").read_text())
    for k in sorted(set(order)):  # shard files named by an index must lie in its folder: copies beside it
        shutil.copyfile(built / idx["shards"][k]["file"], tmp_path / Path(idx["shards"][k]["file"]).name)
    shards = [dict(idx["shards"][k], file=Path(idx["shards"][k]["file"]).name) for k in order]
    idx.update(
        shards=shards, n_models=sum(s["n_models"] for s in shards), n_samples=sum(s["n_samples"] for s in shards)
    )
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(idx))
    return path


@pytest.mark.parametrize(
    "order, says",
    [([0, 0, 2], "lists shard 0 of 3 twice"), ([0, 1], "lacks shard 2 of 3"), ([1, 0, 2], "list the shards in order")],
    ids=["twice", "missing", "swapped"],
)
def test_merge_refuses_an_index_that_misplaces_its_shards(order, says, built, tmp_path, capsys):
    index = _bad_index(built, tmp_path, order)
    assert main(["dataset", "merge", str(index), "--out", str(tmp_path / "m.h5"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0] and "bad.json" in err[0], err
    assert not (tmp_path / "m.h5").exists() and not list(tmp_path.glob("*.part*")), sorted(tmp_path.iterdir())


def one_error_line(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if "error" in ln]
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_resume_on_other_data_is_refused_unless_allowed(meshes, built, tmp_path, capsys):
    """Another dataset (another seed: other samples) under --resume: one line, unless --allow-new-data;
    a copy of the same dataset elsewhere is the same data. (The resumes ask for no more epochs: the
    check comes before any training.)"""
    other = tmp_path / "other.h5"
    build = ["dataset", "build", "--meshes", str(meshes), "--out", str(other), "--seed", "5", "--workers", "1"]
    assert main([*build, *BUILD]) == 0
    copy = tmp_path / "copy.h5"
    shutil.copy(built / "cars.h5", copy)
    run = tmp_path / "run"
    common = ["--model", "pcn", "--out", str(run), "--epochs", "1", "--batch-size", "4", "--device", "cpu", "-q"]
    assert main(["train", "--data", str(built / "cars.h5"), *common]) == 0
    capsys.readouterr()
    assert main(["train", "--data", str(other), "--resume", *common]) == 2
    line = one_error_line(capsys)
    assert "last.pt" in line and "other.h5" in line and "--allow-new-data" in line, line
    assert main(["train", "--data", str(copy), "--resume", *common]) == 0
    assert main(["train", "--data", str(other), "--resume", "--allow-new-data", *common]) == 0


@pytest.mark.parametrize("opset", ["1", "14", "999"])
def test_export_refuses_an_opset_it_cannot_write(opset, tmp_path, capsys):
    """It wrote opset 18 without a word."""
    pytest.importorskip("onnx")
    pytest.importorskip("onnxscript")
    assert main(["export", "default", "--out", str(tmp_path / "m.onnx"), "--opset", opset]) == 2
    line = one_error_line(capsys)
    assert f"--opset {opset}" in line and "15 to" in line, line
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------- Ray


def test_ray_address_where_nothing_answers_is_one_line_in_seconds(meshes, tmp_path):
    """Ray retried for ever (and ignored SIGTERM); now a connect timeout and one line."""
    pytest.importorskip("ray")
    t0 = time.monotonic()
    proc = run_cli(
        "dataset",
        "build",
        "--meshes",
        meshes,
        "--out",
        tmp_path / "o.h5",
        "--backend",
        "ray",
        "--ray-address",
        "127.0.0.1:1",
        *BUILD,
        timeout=120,
    )
    assert_user_error(proc, "cannot connect to the Ray cluster at 127.0.0.1:1")
    assert time.monotonic() - t0 < 90
    assert list(tmp_path.iterdir()) == []


def _listening(pids: set[int]) -> list[str]:
    """The local addresses (hex ip:port from /proc/net/tcp*) the processes ``pids`` listen on."""
    inodes = set()
    for p in pids:
        try:
            for fd in os.listdir(f"/proc/{p}/fd"):
                with_target = os.readlink(f"/proc/{p}/fd/{fd}")
                if with_target.startswith("socket:["):
                    inodes.add(with_target[8:-1])
        except OSError:
            continue
    out = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:  # 0A: LISTEN
                out.append(f[1])
    return out


def _loopback(hex_addr: str) -> bool:
    ip = hex_addr.split(":")[0]
    if len(ip) == 8:  # IPv4, little-endian words: 127.x.x.x ends in 7F
        return ip.endswith("7F")
    return ip == "0" * 31 + "1" or ip.startswith("0000000000000000FFFF0000") and ip.endswith("7F")  # ::1, ::ffff:127.x


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_local_ray_listens_on_loopback_and_sigterm_exits_143(meshes, tmp_path):
    """The local Ray instance of --backend ray listens on loopback only; SIGTERM gives 143 and one
    line (it gave 15 and Ray's stack dump)."""
    pytest.importorskip("ray")
    env = _env(tmp_path)
    del env["TMPDIR"]  # Ray's sockets live under it: a pytest folder makes their paths too long
    env.pop("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", None)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "spotlights",
            "dataset",
            "build",
            "--meshes",
            str(meshes),
            "--out",
            str(tmp_path / "o.h5"),
            "--backend",
            "ray",
            "--workers",
            "1",
            *BUILD,
            "--views",  # after BUILD: the last one counts
            "20000",
            "--block",
            "20",
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and proc.poll() is None:
            if any((tmp_path / "o.h5.parts").glob("obs-*.npz")):
                break
            time.sleep(0.5)
        assert proc.poll() is None, proc.communicate()[1]
        addrs = _listening(_descendants(proc.pid) | {proc.pid})
        assert addrs and all(_loopback(a) for a in addrs), addrs
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 143, err
        assert err.strip().splitlines() == ["spotlights: terminated"], err
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
