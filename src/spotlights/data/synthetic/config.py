"""Configuration of a synthetic dataset build: split specs, :class:`BuildConfig` (rig specs are parsed by
:func:`spotlights.geometry.rig.parse_rig`, importable from here).

Everything that determines a dataset's content is a field of :class:`BuildConfig`; it is
stored in the file as ``config_json`` (and in ``OUT.parts/plan.json`` while a build runs),
so a file says how to rebuild it byte for byte.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ...errors import ParameterError
from ...geometry.rig import Rig, RigSpec, parse_rig
from ...options import check_seed, settings_from_dict
from ..lidar import SensorModel, hdl64e
from ..store import MAX_PARTIAL_POINTS
from ..vehicle_classes import VEHICLE_CLASSES, canonical_class

PLAN_VERSION = 1
# Seed streams (the second spawn-key word).
STREAM_VIEWS, STREAM_GT_POINTS, STREAM_GT_DENSE, STREAM_SPLIT = 1, 2, 3, 4
STREAM_AUGMENT, STREAM_MOUNT_HEIGHT = 5, 6  # augmented copies' scale factors; per-view sensor height
STREAM_PROCEDURAL = 7  # a procedural vehicle's parameters
PROCEDURAL_SOURCE = "procedural"  # the source name (and name prefix) of procedural vehicles
SPLIT_NAMES = ("train", "val", "test")
# Keys of a mesh source (``--meshes DIR,key=value,...``), see :class:`MeshSource`.
SOURCE_KEYS = ("manifest", "up", "forward", "scale", "split", "name")
# Keys that an older dataset file's ``config_json`` may carry but :class:`BuildConfig` no longer has,
# each with the reason it is dropped; :meth:`BuildConfig.from_dict` drops exactly these (every other
# unknown key is an error). None so far: every key ever stored is still a field.
RETIRED_KEYS: dict[str, str] = {}
# Clearance between the sensor and the vehicle's footprint (metres), on top of its half diagonal.
SENSOR_CLEARANCE = 0.5
# Upper bounds of the build's counts, checked by BuildConfig.validate before anything is written or a worker
# starts (each was an endless build or workers killed for memory):
MAX_VIEWS = 100_000
"""Views per model (``--views``): 50 times the paper's 2000; at the default sizes a model's views are then about
1 GB of file (256 partial points and a 32 x 64 rig's depths each)."""
MAX_GT_POINTS = 2**20
"""Ground-truth points per model (``--gt-points``, ``--gt-dense``): 64 times the default dense 16,384; sampled in
float64 by every worker, 2e9 of them killed the workers."""
MAX_PROCEDURAL = 10_000
"""Procedural vehicles per class (``--procedural``): 10,000 per class is 50,000 models, about a hundred times the
mesh datasets the paper uses; a million per class never ended."""
COUNT_BOUNDS = {
    "views": ("--views", MAX_VIEWS),
    "n_points": ("--points", MAX_PARTIAL_POINTS),
    "gt_points": ("--gt-points", MAX_GT_POINTS),
    "gt_dense": ("--gt-dense", MAX_GT_POINTS),
    "max_draws": ("max_draws", 1_000_000),  # poses per observation; not an option
}


# ----------------------------------------------------------------------------------------------
# configuration
# ----------------------------------------------------------------------------------------------
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


def parse_range(text, what: str, positive: bool = True) -> tuple[float, float]:
    """``"MIN:MAX"`` (or a 2-sequence) -> ``(min, max)`` floats with ``min <= max`` (and ``min > 0``
    when ``positive``); raises ParameterError naming ``what``."""
    try:
        vals = [float(x) for x in (str(text).replace(",", ":").split(":") if isinstance(text, str) else text)]
    except (TypeError, ValueError):
        raise ParameterError(f"{what} {text!r}: write MIN:MAX, e.g. 1.5:2.1") from None
    if len(vals) != 2 or not all(math.isfinite(v) for v in vals) or vals[0] > vals[1] or (positive and vals[0] <= 0):
        raise ParameterError(f"{what} {text!r}: write MIN:MAX with {'0 < ' if positive else ''}MIN <= MAX")
    return vals[0], vals[1]


@dataclass(frozen=True)
class MeshSource:
    """One folder of meshes of a build (``--meshes DIR[,key=value...]``).

    path : the folder. manifest : CSV (default ``DIR/manifest.csv`` when present).
    up, forward : the files' axes. scale : factor to metres (a manifest's ``scale`` column
    overrides it per file). split : this source's split: a spec (``"64/8/7"``, fractions)
    dealt over its models alone, or one split name (``"train"``: every model of the source);
    None: the source's models join the pool split by ``BuildConfig.split``.
    name : prefix of the model names (``NAME/relative/path``; default: the folder's name) in a
    build given as ``sources`` ("" for the plain single folder ``meshes``: names are the
    relative paths, as always).
    """

    path: str
    manifest: str | None = None
    up: str = "z"
    forward: str = "x"
    scale: float = 1.0
    split: str | None = None
    name: str = ""


def parse_source(text: str) -> dict:
    """``"DIR[,key=value...]"`` -> a source dict for :attr:`BuildConfig.sources` (keys:
    ``manifest``, ``up``, ``forward``, ``scale``, ``split``, ``name``). A comma followed by
    something that is not ``key=`` stays part of the path."""
    parts = str(text).split(",")
    path, opts = [parts[0]], {}
    for p in parts[1:]:
        key, eq, value = p.partition("=")
        if eq and key.strip() in SOURCE_KEYS:
            opts[key.strip()] = value.strip()
        elif eq and not opts and "/" not in key:
            raise ParameterError(
                f"`meshes` {text!r}: unknown option {key.strip()!r}; known: {', '.join(SOURCE_KEYS)}", "meshes"
            )
        elif opts:
            raise ParameterError(
                f"`meshes` {text!r}: {p!r} is not key=value (keys: {', '.join(SOURCE_KEYS)})", "meshes"
            )
        else:
            path.append(p)
    return {"path": ",".join(path), **opts}


# Realistic passenger-vehicle boxes (metres), from a Smart fortwo (2.70 x 1.66 x 1.56 m; 1.87 m wide
# with mirrors) and a Fiat 500 (3.55 x 1.63 x 1.49 m) to a large SUV (Chevrolet Suburban 5.73 x
# 2.06 x 1.92 m, Cadillac Escalade ESV 5.77 m long, Mercedes G-class 1.97 m high). Mesh boxes
# include the mirrors (ApolloScape: width 1.73-2.41 m, median 2.04 m), hence the width range.
AUGMENT_DEFAULTS = {
    "mirror": False,
    "copies": 0,
    "length": [2.6, 5.8],
    "width": [1.5, 2.45],
    "height": [1.3, 2.0],
    "factor": [0.7, 1.3],
    # length/width (Smart with mirrors 1.44 ... limousines ~3) and length/height (Smart 1.73 ...
    # low sports saloons ~4): keeps a shortened car from turning into a cube
    "length_width": [1.4, 3.0],
    "length_height": [1.6, 4.5],
    "splits": ["train"],
}


def normalize_augment(aug: dict | None) -> dict | None:
    """Validate an augmentation dict (keys of :data:`AUGMENT_DEFAULTS`; missing keys take the
    defaults); None or one that adds no copies gives None (no augmentation)."""
    if not aug:
        return None
    unknown = sorted(set(aug) - set(AUGMENT_DEFAULTS))
    if unknown:
        raise ParameterError(f"unknown augmentation option(s): {', '.join(unknown)}")
    a = {**AUGMENT_DEFAULTS, **{k: v for k, v in aug.items() if v is not None}}
    a["mirror"] = bool(a["mirror"])
    if not (isinstance(a["copies"], (int, np.integer)) and 0 <= a["copies"] <= 1000):
        raise ParameterError(f"scaled copies must be an integer in 0..1000, got {a['copies']!r}")
    a["copies"] = int(a["copies"])
    for k in ("length", "width", "height", "factor", "length_width", "length_height"):
        a[k] = list(parse_range(a[k], f"augmentation {k.replace('_', '/')} range"))
    if not (a["factor"][0] <= 1.0 <= a["factor"][1]):
        raise ParameterError(f"augmentation factor range {a['factor']} must contain 1")
    splits = a["splits"].split(",") if isinstance(a["splits"], str) else list(a["splits"])
    splits = [s.strip().lower() for s in splits if s.strip()]
    if not splits or any(s not in SPLIT_NAMES for s in splits):
        raise ParameterError(f"augmented splits must be among {', '.join(SPLIT_NAMES)}, got {a['splits']!r}")
    a["splits"] = [s for s in SPLIT_NAMES if s in splits]
    if not a["mirror"] and a["copies"] == 0:
        return None
    return a


def normalize_procedural(proc: dict | None) -> dict | None:
    """Validate the procedural-vehicles option of :class:`BuildConfig` (None or a count of 0: none).

    Returns ``{"count": N, "classes": [classes in :data:`~.procedural.VEHICLE_CLASSES` order],
    "split": None | split name | spec}``; raises ParameterError."""
    if not proc:
        return None
    unknown = sorted(set(proc) - {"count", "classes", "split"})
    if unknown:
        raise ParameterError(f"unknown procedural option(s): {', '.join(unknown)}")
    n = _procedural_count(proc.get("count"))
    if n == 0:
        return None
    classes = _procedural_classes(proc.get("classes"))
    split = proc.get("split") or None
    if split is not None:
        split = str(split).strip().lower()
        if split not in SPLIT_NAMES:
            parse_split(split)
    return {"count": int(n), "classes": [c for c in VEHICLE_CLASSES if c in classes], "split": split}


def _procedural_count(n) -> int:
    """The procedural vehicles per class: an integer in [0, MAX_PROCEDURAL]; raises ParameterError."""
    if not (isinstance(n, (int, np.integer)) and not isinstance(n, bool) and n >= 0):
        raise ParameterError(f"`procedural` must be a count of vehicles per class >= 0, got {n!r}", "procedural")
    if n > MAX_PROCEDURAL:
        raise ParameterError(
            f"`procedural` must be at most {MAX_PROCEDURAL:,} vehicles per class, got {n:,}", "procedural"
        )
    return n


def _procedural_classes(classes) -> list[str]:
    """The canonical class names of ``classes`` (a list or a comma-separated string; None: every
    class); raises ParameterError for none or an unknown one."""
    classes = list(VEHICLE_CLASSES) if classes is None else classes
    classes = classes.split(",") if isinstance(classes, str) else list(classes)
    classes = [canonical_class(c) for c in classes if str(c).strip()]
    if not classes:  # "" named no class: it was read as every class
        raise ParameterError(
            f"`classes` names no class; give some of {', '.join(VEHICLE_CLASSES)}, or leave it out for all", "classes"
        )
    bad = [c for c in classes if c not in VEHICLE_CLASSES]
    if bad:
        raise ParameterError(
            f"`classes`: unknown vehicle class {bad[0] if bad else ''!r}; known: {', '.join(VEHICLE_CLASSES)} (van = caravan)",
            "classes",
        )
    return classes


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
    sources : several mesh folders (dicts of :class:`MeshSource` fields); empty: the one folder
        ``meshes`` with ``manifest``, ``up``, ``forward``, ``scale``.
    category_split : ``{category: split}``: every model of the category goes to that split
        (held-out body types, e.g. ``{"suv": "test"}``); the others are split as usual.
    exclude_categories : categories left out of the build.
    augment : augmented copies of the meshes as extra models (see :data:`AUGMENT_DEFAULTS`):
        ``mirror`` (y -> -y), ``copies`` anisotropically scaled copies per mesh within the
        ``length``/``width``/``height`` ranges (metres), per-axis ``factor`` range and the
        ``length_width``/``length_height`` ratio ranges; only for models of ``splits``.
    mount_height_range : (min, max) metres: each view's sensor height drawn uniformly from it
        (None: the sensor's ``mount_height``).
    procedural : procedural vehicles as extra models (:mod:`.procedural`): ``{"count": N,
        "classes": [...], "split": None | "train" | "A/B/C"}``, N per detector class
        (``car``, ``caravan``, ``truck``, ``bus``, ``trailer``; ``van`` = ``caravan``); split None: pooled
        with ``split``.
        With it, every model's detector class is stored (``/models/class``).

    The options after ``stratify`` are left out of :meth:`to_dict` at their defaults, so a
    build without them stores the same ``config_json`` (and bytes) as before they existed.
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
    sources: list = field(default_factory=list)
    category_split: dict = field(default_factory=dict)
    exclude_categories: list = field(default_factory=list)
    augment: dict | None = None
    mount_height_range: tuple | None = None
    procedural: dict | None = None

    def validate(self, where: str | os.PathLike | None = None) -> BuildConfig:
        """Check every field (raises ParameterError); normalises rig specs and tuples.

        ``where`` (a file or a label) names the origin of a config read from a file in the
        error about an unknown sensor key."""
        self._check_numbers()
        parse_split(self.split)
        self.default_rig = parse_rig(self.default_rig).name
        extra = []
        for r in self.extra_rigs:
            name = parse_rig(r).name
            if name != self.default_rig and name not in extra:
                extra.append(name)
        self.extra_rigs = extra
        sensor = SensorModel.from_dict(self.sensor, "sensor" if where is None else f"{where} (sensor)")
        self.sensor = sensor.to_dict()
        if sensor.max_range <= self.distance[0]:
            raise ParameterError(f"the sensor's range ({sensor.max_range} m) does not reach {self.distance[0]} m")
        self._check_sources()
        cs = {}
        for cat, sp in dict(self.category_split).items():
            if str(sp).lower() not in SPLIT_NAMES:
                raise ParameterError(f"category split {cat}={sp}: the split must be one of {', '.join(SPLIT_NAMES)}")
            cs[str(cat)] = str(sp).lower()
        self.category_split = dict(sorted(cs.items()))
        self.exclude_categories = sorted({str(c) for c in self.exclude_categories})
        self.augment = normalize_augment(self.augment)
        if self.mount_height_range is not None:
            self.mount_height_range = parse_range(self.mount_height_range, "mount height range")
        return self

    def _check_numbers(self) -> None:
        """Counts, seed, distance range (normalised to a float pair), downsampling and scale."""
        for name, (option, hi) in COUNT_BOUNDS.items():
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and not isinstance(v, bool) and 1 <= v <= hi):
                raise ParameterError(f"{option} must be a whole number in 1..{hi}, got {v!r}")
        self.seed = check_seed(self.seed)
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

    def _check_sources(self) -> None:
        """The mesh sources (unique names), ``meshes`` from the first, and the procedural vehicles."""
        self.sources = [self._check_source(s) for s in self.sources]
        names = [s["name"] for s in self.sources]
        if len(set(names)) != len(names):
            raise ParameterError(
                f"two mesh sources share the name {sorted(n for n in names if names.count(n) > 1)[0]!r};"
                " give one a name=... "
            )
        if self.sources:
            self.meshes = self.sources[0]["path"]
        self.procedural = normalize_procedural(self.procedural)
        if not self.meshes and not self.procedural:
            raise ParameterError("no meshes folder given (`meshes` DIR or `procedural` N)", "meshes", "procedural")
        if self.procedural and PROCEDURAL_SOURCE in names:
            raise ParameterError(f"a mesh source is named {PROCEDURAL_SOURCE!r}, the name of the procedural vehicles")

    def _check_source(self, src) -> dict:
        """A validated source dict with every :class:`MeshSource` field (defaults: the global axes
        and scale, the folder's name)."""
        d = parse_source(src) if isinstance(src, str) else dict(src)
        unknown = sorted(set(d) - {"path", *SOURCE_KEYS})
        if unknown or not d.get("path"):
            raise ParameterError(
                f"mesh source {src!r}: needs a path" + (f", unknown keys {unknown}" if unknown else "")
            )
        out = {
            "path": str(d["path"]),
            "manifest": d.get("manifest") or None,
            "up": str(d.get("up") or self.up),
            "forward": str(d.get("forward") or self.forward),
        }
        try:
            out["scale"] = float(d["scale"]) if d.get("scale") not in (None, "") else float(self.scale)
        except ValueError:
            raise ParameterError(f"mesh source {d['path']}: scale {d['scale']!r} is not a number") from None
        if not (math.isfinite(out["scale"]) and out["scale"] > 0):
            raise ParameterError(f"mesh source {d['path']}: scale must be > 0, got {out['scale']}")
        sp = d.get("split") or None
        if sp is not None:
            sp = str(sp).strip().lower()
            if sp not in SPLIT_NAMES:
                parse_split(sp)
        out["split"] = sp
        name = str(d.get("name") or "").strip() or Path(str(d["path"]).rstrip("/\\")).name
        if not name or "/" in name or name.startswith("."):
            raise ParameterError(f"mesh source {d['path']}: name {name!r} must be a non-empty word without '/'")
        out["name"] = name
        return out

    def mesh_sources(self) -> list[MeshSource]:
        """The build's mesh folders: ``sources``, or the single folder ``meshes`` (name "")."""
        if self.sources:
            return [MeshSource(**s) for s in self.sources]
        if not self.meshes:  # procedural vehicles only
            return []
        return [MeshSource(self.meshes, self.manifest, self.up, self.forward, float(self.scale), None, "")]

    @property
    def rigs(self) -> list[Rig | RigSpec]:
        """[default rig, extra rigs...]: cap :class:`Rig` objects, box-targeted :class:`RigSpec` objects."""
        return [parse_rig(self.default_rig)] + [parse_rig(r) for r in self.extra_rigs]

    @property
    def sensor_model(self) -> SensorModel:
        """The :class:`SensorModel` of ``sensor``."""
        return SensorModel.from_dict(self.sensor)

    def to_dict(self) -> dict:
        """JSON-serialisable dict (what ``config_json`` stores); the options added after
        ``stratify`` only when set."""
        d = asdict(self)
        d["distance"] = list(self.distance)
        for k in ("sources", "category_split", "exclude_categories", "augment", "mount_height_range", "procedural"):
            if not d[k]:
                del d[k]
        if "mount_height_range" in d:
            d["mount_height_range"] = list(d["mount_height_range"])
        return d

    @classmethod
    def from_dict(cls, d: Mapping, where: str | os.PathLike | None = None) -> BuildConfig:
        """Rebuild and validate a config from :meth:`to_dict` output (a dataset's ``config_json``,
        a build plan) by the one strict policy (:func:`spotlights.options.settings_from_dict`): an
        unknown key, here or in ``sensor``, is a one-line error naming ``where`` (a file path or a
        label) with the closest field suggested. Keys of :data:`RETIRED_KEYS` (written by older
        versions, no longer fields) are dropped explicitly."""
        if isinstance(d, Mapping):
            d = {k: v for k, v in d.items() if k not in RETIRED_KEYS}
        return settings_from_dict(cls, d, where).validate(where)
