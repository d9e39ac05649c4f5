"""A spinning multi-beam LiDAR simulator for vehicles standing on a ground plane.

Sensor model (:class:`SensorModel`, default :func:`hdl64e`)
----------------------------------------------------------
* ``n_beams`` lasers at fixed elevations: by default evenly spaced from
  ``elevation_max`` (+2.0 deg) down to ``elevation_min`` (-24.9 deg), the
  Velodyne HDL-64E's vertical field of view (64 beams, 0.43 deg apart). An
  explicit list of elevations can be given instead.
* The head spins about its z axis and fires every beam at the azimuths
  ``phi_j = j * step`` (degrees, counter-clockwise from the sensor's +x), ``j = 0 ..
  n_columns - 1`` with ``n_columns = round(360 / azimuth_step)``: the effective
  step is ``360 / n_columns`` so that a revolution holds a whole number of
  columns. Default 0.17 deg, the HDL-64E at 10 Hz (KITTI), ~2118 columns.
* Every ray starts at the optical centre, the origin of the sensor frame
  (x forward, y left, z up, metres, the KITTI Velodyne convention), mounted
  ``mount_height`` (1.73 m, KITTI) above a flat ground plane ``z = -mount_height``.
* A return is the first surface hit along the ray. Returns closer than
  ``min_range`` or farther than ``max_range`` are lost; each return is lost with
  probability ``dropout`` (independently: absorbing/glossy surfaces), and each
  beam is dead for a whole scan with probability ``beam_dropout``; the range
  gets Gaussian noise of standard deviation ``range_noise`` (2 cm) along the ray.
  Motion during the sweep (rolling shutter), beam divergence, intensity and
  multiple returns are not modelled.

Scene (:class:`VehiclePose`)
----------------------------
One vehicle mesh, in its object frame (x forward, y left, z up, metres), its
axis-aligned box standing on the ground: the box bottom touches ``z = -h``.
Its box centre is at horizontal ``distance`` and bearing ``azimuth`` from the
sensor, its forward axis at yaw ``heading`` (radians, counter-clockwise from
the sensor's +x). Rays that hit the ground first are occluded there; ground
returns are not object points and are dropped.

Speed
-----
The simulator never casts a full revolution: it computes the azimuth and
elevation window that the vehicle's box can occupy as seen from the sensor and
casts only the (beam, column) pairs inside it, all in one Embree call on a BVH
built once per mesh (in the object frame: the rays are moved, not the mesh).
The ground is intersected analytically.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field

import numpy as np

from ..errors import ParameterError
from ..geometry.frames import Normalization
from ..geometry.raycast import RayCaster
from ..geometry.rotations import rotation_z
from ..options import settings_from_dict
from ..timing import StageTimer

MIN_AZIMUTH_STEP = 0.01
"""The finest azimuth step a sensor may have (degrees; ``dataset build --azimuth-step``): 10 times finer than the
finest spinning LiDARs (about 0.1 degrees; the HDL-64E's is 0.17). A 64-beam scan then casts 2.3 million rays;
1e-6 asked for 23 billion and the workers died of MemoryError."""


@dataclass(frozen=True)
class SensorModel:
    """A spinning multi-beam LiDAR (see the module docstring for the model).

    Attributes
    ----------
    name : preset name, informative (e.g. ``"hdl64e"``).
    n_beams : number of lasers (used with ``elevation_max``/``elevation_min``).
    elevation_max, elevation_min : elevation of the top and bottom beam, degrees.
    elevations : optional explicit beam elevations in degrees (overrides the
        three fields above; ``n_beams`` is then its length).
    azimuth_step : horizontal angle between two firings of a beam, degrees.
    mount_height : height of the optical centre above the ground, metres.
    min_range, max_range : returns outside [min_range, max_range] metres are lost.
    range_noise : standard deviation of the Gaussian range noise, metres.
    dropout : probability that a return is lost, in [0, 1).
    beam_dropout : probability that a whole beam returns nothing during a scan, in [0, 1).
    """

    name: str = "hdl64e"
    n_beams: int = 64
    elevation_max: float = 2.0
    elevation_min: float = -24.9
    elevations: tuple[float, ...] | None = None
    azimuth_step: float = 0.17
    mount_height: float = 1.73
    min_range: float = 0.9
    max_range: float = 120.0
    range_noise: float = 0.02
    dropout: float = 0.0
    beam_dropout: float = 0.0

    def __post_init__(self):
        if self.elevations is not None:
            el = tuple(float(e) for e in self.elevations)
            if not el or not all(math.isfinite(e) and -90.0 < e < 90.0 for e in el):
                raise ParameterError("sensor elevations must be a non-empty list of angles in (-90, 90) degrees")
            object.__setattr__(self, "elevations", el)
            object.__setattr__(self, "n_beams", len(el))
        elif not (int(self.n_beams) >= 1 and -90.0 < self.elevation_min <= self.elevation_max < 90.0):
            raise ParameterError(
                f"sensor needs n_beams >= 1 and -90 < elevation_min <= elevation_max < 90, got "
                f"{self.n_beams}, {self.elevation_min}, {self.elevation_max}"
            )
        if not (MIN_AZIMUTH_STEP <= self.azimuth_step <= 90.0):
            raise ParameterError(
                f"azimuth step must be in [{MIN_AZIMUTH_STEP:g}, 90] degrees (the finest spinning LiDAR's is ~0.1), "
                f"got {self.azimuth_step}"
            )
        if not (self.mount_height > 0.0):
            raise ParameterError(f"mount height must be > 0 m, got {self.mount_height}")
        if not (0.0 <= self.min_range < self.max_range):
            raise ParameterError(f"need 0 <= min_range < max_range, got {self.min_range}, {self.max_range}")
        if not (self.range_noise >= 0.0):
            raise ParameterError(f"range noise must be >= 0 m, got {self.range_noise}")
        if not (0.0 <= self.dropout < 1.0):
            raise ParameterError(f"dropout must be in [0, 1), got {self.dropout}")
        if not (0.0 <= self.beam_dropout < 1.0):
            raise ParameterError(f"beam dropout must be in [0, 1), got {self.beam_dropout}")

    @property
    def beam_elevations(self) -> np.ndarray:
        """(n_beams,) float64 beam elevations in degrees, top beam first."""
        if self.elevations is not None:
            return np.asarray(self.elevations, dtype=np.float64)
        if self.n_beams == 1:
            return np.array([self.elevation_max], dtype=np.float64)
        return np.linspace(self.elevation_max, self.elevation_min, int(self.n_beams))

    @property
    def n_columns(self) -> int:
        """Firings of each beam per revolution: ``round(360 / azimuth_step)``."""
        return max(1, int(round(360.0 / self.azimuth_step)))

    @property
    def effective_azimuth_step(self) -> float:
        """The step actually used, ``360 / n_columns`` degrees."""
        return 360.0 / self.n_columns

    def to_dict(self) -> dict:
        """JSON-serialisable description (:meth:`from_dict` rebuilds it)."""
        d = asdict(self)
        d["elevations"] = list(self.elevations) if self.elevations is not None else None
        return d

    @classmethod
    def from_dict(cls, d: dict, where: str | os.PathLike = "sensor") -> SensorModel:
        """Rebuild from :meth:`to_dict` output by the one strict policy
        (:func:`spotlights.options.settings_from_dict`): an unknown key is a one-line error naming
        ``where`` (a file path or a label, default ``"sensor"``) with the closest field suggested."""
        d = dict(d) if isinstance(d, Mapping) else d
        if isinstance(d, dict) and d.get("elevations") is not None:
            d["elevations"] = tuple(d["elevations"])
        return settings_from_dict(cls, d, where)


def hdl64e(**overrides) -> SensorModel:
    """Velodyne HDL-64E as in KITTI: 64 beams +2..-24.9 deg, 0.17 deg at 10 Hz, 1.73 m high, 2 cm noise."""
    return SensorModel(**{"name": "hdl64e", **overrides})


SENSOR_PRESETS = {
    "hdl64e": dict(name="hdl64e"),
    # Velodyne HDL-32E: 32 beams +10.67..-30.67 deg, 0.16 deg at 10 Hz (nuScenes, roof at ~1.84 m).
    "hdl32e": dict(
        name="hdl32e",
        n_beams=32,
        elevation_max=10.67,
        elevation_min=-30.67,
        azimuth_step=0.16,
        mount_height=1.84,
        max_range=100.0,
    ),
    # Velodyne VLP-16: 16 beams +15..-15 deg, 0.2 deg at 10 Hz.
    "vlp16": dict(
        name="vlp16",
        n_beams=16,
        elevation_max=15.0,
        elevation_min=-15.0,
        azimuth_step=0.2,
        mount_height=1.73,
        max_range=100.0,
        range_noise=0.03,
    ),
}


def sensor_preset(name: str, **overrides) -> SensorModel:
    """A :class:`SensorModel` from a preset name (``hdl64e``, ``hdl32e``, ``vlp16``) with overrides."""
    key = str(name).lower()
    if key not in SENSOR_PRESETS:
        raise ParameterError(f"unknown sensor {name!r}; known: {', '.join(SENSOR_PRESETS)}")
    over = {k: v for k, v in overrides.items() if v is not None}
    return SensorModel(**{**SENSOR_PRESETS[key], **over})


@dataclass(frozen=True)
class VehiclePose:
    """Where the vehicle stands, relative to the sensor.

    distance : horizontal distance from the sensor to the box centre, metres.
    azimuth : bearing of the box centre, radians counter-clockwise from the sensor's +x.
    heading : yaw of the vehicle's forward axis, radians counter-clockwise from the sensor's +x.
    mount_height : the sensor's height above the ground for this scan, metres (None: the
        sensor model's ``mount_height``); lets a dataset vary the mounting per view.
    """

    distance: float
    azimuth: float
    heading: float
    mount_height: float | None = None


@dataclass
class Scan:
    """The returns of one simulated scan of one vehicle.

    points : (K, 3) float64 returns in the vehicle's *object* frame (metres).
    beam : (K,) int64 beam index of each return (0 = top beam).
    column : (K,) int64 azimuth column of each return (phi = column * effective step).
    n_rays : number of rays cast (the window), for statistics.
    """

    points: np.ndarray
    beam: np.ndarray
    column: np.ndarray
    n_rays: int
    timings: dict = field(default_factory=dict)


class LidarSimulator:
    """Scans one mesh standing on the ground with a :class:`SensorModel`.

    Parameters
    ----------
    vertices : (V, 3) float mesh vertices in the object frame (x forward, y left, z up, metres).
    faces : (F, 3) int triangle indices.
    sensor : the sensor model.

    The BVH is built once; :meth:`scan` may be called for many poses.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, sensor: SensorModel | None = None):
        v = np.asarray(vertices, dtype=np.float64)
        self.sensor = sensor if sensor is not None else hdl64e()
        self.caster = RayCaster(v, faces)
        self.lo = v.min(axis=0)
        self.hi = v.max(axis=0)
        self.center = (self.lo + self.hi) / 2.0
        self.size = self.hi - self.lo
        self._elev = np.radians(self.sensor.beam_elevations)
        self._step = math.radians(self.sensor.effective_azimuth_step)

    @property
    def footprint_radius(self) -> float:
        """Half the diagonal of the box's footprint (metres): the sensor must stay farther than this."""
        return 0.5 * float(math.hypot(self.size[0], self.size[1]))

    # --- frames -----------------------------------------------------------------------------
    def box_center_in_sensor(self, pose: VehiclePose) -> np.ndarray:
        """(3,) float64 box centre in the sensor frame (the box bottom on the ground ``z = -h``,
        ``h`` = ``pose.mount_height`` or the sensor's ``mount_height``)."""
        h = self.sensor.mount_height if pose.mount_height is None else float(pose.mount_height)
        return np.array(
            [
                pose.distance * math.cos(pose.azimuth),
                pose.distance * math.sin(pose.azimuth),
                -h + self.size[2] / 2.0,
            ]
        )

    def object_to_sensor(self, pose: VehiclePose) -> np.ndarray:
        """(4, 4) float64 homogeneous transform object frame -> sensor frame for ``pose``."""
        m = np.eye(4)
        r = rotation_z(pose.heading)
        m[:3, :3] = r
        m[:3, 3] = self.box_center_in_sensor(pose) - r @ self.center
        return m

    def box_normalization(self, pose: VehiclePose) -> Normalization:
        """Sensor frame -> unit frame: the vehicle's box as a detector would give it (centre, size, yaw).

        ``to_unit`` of a sensor-frame point equals ``(p_object - box centre) / R``, R = half the
        box diagonal: the same unit frame as the mesh's ground truth.
        """
        return Normalization(
            center=self.box_center_in_sensor(pose),
            radius=0.5 * float(np.linalg.norm(self.size)),
            rotation=rotation_z(pose.heading),
            size=self.size,
        )

    # --- scanning ----------------------------------------------------------------------------
    def window(self, pose: VehiclePose) -> tuple[np.ndarray, np.ndarray]:
        """The (beam, column) pairs whose rays can reach the vehicle's box.

        Returns
        -------
        beams : (B,) int64 indices of the beams whose elevation lies in the box's elevation range.
        columns : (C,) int64 azimuth columns (mod n_columns) inside the box's azimuth range.
        """
        s = self.sensor
        origin = self._sensor_in_object(pose)
        # Footprint corners relative to the sensor (object frame, horizontal).
        cx = np.array([self.lo[0], self.hi[0], self.hi[0], self.lo[0]]) - origin[0]
        cy = np.array([self.lo[1], self.lo[1], self.hi[1], self.hi[1]]) - origin[1]
        # Azimuth range: a convex footprint not containing the sensor spans (< 180 deg) the
        # range of its corners' bearings, measured relative to the bearing of its centre.
        mid = math.atan2(self.center[1] - origin[1], self.center[0] - origin[0])
        rel = np.angle(np.exp(1j * (np.arctan2(cy, cx) - mid)))
        lo_az = mid + float(rel.min()) + pose.heading
        hi_az = mid + float(rel.max()) + pose.heading
        step = self._step
        j0 = math.ceil(lo_az / step - 1e-9)
        j1 = math.floor(hi_az / step + 1e-9)
        columns = np.mod(np.arange(j0, j1 + 1, dtype=np.int64), s.n_columns)
        # Elevation range: horizontal distance from the sensor to the footprint, nearest and farthest.
        dx = max(self.lo[0] - origin[0], 0.0, origin[0] - self.hi[0])
        dy = max(self.lo[1] - origin[1], 0.0, origin[1] - self.hi[1])
        dmin = math.hypot(dx, dy)
        dmax = float(np.sqrt(cx**2 + cy**2).max())
        dz_top = self.hi[2] - origin[2]
        dz_bot = self.lo[2] - origin[2]
        e_hi = math.atan2(dz_top, dmin if dz_top > 0 else dmax)
        e_lo = math.atan2(dz_bot, dmin if dz_bot < 0 else dmax)
        eps = 1e-9
        beams = np.flatnonzero((self._elev >= e_lo - eps) & (self._elev <= e_hi + eps)).astype(np.int64)
        return beams, columns

    def _sensor_in_object(self, pose: VehiclePose) -> np.ndarray:
        """(3,) float64 sensor optical centre in the object frame."""
        b = self.box_center_in_sensor(pose)
        return rotation_z(pose.heading).T @ (-b) + self.center

    def scan(self, pose: VehiclePose, rng: np.random.Generator, timings: StageTimer | None = None) -> Scan:
        """Simulate one scan of the vehicle at ``pose``.

        Parameters
        ----------
        pose : vehicle placement; the sensor must be outside the box's footprint.
        rng : random generator for dropout and range noise (consumed deterministically).
        timings : optional :class:`~spotlights.timing.StageTimer`; the seconds spent in its stages ``rays``,
            ``cast`` and ``returns`` are added to it.

        Returns
        -------
        :class:`Scan` with the returns in the object frame (metres).
        """
        timer = StageTimer()
        s = self.sensor
        if pose.distance <= self.footprint_radius:
            raise ParameterError(
                f"vehicle at {pose.distance:.2f} m would contain the sensor (footprint radius {self.footprint_radius:.2f} m)"
            )
        origin = self._sensor_in_object(pose)
        beams, columns = self.window(pose)
        if s.beam_dropout > 0.0:  # dead beams this scan (drawn for every beam: independent of the window)
            alive = rng.random(s.n_beams) >= s.beam_dropout
            beams = beams[alive[beams]]
        if len(beams) == 0 or len(columns) == 0:
            empty = np.zeros(0, dtype=np.int64)
            return Scan(np.zeros((0, 3)), empty, empty, 0)
        # Directions in the object frame: elevation unchanged, azimuth minus the heading.
        el = self._elev[beams]
        az = columns.astype(np.float64) * self._step - pose.heading
        ce, se = np.cos(el), np.sin(el)
        d = np.empty((len(beams), len(columns), 3))
        d[..., 0] = ce[:, None] * np.cos(az)[None, :]
        d[..., 1] = ce[:, None] * np.sin(az)[None, :]
        d[..., 2] = se[:, None]
        d = d.reshape(-1, 3)
        o = np.broadcast_to(origin, d.shape)
        timer.lap("rays")
        t = self.caster.distances(o, d).astype(np.float64)
        timer.lap("cast")
        # Ground plane z = lo_z (the box bottom) in the object frame; it occludes what lies beyond.
        with np.errstate(divide="ignore", invalid="ignore"):
            t_ground = np.where(d[:, 2] < 0.0, (self.lo[2] - origin[2]) / d[:, 2], np.inf)
        keep = np.isfinite(t) & (t <= t_ground + 1e-6) & (t >= s.min_range) & (t <= s.max_range)
        idx = np.flatnonzero(keep)
        if s.dropout > 0.0 and len(idx):
            idx = idx[rng.random(len(idx)) >= s.dropout]
        r = t[idx]
        if s.range_noise > 0.0 and len(idx):
            r = r + rng.normal(0.0, s.range_noise, len(idx))
        pts = origin + r[:, None] * d[idx]
        nb = len(columns)
        scan = Scan(points=pts, beam=beams[idx // nb], column=columns[idx % nb], n_rays=len(d))
        if timings is not None:
            timer.lap("returns")
            for stage, seconds in timer.seconds.items():
                timings.add(stage, seconds)
        return scan

    def scan_full(self, pose: VehiclePose) -> Scan:
        """Noise-free scan casting every beam over the full revolution (slow; for checks and tests).

        Keeps every return on the vehicle within range, without window culling, dropout or noise.
        """
        s = self.sensor
        origin = self._sensor_in_object(pose)
        beams = np.arange(s.n_beams, dtype=np.int64)
        columns = np.arange(s.n_columns, dtype=np.int64)
        bb, cc = np.meshgrid(beams, columns, indexing="ij")
        el = self._elev[bb.ravel()]
        az = cc.ravel() * self._step - pose.heading
        d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
        t = self.caster.distances(np.broadcast_to(origin, d.shape), d).astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_ground = np.where(d[:, 2] < 0.0, (self.lo[2] - origin[2]) / d[:, 2], np.inf)
        keep = np.isfinite(t) & (t <= t_ground + 1e-6) & (t >= s.min_range) & (t <= s.max_range)
        return Scan(
            points=origin + t[keep, None] * d[keep], beam=bb.ravel()[keep], column=cc.ravel()[keep], n_rays=len(d)
        )
