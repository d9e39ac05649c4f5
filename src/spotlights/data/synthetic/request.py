"""The options of ``spotlights dataset build`` as one settings object, :class:`BuildRequest`.

A request is the command line's flat view of a build (strings such as ``"4:40"`` or
``"1.5:2.1"``, repeated ``--meshes`` and ``--category-split`` items); :meth:`BuildRequest.config`
turns it into the :class:`~.config.BuildConfig` that determines the dataset's bytes,
:meth:`BuildRequest.settings` into the :class:`~.runner.BuildSettings` of how the build runs,
and :func:`build_from_request` does both and builds.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ...errors import InputFileError, ParameterError
from ...options import REQUIRED, SEED_HELP, non_negative_int, option, positive_int, seed_number, settings_from_dict
from ..lidar import MIN_AZIMUTH_STEP, SensorModel, sensor_preset
from .config import MAX_GT_POINTS, MAX_PARTIAL_POINTS, MAX_VIEWS, BuildConfig, parse_range, parse_source
from .runner import BuildReport, BuildSettings, build_dataset

LIDAR = "LiDAR (default: Velodyne HDL-64E as in KITTI)"
PROCEDURAL = "procedural vehicles (every class a real frame holds; docs/dataset.md)"
CATEGORY_SPLITS = "splits by category"
AUGMENTATION = "augmentation (augmented copies of the meshes become extra models, in their mesh's split)"
RUN = "run"


@dataclass(frozen=True, kw_only=True)
class BuildRequest:
    """Every option of ``spotlights dataset build``, named as the option (``--gt-points`` is
    ``gt_points``): each field declares its option (:func:`spotlights.options.option`: default,
    help, sections ``LIDAR`` ... ``RUN`` of ``--help``), so the command and this object agree.

    Units: metres for ``distance``, ``mount_height``, ``range_noise``, ``max_range`` and the
    ``*_range`` box sizes; degrees for ``azimuth_step``; probabilities for the dropouts.
    Strings as on the command line: ``distance`` and the ranges ``"MIN:MAX"``, ``mount_height``
    ``"1.73"`` or ``"MIN:MAX"``, ``meshes`` items ``"DIR[,key=value...]"``, ``category_split``
    items ``"CAT=SPLIT"``.
    """

    meshes: list = option(
        default=[],
        metavar="DIR[,KEY=VALUE...]",
        action="append",
        help="folder of meshes; categories = first sub-folder, or DIR/manifest.csv "
        "(file,category[,up,forward,split,scale]). Repeat for several sources (model names get the folder's "
        "name as prefix); per source: manifest=CSV, up=, forward=, scale=, split=A/B/C or train|val|test, "
        "name=",
    )
    out: str = option(
        "--out", "-o", default=REQUIRED, metavar="FILE", help="dataset file to write (.h5); work folder FILE.parts"
    )
    manifest: str | None = option(
        default=None, metavar="CSV", help="manifest CSV (default: DIR/manifest.csv if present)"
    )
    views: int = option(
        default=2000, type=positive_int, help=f"partial observations per model, 1..{MAX_VIEWS} (default 2000)"
    )
    split: str = option(
        default="0.81/0.1/0.09",
        metavar="A/B/C",
        help="train/val/test: model counts (64/8/7) or fractions (0.8/0.1/0.1); default 0.81/0.1/0.09 (= the "
        "paper's 64/8/7 for 79 models)",
    )
    no_stratify: bool = option(default=False, action="store_true", help="split over all models instead of per category")
    seed: int = option(default=0, type=seed_number, help=f"root seed, {SEED_HELP} (default 0)")
    workers: int | None = option(
        "--workers",
        "-j",
        default=None,
        type=positive_int,
        help="processes (default: all cores); never changes the result",
    )
    rig: list = option(
        default=[],
        action="append",
        metavar="RIG",
        help="extra Spotlights rig for the ground truth, repeatable: NxM[@DEG] cap rigs (e.g. --rig 64x32@60 "
        "--rig 256x64@60) or rig names, e.g. box-32x64-ellipsoid-s1 (box-targeted: each model's own box)",
    )
    default_rig: str = option(default="32x64@60", metavar="RIG", help="the main rig (default 32x64@60)")
    points: int = option(
        default=256, type=int, help=f"points per partial observation, 1..{MAX_PARTIAL_POINTS} (default 256)"
    )
    gt_points: int = option(
        default=2048, type=int, help=f"uniform ground-truth points, 1..{MAX_GT_POINTS} (default 2048)"
    )
    gt_dense: int = option(
        default=16384, type=int, help=f"dense ground-truth points, 1..{MAX_GT_POINTS} (default 16384)"
    )
    downsample: str = option(
        default="random",
        choices=("random", "fps"),
        help="how scans with more points are reduced: random subset (default) or farthest-point sampling",
    )
    up: str = option(default="z", help="the mesh files' up axis (x, y, z, -x, -y, -z; glTF: y; default z)")
    forward: str = option(default="x", help="the mesh files' forward axis (x, y, z, -x, -y, -z; default x)")
    scale: float = option(default=1.0, type=float, help="multiply mesh coordinates by this to get metres (default 1)")
    sensor: str = option(default="hdl64e", group=LIDAR, help="preset: hdl64e (default), hdl32e, vlp16")
    azimuth_step: float | None = option(
        default=None,
        group=LIDAR,
        type=float,
        metavar="DEG",
        help=f"horizontal step, {MIN_AZIMUTH_STEP:g}..90 (hdl64e: 0.17)",
    )
    mount_height: str | float | None = option(
        default=None,
        group=LIDAR,
        metavar="M|MIN:MAX",
        help="sensor height above ground (hdl64e: 1.73); MIN:MAX draws each view's height uniformly (e.g. "
        "1.5:2.1, from low roof mounts to tall SUVs and robotaxis)",
    )
    range_noise: float | None = option(
        default=None, group=LIDAR, type=float, metavar="M", help="range noise sigma (hdl64e: 0.02)"
    )
    dropout: float | None = option(
        default=None, group=LIDAR, type=float, metavar="P", help="probability that a return is lost (default 0)"
    )
    beam_dropout: float | None = option(
        default=None,
        group=LIDAR,
        type=float,
        metavar="P",
        help="probability that a whole beam is dead during a scan (default 0)",
    )
    max_range: float | None = option(
        default=None, group=LIDAR, type=float, metavar="M", help="range limit (hdl64e: 120)"
    )
    distance: str = option(
        default="4:40", group=LIDAR, metavar="MIN:MAX", help="vehicle distance range in metres (default 4:40)"
    )
    min_points: int = option(
        default=50, group=LIDAR, type=int, help="fewer returns than this and the pose is redrawn (default 50)"
    )
    procedural: int = option(
        default=0,
        group=PROCEDURAL,
        type=non_negative_int,
        metavar="N",
        help="add N generated vehicles per class of --classes (models procedural/CLASS/BODY-IIII; with or without "
        "--meshes; at most 10000); stores every model's detector class",
    )
    classes: str | None = option(
        default=None,
        group=PROCEDURAL,
        metavar="LIST",
        help="classes of --procedural (the real readers' names): car (sedan, hatchback, SUV, pickup, coupe, estate), "
        "van (van, minibus; stored as caravan), truck (box truck, semi-tractor, pickup, articulated truck up to 20 m), "
        "bus (rigid, articulated), trailer (box, flatbed, tanker); default all (an empty list is refused)",
    )
    procedural_split: str | None = option(
        default=None,
        group=PROCEDURAL,
        metavar="A/B/C|SPLIT",
        help="split of the procedural vehicles alone (counts, fractions or train|val|test); default: pooled with "
        "the sources without split= and dealt by --split",
    )
    category_split: list = option(
        default=[],
        group=CATEGORY_SPLITS,
        action="append",
        metavar="CAT=SPLIT",
        help="every model of category CAT goes to SPLIT (held-out body types, e.g. suv=test); the rest are split "
        "by --split; repeatable",
    )
    exclude_category: list = option(
        default=[],
        group=CATEGORY_SPLITS,
        action="append",
        metavar="CAT",
        help="leave the models of category CAT out; repeatable",
    )
    mirror: bool = option(
        default=False,
        group=AUGMENTATION,
        action="store_true",
        help="add a copy mirrored across the car's x-z plane (y -> -y)",
    )
    scale_copies: int = option(
        default=0,
        group=AUGMENTATION,
        type=non_negative_int,
        metavar="K",
        help="add K anisotropically scaled copies per mesh (with --mirror, each mirrored too)",
    )
    length_range: str | None = option(
        default=None, group=AUGMENTATION, metavar="MIN:MAX", help="box length of scaled copies, m (2.6:5.8)"
    )
    width_range: str | None = option(
        default=None, group=AUGMENTATION, metavar="MIN:MAX", help="box width (mirrors included), m (1.5:2.45)"
    )
    height_range: str | None = option(
        default=None, group=AUGMENTATION, metavar="MIN:MAX", help="box height, m (1.3:2.0)"
    )
    scale_factor_range: str | None = option(
        default=None, group=AUGMENTATION, metavar="MIN:MAX", help="per-axis factor (0.7:1.3)"
    )
    augment_splits: str = option(
        default="train",
        group=AUGMENTATION,
        metavar="SPLITS",
        help="splits whose meshes get copies, comma-separated (default train: val/test stay real meshes)",
    )
    overwrite: bool = option(
        default=False, group=RUN, action="store_true", help="replace an existing FILE and discard unfinished parts"
    )
    resume: bool = option(
        default=False,
        group=RUN,
        action="store_true",
        help="accept an existing complete FILE (unfinished parts resume anyway)",
    )
    block: int | None = option(
        default=None,
        group=RUN,
        type=positive_int,
        help="views per work unit (default ~views/8, at most 250); a unit holds at most 2**24 partial points "
        "(views x --points)",
    )
    keep_parts: bool = option(default=False, group=RUN, action="store_true", help="keep FILE.parts after writing FILE")
    quiet: bool = option(default=False, group=RUN, quiet=True, help="no progress bars")
    backend: str = option(
        default="local",
        group=RUN,
        choices=("local", "ray"),
        help="local: a process pool on this machine (default); ray: tasks on a Ray cluster (pip install "
        "'spotlights[distributed]'); the bytes are the same",
    )
    ray_address: str | None = option(
        default=None,
        group=RUN,
        metavar="ADDR",
        help="with --backend ray: 'auto' joins the running cluster (ray start), HOST:PORT a given one; default: "
        "start a local instance with --workers CPUs",
    )
    task_retries: int = option(
        default=2,
        group=RUN,
        type=non_negative_int,
        metavar="N",
        help="with --backend ray: retries of a task that crashes or loses its node (default 2); bad input stops "
        "at once",
    )
    shard_size: int | None = option(
        default=None,
        group=RUN,
        type=positive_int,
        metavar="N",
        help="write shards of at most N samples (whole models) plus an index: give --out NAME.json; every reader "
        "takes the index like a file; 'dataset merge' makes one file of them",
    )
    config: str | None = option(
        default=None,
        group=RUN,
        metavar="YAML",
        help="read options from a YAML file, keys named like the options (views: 200, gt_points: 1024, "
        "meshes: [DIR], rig: [64x32@60]); an option given on the command line wins (a repeatable one adds to the "
        "file's); an unknown key is an error",
    )

    @classmethod
    def from_dict(cls, d: Mapping, where: str | os.PathLike | None = None) -> BuildRequest:
        """Read a request by the one strict policy (:func:`spotlights.options.settings_from_dict`)."""
        return settings_from_dict(cls, d, where)

    def sensor_model(self) -> tuple[SensorModel, tuple[float, float] | None]:
        """The LiDAR (``sensor`` preset with the given overrides) and the per-view mount height
        range ``(min, max)`` metres when ``mount_height`` is ``"MIN:MAX"`` (else None)."""
        heights, mount = None, self.mount_height
        if isinstance(mount, str) and ":" in mount:
            heights, mount = parse_range(mount, "--mount-height"), None
        elif mount is not None:
            try:
                mount = float(mount)
            except ValueError:
                raise ParameterError(
                    f"`mount_height` {self.mount_height!r}: write metres (1.73) or MIN:MAX (1.5:2.1)", "mount_height"
                ) from None
        sensor = sensor_preset(
            self.sensor,
            azimuth_step=self.azimuth_step,
            mount_height=mount,
            range_noise=self.range_noise,
            dropout=self.dropout,
            max_range=self.max_range,
            beam_dropout=self.beam_dropout,
        )
        return sensor, heights

    def build_config(self) -> BuildConfig:
        """The :class:`BuildConfig` of this request (not yet validated: :func:`build_dataset` does);
        raises ParameterError naming the option at fault."""
        sensor, heights = self.sensor_model()
        if not self.meshes and not self.procedural:
            raise ParameterError("give `meshes` DIR (repeatable) or `procedural` N (or both)", "meshes", "procedural")
        if not self.procedural and (self.classes or self.procedural_split):
            raise ParameterError(
                "`classes` and `procedural_split` apply to `procedural` N (vehicles per class)",
                "classes",
                "procedural_split",
                "procedural",
            )
        sources = [parse_source(m) for m in self.meshes]
        single = len(sources) <= 1 and all(set(s) == {"path"} for s in sources)
        if not single and self.manifest:
            raise ParameterError(
                "`manifest` applies to a single `meshes` folder; give each source its own (`meshes` DIR,manifest=CSV)",
                "manifest",
                "meshes",
            )
        category_split, augment = self._category_split(), self._augment()
        return BuildConfig(
            meshes=str(sources[0]["path"]) if sources else "",
            manifest=self.manifest,
            views=self.views,
            split=self.split,
            seed=self.seed,
            n_points=self.points,
            gt_points=self.gt_points,
            gt_dense=self.gt_dense,
            default_rig=self.default_rig,
            extra_rigs=list(self.rig),
            sensor=sensor.to_dict(),
            distance=_distance(self.distance),
            min_points=self.min_points,
            downsample=self.downsample,
            up=self.up,
            forward=self.forward,
            scale=self.scale,
            stratify=not self.no_stratify,
            sources=[] if single else sources,
            category_split=category_split,
            exclude_categories=list(self.exclude_category),
            augment=augment,
            mount_height_range=heights,
            procedural={"count": self.procedural, "classes": self.classes, "split": self.procedural_split},
        )

    def _category_split(self) -> dict[str, str]:
        category_split = {}
        for item in self.category_split:
            cat, eq, split = item.partition("=")
            if not eq or not cat.strip():
                raise ParameterError(
                    f"`category_split` {item!r}: write CATEGORY=SPLIT, e.g. suv=test", "category_split"
                )
            category_split[cat.strip()] = split.strip()
        return category_split

    def _augment(self) -> dict | None:
        if not (self.mirror or self.scale_copies):
            return None
        return {
            "mirror": self.mirror,
            "copies": self.scale_copies,
            "length": self.length_range,
            "width": self.width_range,
            "height": self.height_range,
            "factor": self.scale_factor_range,
            "splits": self.augment_splits,
        }

    def settings(self) -> BuildSettings:
        """How the build runs (:class:`BuildSettings`)."""
        return BuildSettings(
            workers=self.workers,
            overwrite=self.overwrite,
            resume=self.resume,
            block=self.block,
            keep_parts=self.keep_parts,
            progress=not self.quiet,
            backend=self.backend,
            ray_address=self.ray_address,
            shard_size=self.shard_size,
            retries=self.task_retries,
        )


def read_request_yaml(path: str | os.PathLike) -> dict:
    """The :class:`BuildRequest` fields a build YAML (``dataset build --config``) sets: a mapping
    whose keys are fields other than ``config``, read by the one strict policy (an unknown key is
    a one-line error naming the file, with the closest field suggested). Values are not checked
    here: the build checks them as it checks the command line's."""
    import yaml

    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputFileError(p, "no such config file") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputFileError(p, f"invalid YAML ({(str(exc).splitlines() or [type(exc).__name__])[0]})") from None
    data = {} if data is None else data
    if isinstance(data, Mapping) and "config" in data:
        raise InputFileError(p, "a build YAML cannot name another one (key 'config')")
    settings_from_dict(BuildRequest, data, p, **({} if isinstance(data, Mapping) and "out" in data else {"out": ""}))
    return dict(data)


def _distance(text: str) -> tuple[float, float]:
    """``"MIN:MAX"`` (or ``"MIN,MAX"``) metres -> ``(min, max)``; checked by :meth:`BuildConfig.validate`."""
    try:
        a, b = (float(x) for x in text.replace(",", ":").split(":"))
    except ValueError:
        raise ParameterError(f"`distance` {text!r}: write MIN:MAX in metres, e.g. 4:40", "distance") from None
    return a, b


def build_from_request(request: BuildRequest) -> BuildReport:
    """Build the dataset a :class:`BuildRequest` describes into ``request.out`` (see :func:`build_dataset`)."""
    return build_dataset(request.build_config(), request.out, request.settings())


def build_summary(report: BuildReport, out: str | os.PathLike) -> list[str]:
    """The lines ``spotlights dataset build`` prints about a finished (or already complete) build
    written to ``out`` (named as the user gave it)."""
    if report.already_complete:
        return [f"{out}: already complete ({report.n_models} models, {report.n_samples} samples); nothing to do"]
    rate = report.units_computed and report.n_samples * report.units_computed / max(report.units_total, 1) / max(
        report.seconds_units, 1e-9
    )
    lines = [
        f"{out}: {report.n_models} models, {report.n_samples} samples, {report.file_size / 2**20:.1f} MiB; "
        f"{report.units_computed} of {report.units_total} work units computed in {report.seconds_units:.1f} s "
        f"(~{rate:.0f} samples/s), file written in {report.seconds_consolidate:.1f} s, total {report.seconds_total:.1f} s"
    ]
    if report.skipped:
        lines.append(f"skipped {len(report.skipped)} mesh(es):")
        lines += [f"  {s['file']}: {s['problem']}" for s in report.skipped]
    return lines
