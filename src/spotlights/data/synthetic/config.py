"""Configuration of a synthetic dataset build: rig and split specs, :class:`BuildConfig`.

Everything that determines a dataset's content is a field of :class:`BuildConfig`; it is
stored in the file as ``config_json`` (and in ``OUT.parts/plan.json`` while a build runs),
so a file says how to rebuild it byte for byte.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field

import numpy as np

from ...errors import ParameterError
from ...geometry.rig import Rig, RigSpec, make_rig
from ..lidar import SensorModel, hdl64e

PLAN_VERSION = 1
# Seed streams (the second spawn-key word).
STREAM_VIEWS, STREAM_GT_POINTS, STREAM_GT_DENSE, STREAM_SPLIT = 1, 2, 3, 4
# Clearance between the sensor and the vehicle's footprint (metres), on top of its half diagonal.
SENSOR_CLEARANCE = 0.5


# ----------------------------------------------------------------------------------------------
# configuration
# ----------------------------------------------------------------------------------------------
def parse_rig(spec: "str | Rig | RigSpec") -> "Rig | RigSpec":
    """A rig from ``"NxM"``, ``"NxM@DEG"`` (e.g. ``"64x32@60"``) or a rig name.

    Cap rigs (``"64x32@60"``, ``"cap-32x64-60"``) give the :class:`Rig` itself (its rays do
    not depend on the object). Box-targeted rig names (``"box-32x64-ellipsoid-s1"``, any
    :attr:`RigSpec.name`) give a :class:`RigSpec`: each model's depths use the rig of its own
    box (``spec.for_box(size / 2R)``, see docs/box-rig.md).
    """
    if isinstance(spec, Rig):
        return spec
    if isinstance(spec, RigSpec):
        return spec if spec.needs_box else spec.for_box(None)
    s = str(spec).strip().lower()
    if s.startswith("box-"):
        return RigSpec.from_name(s)
    m = re.fullmatch(r"(\d+)x(\d+)(?:@(\d+(?:\.\d*)?|\.\d+))?", s) or re.fullmatch(r"cap-(\d+)x(\d+)-(\d+(?:\.\d*)?)", s)
    if not m:
        raise ParameterError(f"rig {spec!r} not understood; write NxM or NxM@DEG, e.g. 64x32@60 (N viewpoints, "
                             "M rays each, cap half-angle in degrees, default 60), or a rig name such as "
                             "cap-32x64-60 or box-32x64-ellipsoid-s1 (box-targeted, docs/box-rig.md)")
    return make_rig(int(m.group(1)), int(m.group(2)), angle=float(m.group(3)) if m.group(3) else 60.0)


def parse_split(spec: str) -> tuple[str, list[float]]:
    """Parse ``"64/8/7"`` (model counts: integers) or ``"0.8/0.1/0.1"`` (fractions summing to 1).

    Returns ``("counts" | "fractions", [train, val, test])``.
    """
    parts = [p.strip() for p in str(spec).replace(",", "/").split("/")]
    if len(parts) != 3 or not all(parts):
        raise ParameterError(f"split {spec!r}: give three parts train/val/test, e.g. 64/8/7 or 0.8/0.1/0.1")
    try:
        if all(re.fullmatch(r"\d+", p) for p in parts):
            vals = [int(p) for p in parts]
            return "counts", vals
        vals = [float(p) for p in parts]
    except ValueError:
        raise ParameterError(f"split {spec!r}: parts must be numbers") from None
    if any(not math.isfinite(v) or v < 0 for v in vals):
        raise ParameterError(f"split {spec!r}: parts must be >= 0")
    if abs(sum(vals) - 1.0) > 1e-6:
        raise ParameterError(f"split {spec!r}: fractions add up to {sum(vals):g}, not 1")
    return "fractions", vals


@dataclass
class BuildConfig:
    """Everything that determines a dataset's content (stored as ``config_json``).

    meshes : folder of meshes (sub-folders = categories) or with a manifest.
    manifest : CSV with columns ``file`` and ``category`` (optional ``up``, ``forward``, ``split``);
        default: ``MESHES/manifest.csv`` when it exists.
    views : partial observations per model.
    split : ``"64/8/7"`` model counts or ``"0.81/0.1/0.09"`` fractions (train/val/test).
    seed : root seed (>= 0).
    n_points : points per partial observation.
    gt_points, gt_dense : uniform surface samples per model (paper: 2048 and 16384).
    default_rig : the rig of the SA-Net ground truth (paper: 32 x 64, 60 deg).
    extra_rigs : more rigs whose ground truth is stored too (ablations: 64x32@60, 256x64@60;
        box-targeted rigs by name, e.g. box-32x64-ellipsoid-s1: each model uses its own box).
    sensor : the LiDAR model (dict of :class:`SensorModel`).
    distance : (min, max) horizontal distance of the box centre from the sensor, metres.
    min_points : fewest returns an observation may have; fewer and the pose is redrawn.
    max_draws : poses tried per observation before giving up on the model (an error).
    downsample : ``"random"`` (subset without replacement) or ``"fps"`` (farthest-point).
    up, forward : the mesh files' up and forward axes (object frame: x forward, y left, z up).
    scale : factor applied to the mesh coordinates (meshes must be in metres for the sensor).
    stratify : assign the split per category (keeps category proportions) or over all models.
    """

    meshes: str = ""
    manifest: str | None = None
    views: int = 2000
    split: str = "0.81/0.1/0.09"
    seed: int = 0
    n_points: int = 256
    gt_points: int = 2048
    gt_dense: int = 16384
    default_rig: str = "32x64@60"
    extra_rigs: list = field(default_factory=list)
    sensor: dict = field(default_factory=lambda: hdl64e().to_dict())
    distance: tuple = (4.0, 40.0)
    min_points: int = 50
    max_draws: int = 100
    downsample: str = "random"
    up: str = "z"
    forward: str = "x"
    scale: float = 1.0
    stratify: bool = True

    def validate(self) -> "BuildConfig":
        """Check every field (raises ParameterError); normalises rig specs and tuples."""
        for name in ("views", "n_points", "gt_points", "gt_dense", "max_draws"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and v >= 1):
                raise ParameterError(f"{name.replace('_', ' ')} must be an integer >= 1, got {v!r}")
        if not (isinstance(self.seed, (int, np.integer)) and self.seed >= 0):
            raise ParameterError(f"seed must be an integer >= 0, got {self.seed!r}")
        if not (isinstance(self.min_points, (int, np.integer)) and self.min_points >= 1):
            raise ParameterError(f"min points must be an integer >= 1, got {self.min_points!r}")
        d = tuple(float(x) for x in self.distance)
        if len(d) != 2 or not (0.0 < d[0] < d[1]) or not all(math.isfinite(x) for x in d):
            raise ParameterError(f"distance range must be MIN:MAX metres with 0 < MIN < MAX, got {self.distance!r}")
        self.distance = d
        if self.downsample not in ("random", "fps"):
            raise ParameterError(f"downsample must be 'random' or 'fps', got {self.downsample!r}")
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ParameterError(f"scale must be > 0, got {self.scale!r}")
        parse_split(self.split)
        self.default_rig = parse_rig(self.default_rig).name
        extra = []
        for r in self.extra_rigs:
            name = parse_rig(r).name
            if name != self.default_rig and name not in extra:
                extra.append(name)
        self.extra_rigs = extra
        sensor = SensorModel.from_dict(self.sensor)
        self.sensor = sensor.to_dict()
        if sensor.max_range <= d[0]:
            raise ParameterError(f"the sensor's range ({sensor.max_range} m) does not reach {d[0]} m")
        return self

    @property
    def rigs(self) -> "list[Rig | RigSpec]":
        """[default rig, extra rigs...]: cap :class:`Rig` objects, box-targeted :class:`RigSpec` objects."""
        return [parse_rig(self.default_rig)] + [parse_rig(r) for r in self.extra_rigs]

    @property
    def sensor_model(self) -> SensorModel:
        """The :class:`SensorModel` of ``sensor``."""
        return SensorModel.from_dict(self.sensor)

    def to_dict(self) -> dict:
        """JSON-serialisable dict (what ``config_json`` stores)."""
        d = asdict(self)
        d["distance"] = list(self.distance)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "BuildConfig":
        """Rebuild and validate a config from :meth:`to_dict` output (unknown keys ignored)."""
        cfg = cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})
        return cfg.validate()

