"""Argoverse 2 sensor-dataset reader (Apache Arrow feather files, read with pyarrow).

Layout of one log (``LOG`` = the log id)::

    LOG/sensors/lidar/<timestamp_ns>.feather   columns x, y, z (float16, metres, ego-vehicle frame),
                                               intensity, laser_number, offset_ns
    LOG/annotations.feather                    one cuboid per row: timestamp_ns, track_uuid, category,
                                               length_m, width_m, height_m, qw, qx, qy, qz, tx_m, ty_m, tz_m
                                               (ego-vehicle frame at that timestamp), num_interior_pts
    LOG/city_SE3_egovehicle.feather            ego poses: timestamp_ns, qw, qx, qy, qz, tx_m, ty_m, tz_m

``ROOT`` is one log folder or a folder whose sub-folders (one or two levels
down, e.g. ``sensor/val/``) are logs. Sweeps are already in the ego-vehicle
frame (x forward, y left, z up), and so are the cuboids of the same
``timestamp_ns``: the sensor frame of a frame here is the ego frame. The cuboid
translation is its centre; its rotation (scalar-first quaternion) maps the
cuboid's x (length), y (width), z (height) axes into the ego frame. An annotation row with a NaN
or infinite number, a zero quaternion or a box out of range (:func:`~spotlights.geometry.boxes.box_range_problem`)
is refused: :class:`~spotlights.errors.InputFileError` naming the file and row.

The LiDAR's optical centre (``Frame.sensor_origin``, for free-space reasoning) is the translation
of ``up_lidar`` in ``LOG/calibration/egovehicle_SE3_sensor.feather`` (a sweep merges the roof's
two lidars, ``up_lidar`` and ``down_lidar``, about 0.1 m apart; the upper one stands for both);
all NaN when the log has no calibration file.

``sensor_to_world`` is the pose ``city_SE3_egovehicle`` at the sweep's
timestamp (exact match, else the nearest pose within 50 ms, else ``None``), so
boxes and points of different sweeps can be put in one city frame.

Classes (the AV2 taxonomy has no van class: vans are ``REGULAR_VEHICLE``):
``REGULAR_VEHICLE`` -> car; ``BOX_TRUCK``, ``TRUCK``, ``TRUCK_CAB`` -> truck;
``LARGE_VEHICLE`` (RVs, extended vans, per the AV2 definition) -> caravan;
``VEHICULAR_TRAILER`` -> trailer; ``BUS``, ``SCHOOL_BUS``, ``ARTICULATED_BUS`` -> bus
(not a class of the paper's Table 2: left out by ``real extract``'s default classes).
Message-board trailers, two-wheelers and every other category are not vehicles of interest.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ...errors import InputFileError, ParameterError
from ...geometry.boxes import Box
from ...geometry.rotations import quaternion_to_matrix
from ...outputs import check_regular_file
from .base import Frame, SceneReader, finite_rows, lookup_class

CLASS_MAP: dict[str, str | None] = {
    "regular_vehicle": "car",
    "box_truck": "truck",
    "truck": "truck",
    "truck_cab": "truck",
    "large_vehicle": "caravan",
    "vehicular_trailer": "trailer",
    "bus": "bus",
    "school_bus": "bus",
    "articulated_bus": "bus",
}

ANNOTATION_COLUMNS = (
    "timestamp_ns",
    "track_uuid",
    "category",
    "length_m",
    "width_m",
    "height_m",
    "qw",
    "qx",
    "qy",
    "qz",
    "tx_m",
    "ty_m",
    "tz_m",
)
POSE_COLUMNS = ("timestamp_ns", "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
POSE_TOLERANCE_NS = 50_000_000
CALIBRATION_COLUMNS = ("sensor_name", "tx_m", "ty_m", "tz_m")
LIDAR_SENSOR = "up_lidar"


def _read_feather(path: Path, columns, what: str):
    """Read the named columns of a feather file as a dict of numpy arrays; errors name the file."""
    import pyarrow.feather as feather

    check_regular_file(path, what)  # missing, a folder, a FIFO (reading one would block): one line
    try:
        table = feather.read_table(path)
    except Exception as exc:  # pyarrow raises several types for corrupt files
        raise InputFileError(path, f"cannot read {what}: {str(exc).splitlines()[0]}") from None
    missing = [c for c in columns if c not in table.column_names]
    if missing:
        raise InputFileError(path, f"{what} lacks column(s) {', '.join(missing)}")
    return {c: table.column(c).to_numpy(zero_copy_only=False) for c in columns}


def read_av2_sweep(path: str | os.PathLike) -> np.ndarray:
    """Read an AV2 lidar sweep ``.feather``: (N, 3) float32 x, y, z, metres, ego-vehicle frame, rows with NaN or
    infinite coordinates dropped (:func:`~spotlights.data.real.base.finite_rows`)."""
    cols = _read_feather(Path(path), ("x", "y", "z"), "lidar sweep")
    return finite_rows(np.stack([cols["x"], cols["y"], cols["z"]], axis=1).astype(np.float32))


def pose_matrices(cols: dict) -> np.ndarray:
    """(n, 4, 4) float64 rigid transforms from AV2 pose columns qw..qz, tx_m..tz_m."""
    n = len(cols["qw"])
    t = np.zeros((n, 4, 4))
    t[:, :3, :3] = quaternion_to_matrix(cols["qw"], cols["qx"], cols["qy"], cols["qz"])
    t[:, 0, 3], t[:, 1, 3], t[:, 2, 3] = cols["tx_m"], cols["ty_m"], cols["tz_m"]
    t[:, 3, 3] = 1.0
    return t


def find_logs(root: Path) -> list[Path]:
    """Log folders under ``root`` (itself, or one/two levels down): those with ``sensors/lidar/``."""
    if (root / "sensors" / "lidar").is_dir():
        return [root]
    logs = sorted(p for p in root.glob("*") if (p / "sensors" / "lidar").is_dir())
    if not logs:
        logs = sorted(p for p in root.glob("*/*") if (p / "sensors" / "lidar").is_dir())
    return logs


class _Log:
    """The annotations and poses of one log, read once."""

    def __init__(self, path: Path):
        self.path = path
        self.sweeps = sorted(path.glob("sensors/lidar/*.feather"), key=lambda p: int(p.stem) if p.stem.isdigit() else 0)
        for p in self.sweeps:
            if not p.stem.isdigit():
                raise InputFileError(p, "sweep file name is not a nanosecond timestamp")
        self.ann_path = path / "annotations.feather"
        ann = _read_feather(self.ann_path, ANNOTATION_COLUMNS, "annotations")
        order = np.argsort(ann["timestamp_ns"], kind="stable")
        self.ann = {k: v[order] for k, v in ann.items()}
        numeric = ("length_m", "width_m", "height_m", "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
        for c in numeric:
            self.ann[c] = self.ann[c].astype(np.float64)
        self.ann_rows = order  # each sorted row's row number in the file (for errors)
        # refuse corrupt numbers here, naming the file and row: a NaN would make a box without a rotation
        for c in numeric:
            bad = np.flatnonzero(~np.isfinite(self.ann[c]))
            if len(bad):
                raise InputFileError(
                    self.ann_path, f"row {int(order[bad[0]])}: {c} must be finite, got {self.ann[c][bad[0]]}"
                )
        with np.errstate(over="ignore"):
            qnorm = np.sqrt(sum(self.ann[c] ** 2 for c in ("qw", "qx", "qy", "qz")))
        bad = np.flatnonzero(qnorm < 1e-9)
        if len(bad):
            raise InputFileError(self.ann_path, f"row {int(order[bad[0]])}: the quaternion (qw, qx, qy, qz) is zero")
        bad = np.flatnonzero(~np.isfinite(qnorm))  # finite components whose squares overflow: not a rotation
        if len(bad):
            raise InputFileError(
                self.ann_path, f"row {int(order[bad[0]])}: the quaternion (qw, qx, qy, qz) cannot be normalised"
            )
        pose_path = path / "city_SE3_egovehicle.feather"
        if pose_path.is_file():
            cols = _read_feather(pose_path, POSE_COLUMNS, "ego poses")
            order = np.argsort(cols["timestamp_ns"], kind="stable")
            self.pose_ts = cols["timestamp_ns"][order].astype(np.int64)
            try:
                self.poses = pose_matrices({k: v[order] for k, v in cols.items()})
            except ParameterError as exc:  # a quaternion that cannot be normalised, here naming the file
                raise InputFileError(pose_path, str(exc)) from None
        else:
            self.pose_ts = np.zeros(0, np.int64)
            self.poses = np.zeros((0, 4, 4))
        self.lidar_origin = np.full(3, np.nan)
        calib = path / "calibration" / "egovehicle_SE3_sensor.feather"
        if calib.is_file():
            cols = _read_feather(calib, CALIBRATION_COLUMNS, "sensor calibration")
            rows = np.flatnonzero(cols["sensor_name"].astype(str) == LIDAR_SENSOR)
            if len(rows) == 0:
                raise InputFileError(calib, f"sensor calibration has no {LIDAR_SENSOR} row")
            self.lidar_origin = np.array([cols[c][rows[0]] for c in ("tx_m", "ty_m", "tz_m")], dtype=np.float64)

    def pose_at(self, ts: int) -> np.ndarray | None:
        """city_SE3_egovehicle at ``ts`` (nearest within 50 ms), or None."""
        if len(self.pose_ts) == 0:
            return None
        i = int(np.searchsorted(self.pose_ts, ts))
        cand = [j for j in (i - 1, i) if 0 <= j < len(self.pose_ts)]
        j = min(cand, key=lambda k: abs(int(self.pose_ts[k]) - ts))
        if abs(int(self.pose_ts[j]) - ts) > POSE_TOLERANCE_NS:
            return None
        return self.poses[j].copy()

    def boxes_at(self, ts: int) -> list[Box]:
        a = self.ann
        lo, hi = np.searchsorted(a["timestamp_ns"], [ts, ts + 1])
        if hi <= lo:
            return []
        rot = quaternion_to_matrix(a["qw"][lo:hi], a["qx"][lo:hi], a["qy"][lo:hi], a["qz"][lo:hi])
        boxes = []
        for k, i in enumerate(range(lo, hi)):
            label = str(a["category"][i])
            try:
                box = Box(
                    np.array([a["tx_m"][i], a["ty_m"][i], a["tz_m"][i]]),
                    np.array([a["length_m"][i], a["width_m"][i], a["height_m"][i]]),
                    rot[k],
                    label,
                    lookup_class(label, CLASS_MAP),
                    str(a["track_uuid"][i]),
                )
            except ParameterError as exc:  # out of range (the box's own checks), here naming the file and row
                raise InputFileError(self.ann_path, f"row {int(self.ann_rows[i])}: {exc}") from None
            boxes.append(box)
        return boxes


class Av2Reader(SceneReader):
    """Argoverse 2 sensor logs: one :class:`Frame` per lidar sweep, boxes from ``annotations.feather``.

    Parameters
    ----------
    root : one log folder, or a folder of logs (searched one and two levels down).
    """

    format = "av2"

    def __init__(self, root: str | os.PathLike):
        root = Path(root)
        if not root.is_dir():
            raise InputFileError(root, "not a folder")
        logs = find_logs(root)
        if not logs:
            raise InputFileError(root, "not an Argoverse 2 folder: no <log>/sensors/lidar/ found")
        self.root = str(root)
        self._logs: dict[str, _Log] = {}
        self._keys: list[tuple[str, str]] = []
        for log in logs:
            lg = _Log(log)
            self._logs[log.name] = lg
            self._keys.extend((log.name, p.stem) for p in lg.sweeps)
        if not self._keys:
            raise InputFileError(root, "no lidar sweeps (sensors/lidar/*.feather)")

    def frame_keys(self) -> list[tuple[str, str]]:
        return list(self._keys)

    def load(self, key: tuple[str, str]) -> Frame:
        log_name, stem = key
        lg = self._logs[log_name]
        ts = int(stem)
        scan_path = lg.path / "sensors" / "lidar" / f"{stem}.feather"
        return Frame(
            sequence=log_name,
            frame_id=stem,
            timestamp=ts,
            points=read_av2_sweep(scan_path),
            boxes=lg.boxes_at(ts),
            sensor_to_world=lg.pose_at(ts),
            scan_path=str(scan_path),
            label_path=str(lg.ann_path),
            sensor_origin=lg.lidar_origin.copy(),
        )
