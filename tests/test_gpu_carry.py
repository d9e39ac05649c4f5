"""The GPU recipe fits what a device call carries: the checkout's tracked files and the bundle of
``scripts/gpu_bundle.sh`` (the wheels the GPU image lacks and the meshes, about 19 MiB) under 64 MiB.

The recipe broke once when 14 MB of ONNX exports were added to the tracked files: this test makes such an addition
a decision (shrink something, or carry less), not a surprise on the day a GPU is lent."""

from __future__ import annotations

import subprocess

import pytest

from helpers import REPO

#: What a device call carries: the working tree (tracked and untracked files) and the carried ``.whl``.
CARRY_LIMIT = 64 * 2**20

#: Room kept for the bundle (trimesh, embreex and pykdtree wheels, 15.1 MiB; the meshes' xz archive, 3.8 MiB) and a
#: few untracked files.
BUNDLE_RESERVE = 20 * 2**20


def tracked_bytes() -> int:
    """Bytes of the files git tracks, as they are in the working tree (missing ones count 0)."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the tracked files are not known")
    paths = [p for p in out.stdout.decode("utf-8", "replace").split("\0") if p]
    return sum((REPO / p).stat().st_size for p in paths if (REPO / p).is_file())


def test_the_tracked_files_leave_room_for_the_gpu_bundle():
    size = tracked_bytes()
    assert size <= CARRY_LIMIT - BUNDLE_RESERVE, (
        f"the tracked files are {size / 2**20:.1f} MiB: with the GPU bundle ({BUNDLE_RESERVE / 2**20:.0f} MiB kept) "
        f"they pass the {CARRY_LIMIT / 2**20:.0f} MiB a device call carries (docs/training.md, 'GPU recipe')"
    )
