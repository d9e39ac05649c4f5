"""The per-sample arrays of a completion dataset are written uncompressed (a faster write and read than gzip, and
deterministic bytes: lzf's are not) and read back exactly the arrays a gzip build of the same meshes and seed
holds; the per-model arrays stay gzip."""

from __future__ import annotations

import hashlib
import io

import h5py
import numpy as np
import pytest

from spotlights.data import store_writer

from builders import build_reference, write_box_meshes


def arrays(path) -> dict:
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


@pytest.mark.timeout(300)
def test_uncompressed_samples_read_back_the_gzip_build_and_give_the_same_bytes_twice(tmp_path, monkeypatch):
    meshes = write_box_meshes(tmp_path / "meshes")
    plain = build_reference(meshes, tmp_path / "plain.h5")
    again = build_reference(meshes, tmp_path / "again.h5")
    assert hashlib.sha256(plain.read_bytes()).digest() == hashlib.sha256(again.read_bytes()).digest()
    monkeypatch.setattr(store_writer, "SAMPLE_COMPRESSION", dict(store_writer.COMPRESSION))
    gz = build_reference(meshes, tmp_path / "gzip.h5")
    with h5py.File(plain, "r") as f, h5py.File(gz, "r") as g:
        assert f["samples/partial"].compression is None
        assert all(f[f"samples/{k}"].compression is None for k in store_writer.SAMPLE_FIELDS)
        assert g["samples/partial"].compression == "gzip"
        assert f["models/gt_points"].compression == "gzip"  # the per-model arrays as before
    a, b = arrays(plain), arrays(gz)
    assert a.keys() == b.keys() and "samples/partial" in a
    for k in a:
        assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), k


def test_the_sample_arrays_are_written_with_a_deterministic_filter():
    """Why not lzf: the same arrays written again must give the same bytes. The writer's filter (none) does; gzip
    does too (the per-model arrays)."""
    rng = np.random.default_rng(0)
    data = rng.normal(size=(64, 256, 3)).astype(np.float32)

    def written(**filters) -> bytes:
        buf = io.BytesIO()
        with h5py.File(buf, "w") as f:
            f.create_dataset("a", data=data, chunks=(1, 256, 3), track_times=False, **filters)
        return buf.getvalue()

    for filters in (store_writer.SAMPLE_COMPRESSION, store_writer.COMPRESSION):
        assert len({written(**filters) for _ in range(6)}) == 1
