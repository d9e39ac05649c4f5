"""Generic reader: point-cloud files plus boxes in JSON, one frame or a whole sequence.

Three ways to give the data (``SOURCE``):

1. **A scan file** (any kind :func:`spotlights.data.real.scans.read_scan` reads: KITTI
   ``.bin``, nuScenes ``.pcd.bin``, AV2 ``.feather``, PLY, PCD, NPY, NPZ, XYZ, TXT, LAS,
   LAZ) and its box file ``boxes`` (default: the scan's name with ``.json``, e.g.
   ``scan.ply`` -> ``scan.json``). One frame.

2. **A folder of frames**: every scan file in it with a box file of the same name
   (``0001.pcd`` + ``0001.json``, ``a.pcd.bin`` + ``a.json``). Each box file is a box list
   or a per-frame object ``{"timestamp": 0.35, "frame_index": 7, "boxes": [...]}``
   (:mod:`spotlights.data.real.boxfiles`). ``sequence`` defaults to the folder's name.

3. **A sequence (scene) JSON**::

       {"sequence": "drive-a",                   # optional default for the frames
        "frames": [
          {"scan": "scans/0001.ply",           # relative to the JSON file's folder
           "boxes": "boxes/0001.json",         # a per-frame box file, or the box list inline
           "frame_id": "0001",                 # optional (default: the scan's name)
           "timestamp": 0.1,                   # optional float order key (seconds, or any unit)
           "frame_index": 1,                   # optional integer order key
           "sequence": "drive-a",              # optional (default: the top-level one, else "")
           "sensor_to_world": [[...4x4...]]},  # optional
          ...]}

Order and time. Frames are ordered within a sequence by ``timestamp`` (kept as given,
an integer or a float: 0.25 s and 0.5 s stay apart), else by ``frame_index``, else (folders only)
by the scan's name in natural order (``2`` before ``10``); the frame's
:attr:`~spotlights.data.real.base.Frame.timestamp` is that key (the position in the
list when there is none). A sequence must use one kind of key for all its frames.
Keys given in a per-frame box file fill those the sequence JSON leaves out.

A box is an object with ``center`` [x, y, z] (metres, the box centre, in the
scan's frame, z up), ``size`` [length, width, height] (metres), either ``yaw``
(radians about +z, 0 = box x along the scan's x) or ``rotation`` (3x3 nested
list, row-major, whose columns are the box's forward, left, up axes; or a
quaternion w, x, y, z), a ``label`` string, and optionally ``track_id`` (a
string or integer; boxes with the same ``track_id`` in different frames of one
sequence are the same object).

Labels map to classes case-insensitively: the class names themselves (car,
truck, caravan, van, trailer, bus, construction, emergency) and every label the other
readers know (KITTI, KITTI-360, Argoverse 2, nuScenes) are accepted; anything else is
not a vehicle of interest.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ...errors import InputFileError
from ...inputs import path_inside, read_json
from .base import Frame, SceneReader
from .boxfiles import CLASS_MAP, parse_boxes, parse_frame_keys, read_json_boxes  # noqa: F401  (CLASS_MAP re-exported)
from .scans import read_scan, scan_kind

SCAN_NAME_SUFFIXES = (".pcd.bin", ".bin", ".feather", ".ply", ".pcd", ".npy", ".npz", ".xyz", ".txt", ".las", ".laz")


def read_points_file(path: str | os.PathLike) -> np.ndarray:
    """Read a point-cloud file of any supported kind: (N, 3) metres (see :func:`~spotlights.data.real.scans.read_scan`)."""
    return read_scan(path)


def frame_name(path: Path) -> str:
    """A scan file's name without its scan suffix (``a.pcd.bin`` -> ``a``, ``0001.ply`` -> ``0001``)."""
    low = path.name.lower()
    for sfx in SCAN_NAME_SUFFIXES:
        if low.endswith(sfx) and len(low) > len(sfx):
            return path.name[: -len(sfx)]
    return path.stem


def natural_key(text: str) -> list:
    """Sort key that orders digit runs by value (``frame2`` before ``frame10``)."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", text)]


def _order_sequence(frames: list[dict], source) -> None:
    """Set each frame's ``timestamp`` (order key) from timestamp / frame_index / position; one kind per sequence."""
    by_seq: dict[str, list[dict]] = {}
    for f in frames:
        by_seq.setdefault(f["sequence"], []).append(f)
    for seq, fs in by_seq.items():
        kinds = {
            (
                "timestamp"
                if f.get("timestamp") is not None
                else "frame_index"
                if f.get("frame_index") is not None
                else "none"
            )
            for f in fs
        }
        if len(kinds) > 1:
            first = next(f for f in fs if f.get("timestamp") is None)
            raise InputFileError(
                source,
                f"sequence {seq!r} mixes frames with and without a timestamp (e.g. frame "
                f"{first['frame_id']!r}); give every frame a timestamp, or every frame a frame_index",
            )
        kind = kinds.pop()
        for pos, f in enumerate(fs):
            f["timestamp"] = (
                f["timestamp"] if kind == "timestamp" else int(f["frame_index"]) if kind == "frame_index" else pos
            )


#: The dataset formats a folder's layout gives away, with their names in messages.
DATASET_NAMES = {"nuscenes": "nuScenes", "kitti": "KITTI object", "kitti360": "KITTI-360", "av2": "Argoverse 2"}


def dataset_layout(folder: Path) -> str | None:
    """The format (``nuscenes``, ``kitti``, ``kitti360``, ``av2``) whose layout ``folder`` has, from a few names
    in it and one level down (nothing is read), or None: a dataset given as a folder of generic scans."""
    if (folder / "sample_annotation.json").is_file() or any(folder.glob("*/sample_annotation.json")):
        return "nuscenes"
    if (folder / "samples" / "LIDAR_TOP").is_dir():
        return "nuscenes"
    if (folder / "label_2").is_dir() or (folder / "training" / "label_2").is_dir():
        return "kitti"
    if (folder / "data_3d_raw").is_dir():
        return "kitti360"
    if (folder / "annotations.feather").is_file() or any(folder.glob("*/annotations.feather")):
        return "av2"
    return None


class GenericReader(SceneReader):
    """A scan file with its JSON boxes, a folder of frames, or a sequence JSON (see the module doc).

    Parameters
    ----------
    source : the scan file, the folder, or the sequence JSON.
    boxes : for a single scan, its JSON box file (default: the scan's name with ``.json``).
    """

    format = "generic"

    def __init__(self, source: str | os.PathLike, boxes: str | os.PathLike | None = None):
        source = Path(source)
        if not source.exists():
            raise InputFileError(source, "not found")
        self.root = str(source if source.is_dir() else source.parent)
        if boxes is not None and (source.is_dir() or source.suffix.lower() == ".json"):
            raise InputFileError(
                source,
                "--boxes applies to a single scan file SOURCE (a folder or sequence JSON names its own box files)",
            )
        if source.is_dir():
            frames = self._folder(source)
        elif source.suffix.lower() == ".json":
            frames = self._sequence_json(source)
        else:
            box_path = Path(boxes) if boxes is not None else source.with_name(frame_name(source) + ".json")
            bf = read_json_boxes(box_path)
            frames = [
                dict(
                    scan=source,
                    label_path=box_path,
                    frame_id=bf.frame_id or frame_name(source),
                    timestamp=bf.timestamp,
                    frame_index=bf.frame_index,
                    sequence=bf.sequence or "",
                    pose=bf.sensor_to_world,
                    boxes=bf.boxes,
                )
            ]
        if not frames:
            raise InputFileError(source, "no frames")
        keys = [(f["sequence"], f["frame_id"]) for f in frames]
        if len(set(keys)) != len(keys):
            dup = next(k for k in keys if keys.count(k) > 1)
            raise InputFileError(source, f"two frames share the sequence {dup[0]!r} and frame_id {dup[1]!r}")
        _order_sequence(frames, source)
        order = sorted(range(len(frames)), key=lambda i: (frames[i]["sequence"], frames[i]["timestamp"], i))
        self._frames = [frames[i] for i in order]
        self._index = {(f["sequence"], f["frame_id"]): f for f in self._frames}

    @staticmethod
    def _folder(folder: Path) -> list[dict]:
        dataset = dataset_layout(folder)
        if dataset is not None:
            raise InputFileError(
                folder,
                f"this is a {DATASET_NAMES[dataset]} folder, not a folder of scans with NAME.json box files: read it "
                f"with the format {dataset!r} ('spotlights real complete FOLDER --format {dataset}')",
            )
        scans = []
        for p in folder.iterdir():
            if p.is_symlink() and not p.exists():  # a broken link was skipped silently: a frame went missing
                try:
                    scan_kind(p)
                except InputFileError:
                    if p.suffix.lower() != ".json":
                        continue  # not a scan or a box file
                raise InputFileError(p, f"a broken symbolic link (its target {os.readlink(p)!r} does not exist)")
            if not p.is_file() or p.suffix.lower() == ".json":
                continue
            try:
                scan_kind(p)
            except InputFileError:
                continue  # not a scan (README, pictures, ...)
            scans.append(p)
        if not scans:
            raise InputFileError(folder, "no scan files (.bin, .pcd.bin, .ply, .pcd, .npy, .las, ...) in this folder")
        scans.sort(key=lambda p: natural_key(frame_name(p)))
        frames = []
        names = [frame_name(p) for p in scans]
        if len(set(names)) != len(names):
            dup = next(n for n in names if names.count(n) > 1)
            raise InputFileError(folder, f"several scan files are named {dup!r}: one scan per frame name")
        for p, name in zip(scans, names):
            box_path = folder / f"{name}.json"
            if not box_path.is_file():
                hint = "; or give this sequence's sequence.json" if (folder / "sequence.json").is_file() else ""
                raise InputFileError(
                    box_path, f"box file of scan {p.name} not found (each scan needs NAME.json beside it{hint})"
                )
            bf = read_json_boxes(box_path)
            frames.append(
                dict(
                    scan=p,
                    label_path=box_path,
                    frame_id=bf.frame_id or name,
                    timestamp=bf.timestamp,
                    frame_index=bf.frame_index,
                    sequence=bf.sequence if bf.sequence is not None else folder.name,
                    pose=bf.sensor_to_world,
                    boxes=bf.boxes,
                )
            )
        return frames

    @staticmethod
    def _sequence_json(source: Path) -> list[dict]:
        data = read_json(source)
        if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
            raise InputFileError(
                source, 'a sequence file must be {"frames": [...]} (a bare box list needs a scan file as SOURCE)'
            )
        default_seq = str(data["sequence"]) if data.get("sequence") is not None else ""
        frames = []
        for i, fr in enumerate(data["frames"]):
            what = f"frames[{i}]"
            if not isinstance(fr, dict) or "scan" not in fr or not isinstance(fr.get("boxes"), (list, str)):
                raise InputFileError(source, f"{what} needs 'scan' and 'boxes' (a list of boxes, or a box file path)")
            scan = path_inside(source.parent, fr["scan"], source, f"{what} scan").resolve()
            if not scan.is_file():
                raise InputFileError(scan, f"scan file of {what} not found")
            keys = parse_frame_keys(fr, source, what)
            if isinstance(fr["boxes"], str):
                box_path = path_inside(source.parent, fr["boxes"], source, f"{what} boxes").resolve()
                bf = read_json_boxes(box_path)
                boxes, label_path = bf.boxes, box_path
                for k, v in (
                    ("timestamp", bf.timestamp),
                    ("frame_index", bf.frame_index),
                    ("frame_id", bf.frame_id),
                    ("sequence", bf.sequence),
                    ("sensor_to_world", bf.sensor_to_world),
                ):
                    if k not in keys and v is not None:
                        keys[k] = v
            else:
                boxes, label_path = parse_boxes(fr["boxes"], source, what=f"{what} box"), source
            frames.append(
                dict(
                    scan=scan,
                    label_path=label_path,
                    frame_id=keys.get("frame_id", frame_name(scan)),
                    timestamp=keys.get("timestamp"),
                    frame_index=keys.get("frame_index"),
                    sequence=keys.get("sequence", default_seq),
                    pose=keys.get("sensor_to_world"),
                    boxes=boxes,
                )
            )
        return frames

    def frame_keys(self) -> list[tuple[str, str]]:
        return [(f["sequence"], f["frame_id"]) for f in self._frames]

    def load(self, key: tuple[str, str]) -> Frame:
        f = self._index[key]
        return Frame(
            sequence=f["sequence"],
            frame_id=f["frame_id"],
            timestamp=f["timestamp"],
            points=read_scan(f["scan"]),
            boxes=list(f["boxes"]),
            sensor_to_world=f["pose"],
            scan_path=str(f["scan"]),
            label_path=str(f["label_path"]),
        )
