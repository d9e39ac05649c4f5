"""The suite on a busy machine and after a failure: a failed run's temporary folders are trimmed to what a failing
test is read by (a failed run left 718 MB under the system's temporary folder)."""

from __future__ import annotations

import os
import subprocess
import sys

from helpers import REPO, src_pythonpath, trim_kept_files


def _write(path, size: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x" * size)


def test_trim_removes_the_largest_files_first_down_to_the_caps(tmp_path):
    sizes = {"a/big.h5": 5000, "a/mid.npz": 1500, "b/log.txt": 300, "b/c/config.yaml": 200, "small.json": 100}
    for rel, size in sizes.items():
        _write(tmp_path / rel, size)
    removed = trim_kept_files(tmp_path, file_bytes=2000, total_bytes=1000)
    # by hand: big.h5 is above the file cap; then 2100 bytes are left, above 1000: mid.npz (1500) goes, 600 stay
    assert [(os.path.relpath(p, tmp_path), s) for p, s in removed] == [("a/big.h5", 5000), ("a/mid.npz", 1500)]
    kept = sorted(os.path.relpath(p, tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert kept == ["TRIMMED.txt", "b/c/config.yaml", "b/log.txt", "small.json"]
    assert "a/big.h5" in (tmp_path / "TRIMMED.txt").read_text()
    assert trim_kept_files(tmp_path, file_bytes=2000, total_bytes=1000) == []  # within the caps: nothing more


def test_a_failed_run_leaves_only_small_files(tmp_path):
    """A pytest run of one failing test that wrote a 20 MB file and a log into its tmp_path, with this suite's
    conftest: afterwards its folder holds the log (what the failure is read by), not the big file."""
    test = tmp_path / "test_fails.py"
    test.write_text(
        "def test_fails(tmp_path):\n"
        "    (tmp_path / 'big.bin').write_bytes(bytes(20 << 20))\n"
        "    (tmp_path / 'run.log').write_text('what went wrong')\n"
        "    assert False\n"
    )
    base = tmp_path / "base"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO / "tests"), src_pythonpath()]))
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "conftest", "-p", "no:cacheprovider", "-p", "no:randomly"]
        + ["--basetemp", str(base), "-o", "tmp_path_retention_policy=failed", str(test)],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=300,
    )
    assert proc.returncode == 1, proc.stdout + proc.stderr  # the test failed, as it should
    files = {p.name: p.stat().st_size for p in base.rglob("*") if p.is_file()}
    assert "run.log" in files and "big.bin" not in files, files
    assert "TRIMMED.txt" in files
