"""Vehicle extraction: the points inside each vehicle box, as unit-frame partial observations.

For every box of a vehicle class (:data:`~spotlights.data.real.base.CLASSES`):

1. Points are expressed in the box's object frame (x forward, y left, z up,
   origin at the box centre, metres): ``p_obj = (p - center) @ rotation``.
2. A point is kept when ``|x| <= l/2 + margin``, ``|y| <= w/2 + margin``,
   ``z <= h/2 + margin`` and ``z >= -h/2 + ground_clearance``: the box grown by
   ``margin`` (default 0.15 m) on every side but the bottom, whose plane is
   raised by ``ground_clearance`` (default 0.10 m) to drop ground returns (on
   the Argoverse 2 and KITTI samples the ground returns lie within about
   +-0.1 m of the box bottom; a car body starts about 0.2 m above it).
3. Boxes with no point left are skipped as ``empty_box``, those with fewer
   than ``min_points`` (default 10) as ``too_few_points``.
4. The kept points are normalised exactly like the synthetic data:
   ``unit = p_obj / R``, R = half the box diagonal
   (:func:`spotlights.geometry.frames.normalization_from_box`), and resampled
   to ``n_points`` (default 256) by
   :func:`spotlights.geometry.sampling.resample_set`: the points in a canonical
   (sorted) order, then a random subset without replacement drawn with ``seed``
   (or all points plus random repeats when there are fewer). The input of an
   observation depends only on its points and ``seed`` - not on the order or the
   number of frames processed, nor on the command: ``spotlights complete`` on the
   same scan and box feeds the model the same 256 points.
5. Every kept point (before resampling, unit frame) is stored too
   (``raw_points``/``raw_offsets``): ``real evaluate`` resamples them with a second
   seed to measure the resampling noise floor.

Skip reasons (counted, never silent): ``class_excluded`` (the label is not a
vehicle of interest; also counted per source label), ``invalid_box``
(non-finite or non-positive size), ``empty_box``, ``too_few_points``,
``duplicate_box`` (the same box annotated twice in one frame, see
:data:`DUPLICATE_TOLERANCE_M`: the copy with the smallest (track id, box index) is
kept (track ids compared as text), the same one in every frame, so that an object is
scored once).
"""

from __future__ import annotations

import json
import os
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..._version import __version__
from ...errors import InputFileError, ParameterError
from ...geometry.boxes import Box
from ...geometry.sampling import resample_set
from ...outputs import atomic_output, hdf5_output
from ..store import MAX_PARTIAL_POINTS, int_attribute, json_attribute
from .base import CLASSES, PAPER_CLASSES, Frame, SceneReader

FILE_FORMAT = "spotlights-real-observations"
FILE_FORMAT_VERSION = 2
"""2: ``timestamp`` int64 or float64 (float keys are no longer cut), ``raw_points`` and ``raw_offsets``
added. Version 1 files are read (timestamps int64, no raw points)."""
SKIP_REASONS = ("class_excluded", "invalid_box", "empty_box", "too_few_points", "duplicate_box")
DUPLICATE_TOLERANCE_M = 0.05
"""Two vehicle boxes of one frame whose centres and sizes agree within this (metres, per
coordinate) and whose axes agree within 0.01 (rotation matrix entries) are one object
annotated twice (the shared Argoverse 2 sweeps hold such a pair under two track ids)."""


@dataclass(frozen=True)
class ExtractConfig:
    """Parameters of the extraction (see the module docstring). Lengths in metres."""

    margin: float = 0.15
    ground_clearance: float = 0.10
    min_points: int = 10
    n_points: int = 256
    seed: int = 0
    classes: tuple[str, ...] = PAPER_CLASSES

    def __post_init__(self):
        if not (np.isfinite(self.margin) and self.margin >= 0):
            raise ParameterError(f"margin must be >= 0 metres, got {self.margin}")
        if not np.isfinite(self.ground_clearance):
            raise ParameterError(f"ground clearance must be finite, got {self.ground_clearance}")
        if self.min_points < 1:
            raise ParameterError(f"minimum point count must be >= 1, got {self.min_points}")
        if not 1 <= self.n_points <= MAX_PARTIAL_POINTS:
            raise ParameterError(
                f"`points`: 1..{MAX_PARTIAL_POINTS} points per observation, got {self.n_points}", "points"
            )
        bad = [c for c in self.classes if c not in CLASSES]
        if bad or not self.classes:
            raise ParameterError(f"unknown class(es) {bad}; choose among {', '.join(CLASSES)}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["classes"] = list(self.classes)
        return d


@dataclass
class Observations:
    """Partial observations of real vehicles, one row each (the content of the HDF5 file).

    Arrays (n = number of observations):

    - ``partial`` (n, P, 3) float32: the resampled points, unit frame of the box.
    - ``n_points_raw`` (n,) int32: points inside the (grown, ground-cut) box before resampling.
    - ``timestamp`` (n,) int64 or float64: the frame's order key (ns for AV2, µs for nuScenes,
      frame index for KITTI, as given for generic frames); float64 as soon as one key is not an integer.
    - ``box_center`` (n, 3), ``box_size`` (n, 3) = (l, w, h), ``box_yaw`` (n,) radians,
      ``box_rotation`` (n, 3, 3) (columns = box axes): float64, metres, sensor frame.
    - ``unit_to_sensor`` (n, 4, 4) float64: homogeneous unit frame -> sensor frame
      (``p_sensor = M[:3,:3] @ q + M[:3,3]``).
    - ``sensor_to_world`` (n, 4, 4) float64: the scan's pose, all NaN when unknown.
    - ``sensor_origin`` (n, 3) float64: the LiDAR's optical centre in the unit frame of the box
      (``Frame.lidar_origin()`` mapped by the box's normalisation), for free-space reasoning; a NaN
      row when unknown (an Argoverse 2 log without calibration, a file written before the field).
    - strings (lists of n): ``sequence``, ``frame_id``, ``track_id`` ("" = untracked),
      ``cls`` (one of CLASSES), ``label`` (the dataset's label), ``scan_path``, ``label_path``.

    - ``raw_points`` (total, 3) float32 and ``raw_offsets`` (n + 1,) int64: every kept point of
      observation i (unit frame, before resampling) is ``raw_points[raw_offsets[i]:raw_offsets[i+1]]``
      (:meth:`raw`); empty (offsets all 0) for files of format version 1.

    ``meta``: source format, source path, config dict, ``skipped`` {reason: count},
    ``skipped_labels`` {label: count}, ``n_frames``, ``n_boxes``.
    """

    partial: np.ndarray
    n_points_raw: np.ndarray
    timestamp: np.ndarray
    box_center: np.ndarray
    box_size: np.ndarray
    box_yaw: np.ndarray
    box_rotation: np.ndarray
    unit_to_sensor: np.ndarray
    sensor_to_world: np.ndarray
    sequence: list[str]
    frame_id: list[str]
    track_id: list[str]
    cls: list[str]
    label: list[str]
    scan_path: list[str]
    label_path: list[str]
    meta: dict = field(default_factory=dict)
    raw_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    raw_offsets: np.ndarray | None = None
    sensor_origin: np.ndarray | None = None

    def __post_init__(self):
        if self.raw_offsets is None:
            self.raw_offsets = np.zeros(len(self) + 1, dtype=np.int64)
        if self.sensor_origin is None:
            self.sensor_origin = np.full((len(self), 3), np.nan)

    def __len__(self) -> int:
        return int(self.partial.shape[0])

    @property
    def has_raw(self) -> bool:
        """True when every observation's kept points are stored (format version 2)."""
        return len(self) > 0 and bool(np.all(np.diff(self.raw_offsets) > 0))

    def raw(self, i: int) -> np.ndarray:
        """(n_points_raw[i], 3) float32 unit-frame points of observation ``i`` before resampling."""
        if not self.has_raw:
            raise InputFileError(
                self.meta.get("file", "observations"),
                "holds no raw points (format version 1): extract it again with this spotlights",
            )
        return self.raw_points[self.raw_offsets[i] : self.raw_offsets[i + 1]]

    def object_keys(self) -> list[tuple[str, str]]:
        """(sequence, track_id) of every observation ("" track ids stay distinct per row)."""
        return [(s, t) if t else (s, f"#{i}") for i, (s, t) in enumerate(zip(self.sequence, self.track_id))]


_ARRAYS = (
    "partial",
    "n_points_raw",
    "timestamp",
    "box_center",
    "box_size",
    "box_yaw",
    "box_rotation",
    "unit_to_sensor",
    "sensor_to_world",
)
_STRINGS = ("sequence", "frame_id", "track_id", "cls", "label", "scan_path", "label_path")


def points_in_box(points: np.ndarray, box: Box, margin: float, ground_clearance: float) -> np.ndarray:
    """Boolean mask (N,) of the sensor-frame points (N, 3) inside ``box`` grown by ``margin``
    (sides and top, metres) with its bottom raised by ``ground_clearance`` metres
    (:meth:`spotlights.geometry.boxes.Box.contains`)."""
    return box.contains(points, margin=margin, ground_clearance=ground_clearance)


def duplicate_boxes(boxes: list[Box], tol: float = DUPLICATE_TOLERANCE_M) -> set[int]:
    """Indices of the boxes that repeat another box of the list (same centre, size and axes).

    Among copies of one box the one with the smallest ``(track_id, index)`` (track ids compared
    as text) is kept (not returned), so that a doubly annotated object keeps the same track in
    every frame. Pairwise tests vectorised: a frame holds at most a few hundred boxes.
    """
    n = len(boxes)
    if n < 2:
        return set()
    c = np.array([b.center for b in boxes], dtype=np.float64)
    z = np.array([b.size for b in boxes], dtype=np.float64)
    r = np.array([b.rotation for b in boxes], dtype=np.float64).reshape(n, 9)
    same = (
        (np.abs(c[:, None] - c[None]) <= tol).all(-1)
        & (np.abs(z[:, None] - z[None]) <= tol).all(-1)
        & (np.abs(r[:, None] - r[None]) <= 0.01).all(-1)
    )
    # Greedy in (track id as text, index) order: a box is a duplicate when it matches a box
    # already kept (the relation is not transitive: a chain of boxes 4 cm apart keeps every
    # other one, never a box farther than the tolerance from every kept box).
    order = sorted(range(n), key=lambda i: (str(boxes[i].track_id), i))
    kept: list[int] = []
    dup: set[int] = set()
    for i in order:
        if kept and same[i, kept].any():
            dup.add(i)
        else:
            kept.append(i)
    return dup


def extract_frame(frame: Frame, config: ExtractConfig, skipped: Counter, skipped_labels: Counter) -> list[dict]:
    """Observations of one frame (a list of dicts, see :class:`Observations`); updates the skip counters."""
    out = []
    pts = np.asarray(frame.points, dtype=np.float64)
    pose = frame.sensor_to_world if frame.sensor_to_world is not None else np.full((4, 4), np.nan)
    wanted = [i for i, b in enumerate(frame.boxes) if b.cls is not None and b.cls in config.classes and b.is_valid()]
    duplicates = duplicate_boxes([frame.boxes[i] for i in wanted])
    duplicates = {wanted[j] for j in duplicates}
    for i, box in enumerate(frame.boxes):
        if box.cls is None or box.cls not in config.classes:
            skipped["class_excluded"] += 1
            skipped_labels[box.label] += 1
            continue
        if not box.is_valid():
            skipped["invalid_box"] += 1
            continue
        if i in duplicates:
            skipped["duplicate_box"] += 1
            continue
        inside = box.crop(pts, config.margin, config.ground_clearance)
        n = int(inside.size)
        if n == 0:
            skipped["empty_box"] += 1
            continue
        if n < config.min_points:
            skipped["too_few_points"] += 1
            continue
        norm = box.normalization()
        unit = norm.to_unit(pts[inside])
        partial = resample_set(unit, config.n_points, seed=config.seed).astype(np.float32)
        out.append(
            dict(
                partial=partial,
                raw=unit.astype(np.float32),
                n_points_raw=n,
                timestamp=frame.timestamp,
                box_center=box.center,
                box_size=box.size,
                box_yaw=box.yaw,
                box_rotation=box.rotation,
                unit_to_sensor=norm.inverse_matrix,
                sensor_to_world=pose,
                sensor_origin=norm.to_unit(frame.lidar_origin()),
                sequence=frame.sequence,
                frame_id=frame.frame_id,
                track_id=box.track_id,
                cls=box.cls,
                label=box.label,
                scan_path=frame.scan_path,
                label_path=frame.label_path,
            )
        )
    return out


def extract(reader: SceneReader, config: ExtractConfig | None = None, progress: bool = True) -> Observations:
    """Extract every vehicle observation of a dataset.

    Parameters
    ----------
    reader : an opened dataset (:func:`spotlights.data.real.open_reader`).
    config : extraction parameters (default :class:`ExtractConfig`).
    progress : show a tqdm progress bar over frames.

    Returns
    -------
    :class:`Observations` in reader order (frames), then box order within a frame.
    """
    from tqdm import tqdm

    config = config or ExtractConfig()
    skipped: Counter = Counter({r: 0 for r in SKIP_REASONS})
    skipped_labels: Counter = Counter()
    rows: list[dict] = []
    keys = reader.frame_keys()
    n_boxes = 0
    for key in tqdm(keys, desc="extract", unit="frame", disable=not progress):
        frame = reader.load(key)
        n_boxes += len(frame.boxes)
        rows.extend(extract_frame(frame, config, skipped, skipped_labels))
    meta = dict(
        source_format=reader.format,
        source=str(Path(reader.root).resolve()) if reader.root else "",
        config=config.to_dict(),
        skipped=dict(skipped),
        skipped_labels=dict(sorted(skipped_labels.items())),
        n_frames=len(keys),
        n_boxes=n_boxes,
    )
    return _stack(rows, config.n_points, meta)


def _stack(rows: list[dict], n_points: int, meta: dict) -> Observations:
    n = len(rows)

    def arr(name, shape, dtype):
        if n == 0:
            return np.zeros((0,) + shape, dtype=dtype)
        return np.stack([np.asarray(r[name], dtype=dtype) for r in rows]).reshape((n,) + shape)

    ts_dtype = np.int64 if all(isinstance(r["timestamp"], (int, np.integer)) for r in rows) else np.float64
    raw = [r["raw"] for r in rows] if all("raw" in r for r in rows) else []  # rows without raw points: none stored
    offsets = np.zeros(n + 1, dtype=np.int64)
    if raw:
        offsets[1:] = np.cumsum([len(r) for r in raw])
    return Observations(
        partial=arr("partial", (n_points, 3), np.float32),
        n_points_raw=arr("n_points_raw", (), np.int32),
        timestamp=arr("timestamp", (), ts_dtype),
        box_center=arr("box_center", (3,), np.float64),
        box_size=arr("box_size", (3,), np.float64),
        box_yaw=arr("box_yaw", (), np.float64),
        box_rotation=arr("box_rotation", (3, 3), np.float64),
        unit_to_sensor=arr("unit_to_sensor", (4, 4), np.float64),
        sensor_to_world=arr("sensor_to_world", (4, 4), np.float64),
        sensor_origin=np.array([r.get("sensor_origin", (np.nan,) * 3) for r in rows], np.float64).reshape(n, 3),
        **{s: [str(r[s]) for r in rows] for s in _STRINGS},
        meta=meta,
        raw_points=np.concatenate(raw).astype(np.float32) if raw else np.zeros((0, 3), np.float32),
        raw_offsets=offsets,
    )


def write_observations(path: str | os.PathLike, obs: Observations) -> Path:
    """Write observations to HDF5 atomically (schema in ``docs/real-data.md``); returns the path."""
    import h5py

    path = Path(path)
    with atomic_output(path, suffix=".h5") as tmp:
        with hdf5_output(tmp, "w", track_order=False) as (f, _):
            f.attrs["format"] = FILE_FORMAT
            f.attrs["format_version"] = FILE_FORMAT_VERSION
            f.attrs["spotlights_version"] = __version__
            f.attrs["source_format"] = obs.meta.get("source_format", "")
            f.attrs["source"] = obs.meta.get("source", "")
            f.attrs["config_json"] = json.dumps(obs.meta.get("config", {}), sort_keys=True)
            f.attrs["skipped_json"] = json.dumps(obs.meta.get("skipped", {}), sort_keys=True)
            f.attrs["skipped_labels_json"] = json.dumps(obs.meta.get("skipped_labels", {}), sort_keys=True)
            f.attrs["n_frames"] = int(obs.meta.get("n_frames", 0))
            f.attrs["n_boxes"] = int(obs.meta.get("n_boxes", 0))
            f.attrs["classes"] = ",".join(CLASSES)
            g = f.create_group("observations")
            n = len(obs)
            for name in _ARRAYS:
                a = getattr(obs, name)
                kw = {}
                if name == "partial" and n:
                    kw = dict(chunks=(1,) + a.shape[1:], compression="gzip", compression_opts=4, shuffle=True)
                g.create_dataset(name, data=a, **kw)
            raw_kw = dict(compression="gzip", compression_opts=4, shuffle=True) if len(obs.raw_points) else {}
            g.create_dataset("raw_points", data=np.asarray(obs.raw_points, np.float32).reshape(-1, 3), **raw_kw)
            g.create_dataset("raw_offsets", data=np.asarray(obs.raw_offsets, np.int64))
            g.create_dataset("sensor_origin", data=np.asarray(obs.sensor_origin, np.float64).reshape(n, 3))
            st = h5py.string_dtype("utf-8")
            for name in _STRINGS:
                g.create_dataset(name, data=np.array(getattr(obs, name), dtype=object), dtype=st, shape=(n,))
    return path


def _observation_file_version(path: Path, f) -> int:
    """The ``format_version`` of an open real-observation file; raises InputFileError for another
    format or a newer version."""
    if f.attrs.get("format") != FILE_FORMAT:
        raise InputFileError(
            path,
            f"not a real-observation file (format attribute {f.attrs.get('format')!r}, expected {FILE_FORMAT!r}; make one with 'spotlights real extract')",
        )
    version = int_attribute(path, f.attrs, "format_version", 1)
    if version > FILE_FORMAT_VERSION:
        raise InputFileError(path, f"format version {version} is newer than this spotlights ({FILE_FORMAT_VERSION})")
    return version


def _observation_datasets(path: Path, f, version: int) -> tuple[dict, dict]:
    """``(arrays, strings)``: the ``/observations`` numeric datasets (with the raw points and sensor
    origins when the file has them) and string columns; raises InputFileError for a missing one."""
    g = f.get("observations")
    missing = [k for k in _ARRAYS + _STRINGS if g is None or k not in g]
    if missing:
        raise InputFileError(path, f"missing dataset(s) {', '.join('observations/' + m for m in missing)}")
    arrays = {k: g[k][()] for k in _ARRAYS}
    if version >= 2 and "raw_points" in g and "raw_offsets" in g:
        arrays["raw_points"] = g["raw_points"][()]
        arrays["raw_offsets"] = g["raw_offsets"][()]
    if "sensor_origin" in g:  # absent from files written before it: NaN rows (Observations)
        arrays["sensor_origin"] = g["sensor_origin"][()]
    strings = {k: [s.decode("utf-8") if isinstance(s, bytes) else str(s) for s in g[k][()]] for k in _STRINGS}
    return arrays, strings


def _check_observation_arrays(path: Path, arrays: dict, strings: dict) -> None:
    """Equal lengths, ``sensor_origin`` (N, 3), ``raw_offsets`` indexing ``raw_points`` and finite
    scans, sizes and frames; raises InputFileError naming the first bad row."""
    n = arrays["partial"].shape[0]
    if any(len(arrays[k]) != n for k in _ARRAYS) or any(len(v) != n for v in strings.values()):
        raise InputFileError(path, "observation datasets have different lengths")
    if "sensor_origin" in arrays and arrays["sensor_origin"].shape != (n, 3):
        raise InputFileError(
            path, f"observations/sensor_origin has shape {arrays['sensor_origin'].shape}, expected ({n}, 3)"
        )
    if "raw_offsets" in arrays:
        off = arrays["raw_offsets"]
        if off.shape != (n + 1,) or off[0] != 0 or np.any(np.diff(off) < 0) or off[-1] != len(arrays["raw_points"]):
            raise InputFileError(path, "observations/raw_offsets do not index observations/raw_points")
    for key, what in (
        ("partial", "partial scans contain NaN or infinite coordinates"),
        ("box_size", "box sizes must be finite"),
        ("unit_to_sensor", "box frames must be finite"),
    ):
        a = np.asarray(arrays[key])
        if a.dtype.kind != "f" or not np.isfinite(a).all():  # the first bad row, named with the file
            bad = 0 if a.dtype.kind != "f" else int(np.argmin(np.isfinite(a).reshape(n, -1).all(axis=1)))
            raise InputFileError(path, f"observations/{key}[{bad}]: {what}")


def read_observations(path: str | os.PathLike) -> Observations:
    """Read a file written by :func:`write_observations`; errors name the file."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "file not found")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputFileError(path, f"not an HDF5 file ({str(exc).splitlines()[0]})") from None
    with f:
        version = _observation_file_version(path, f)
        arrays, strings = _observation_datasets(path, f, version)
        meta = dict(
            source_format=str(f.attrs.get("source_format", "")),
            source=str(f.attrs.get("source", "")),
            config=json_attribute(path, f.attrs, "config_json", dict, {}),
            skipped=json_attribute(path, f.attrs, "skipped_json", dict, {}),
            skipped_labels=json_attribute(path, f.attrs, "skipped_labels_json", dict, {}),
            n_frames=int_attribute(path, f.attrs, "n_frames", 0, minimum=0),
            n_boxes=int_attribute(path, f.attrs, "n_boxes", 0, minimum=0),
        )
    _check_observation_arrays(path, arrays, strings)
    meta["file"] = str(path)
    meta["format_version"] = version
    return Observations(**arrays, **strings, meta=meta)
