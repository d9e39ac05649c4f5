"""The per-sample arrays of a completion dataset are lzf-compressed (a faster write and read than gzip) and read
back exactly the arrays a gzip build of the same meshes and seed holds; the per-model arrays stay gzip."""

from __future__ import annotations

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
def test_lzf_samples_read_back_the_gzip_build(tmp_path, monkeypatch):
    meshes = write_box_meshes(tmp_path / "meshes")
    lzf = build_reference(meshes, tmp_path / "lzf.h5")
    monkeypatch.setattr(store_writer, "SAMPLE_COMPRESSION", dict(store_writer.COMPRESSION))
    gz = build_reference(meshes, tmp_path / "gzip.h5")
    with h5py.File(lzf, "r") as f, h5py.File(gz, "r") as g:
        assert f["samples/partial"].compression == "lzf" and f["samples/partial"].shuffle
        assert all(f[f"samples/{k}"].compression == "lzf" for k in store_writer.SAMPLE_FIELDS)
        assert g["samples/partial"].compression == "gzip"
        assert f["models/gt_points"].compression == "gzip"  # the per-model arrays as before
    a, b = arrays(lzf), arrays(gz)
    assert a.keys() == b.keys() and "samples/partial" in a
    for k in a:
        assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), k
