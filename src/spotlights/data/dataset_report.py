"""A completion dataset for people: its summary as text lines, one sample picked by split and
position, and that sample written to an ``.npz`` (``spotlights dataset info / export / show``)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..errors import ParameterError, SpotlightsError
from ..outputs import atomic_output, check_writable
from .store import CompletionDataset, open_dataset


def info_lines(info: dict) -> list[str]:
    """The lines ``spotlights dataset info`` prints for :meth:`CompletionDataset.info`'s dict
    (sizes in MiB, distances in metres, angles in degrees)."""
    cfg = info["config"]
    shards = f", {len(info['shards'])} shards" if info.get("shards") else ""
    lines = [
        f"{info['path']}: {info['format']} v{info['format_version']} (spotlights {info['spotlights_version']}), "
        f"{info['file_size_bytes'] / 2**20:.1f} MiB{shards}, seed {info['seed']}",
        f"  {info['n_models']} models x {info['views_per_model']} views = {info['n_samples']} samples; "
        f"categories: " + ", ".join(f"{k} {v}" for k, v in info["categories"].items()),
    ]
    if info.get("classes"):
        lines.append("  classes: " + ", ".join(f"{k} {v}" for k, v in info["classes"].items()))
    for sp, d in info["splits"].items():
        cats = ", ".join(f"{k} {v}" for k, v in d["categories"].items())
        lines.append(f"  {sp:5s}: {d['models']:4d} models, {d['samples']:8d} samples ({cats})")
    lines.append(
        "  rigs: "
        + ", ".join(
            f"{n} ({k} rays){' [default]' if n == info['default_rig'] else ''}" for n, k in info["rigs"].items()
        )
    )
    sen = info["sensor"]
    lines.append(
        f"  sensor: {sen.get('name')} {sen.get('n_beams')} beams {sen.get('elevation_max')}..{sen.get('elevation_min')} deg, "
        f"azimuth step {sen.get('azimuth_step')} deg, {sen.get('mount_height')} m high, noise {sen.get('range_noise')} m, "
        f"dropout {sen.get('dropout')}, beam dropout {sen.get('beam_dropout', 0)}; distance {cfg.get('distance')} m, >= {cfg.get('min_points')} returns, "
        f"{cfg.get('n_points')} points ({cfg.get('downsample')})"
    )
    if info["skipped"]:
        lines.append("  skipped meshes: " + "; ".join(f"{s['file']} ({s['problem']})" for s in info["skipped"]))
    lines.append("  datasets:")
    lines += [f"    {name:28s} {str(tuple(d['shape'])):20s} {d['dtype']}" for name, d in info["datasets"].items()]
    return lines


def dataset_info(path: str | os.PathLike) -> dict:
    """:meth:`CompletionDataset.info` of the dataset file (or shard index) ``path``."""
    with open_dataset(path) as ds:
        return ds.info()


def pick_sample(ds: CompletionDataset, split: str, index: int) -> int:
    """The dataset-wide sample index of the ``index``-th sample of ``split`` (ParameterError when
    out of range, naming ``--index``)."""
    idx = ds.split_indices(split)
    if not (0 <= index < len(idx)):
        raise ParameterError(
            f"{ds.path}: split {split!r} has {len(idx)} samples; `index` {index} is out of range", "index"
        )
    return int(idx[index])


def read_sample(path: str | os.PathLike, split: str, index: int, rig: str | None = None) -> tuple[int, dict, object]:
    """``(i, sample, rig)``: the dataset-wide index ``i`` of ``split[index]``, its
    :meth:`CompletionDataset.sample` dict (unit frame) and the rig of its depths (a ``Rig``, or
    the sample model's box-targeted rig)."""
    with open_dataset(path) as ds:
        i = pick_sample(ds, split, index)
        s = ds.sample(i, rig=rig)
        return i, s, ds.rig(s["rig"], s["model_index"])


def export_sample(
    path: str | os.PathLike, split: str, index: int, out: str | os.PathLike, rig: str | None = None
) -> tuple[int, dict]:
    """Write sample ``split[index]`` of the dataset ``path`` to ``out`` (``.npz``, atomically):
    ``partial`` (256, 3), ``gt_points`` (2048, 3), ``gt_dense`` (16384, 3) float32 unit-frame
    points, ``gt_depths`` (rays,) float32 depths of ``rig``, ``sensor_to_unit`` (4, 4), the
    sample's metadata and ``rig`` (JSON). Returns ``(i, sample)`` (``i`` the dataset-wide index)."""
    if Path(out).suffix.lower() != ".npz":
        raise SpotlightsError(f"{out}: the sample is written as .npz; name the output FILE.npz")
    check_writable(out)
    i, s, r = read_sample(path, split, index, rig)
    with atomic_output(out, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(
                fh,
                partial=s["partial"],
                gt_points=s["gt_points"],
                gt_dense=s["gt_dense"],
                gt_depths=s["gt_depths"],
                model=np.array(s["model"]),
                category=np.array(s["category"]),
                split=np.array(s["split"]),
                view=np.int32(s["view"]),
                sample_index=np.int64(i),
                sensor_to_unit=s["sensor_to_unit"],
                distance=np.float32(s["distance"]),
                heading=np.float32(s["heading"]),
                n_raw=np.int32(s["n_raw"]),
                rig=np.array(json.dumps(r.to_dict())),
            )
    return i, s
