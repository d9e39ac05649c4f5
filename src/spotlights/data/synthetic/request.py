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
from dataclasses import dataclass, field

from ...errors import ParameterError
from ...utils import settings_from_dict
from ..lidar import SensorModel, sensor_preset
from .config import BuildConfig, parse_range, parse_source
from .runner import BuildReport, BuildSettings, build_dataset


@dataclass(frozen=True)
class BuildRequest:
    """Every option of ``spotlights dataset build``, named as the option (``--gt-points`` is
    ``gt_points``), with the command's defaults; see ``spotlights dataset build --help``.

    Units: metres for ``distance``, ``mount_height``, ``range_noise``, ``max_range`` and the
    ``*_range`` box sizes; degrees for ``azimuth_step``; probabilities for the dropouts.
    Strings as on the command line: ``distance`` and the ranges ``"MIN:MAX"``, ``mount_height``
    ``"1.73"`` or ``"MIN:MAX"``, ``meshes`` items ``"DIR[,key=value...]"``, ``category_split``
    items ``"CAT=SPLIT"``.
    """

    out: str
    meshes: list = field(default_factory=list)
    manifest: str | None = None
    views: int = 2000
    split: str = "0.81/0.1/0.09"
    no_stratify: bool = False
    seed: int = 0
    workers: int | None = None
    rig: list = field(default_factory=list)
    default_rig: str = "32x64@60"
    points: int = 256
    gt_points: int = 2048
    gt_dense: int = 16384
    downsample: str = "random"
    up: str = "z"
    forward: str = "x"
    scale: float = 1.0
    sensor: str = "hdl64e"
    azimuth_step: float | None = None
    mount_height: str | float | None = None
    range_noise: float | None = None
    dropout: float | None = None
    beam_dropout: float | None = None
    max_range: float | None = None
    distance: str = "4:40"
    min_points: int = 50
    procedural: int = 0
    classes: str | None = None
    procedural_split: str | None = None
    category_split: list = field(default_factory=list)
    exclude_category: list = field(default_factory=list)
    mirror: bool = False
    scale_copies: int = 0
    length_range: str | None = None
    width_range: str | None = None
    height_range: str | None = None
    scale_factor_range: str | None = None
    augment_splits: str = "train"
    overwrite: bool = False
    resume: bool = False
    block: int | None = None
    keep_parts: bool = False
    quiet: bool = False
    backend: str = "local"
    ray_address: str | None = None
    task_retries: int = 2
    shard_size: int | None = None

    @classmethod
    def from_dict(cls, d: Mapping, where: str | os.PathLike | None = None) -> BuildRequest:
        """Read a request by the one strict policy (:func:`spotlights.utils.settings_from_dict`)."""
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
                    f"--mount-height {self.mount_height!r}: write metres (1.73) or MIN:MAX (1.5:2.1)"
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

    def config(self) -> BuildConfig:
        """The :class:`BuildConfig` of this request (not yet validated: :func:`build_dataset` does);
        raises ParameterError naming the option at fault."""
        sensor, heights = self.sensor_model()
        if not self.meshes and not self.procedural:
            raise ParameterError("give --meshes DIR (repeatable) or --procedural N (or both)")
        if not self.procedural and (self.classes or self.procedural_split):
            raise ParameterError("--classes and --procedural-split apply to --procedural N (vehicles per class)")
        sources = [parse_source(m) for m in self.meshes]
        single = len(sources) <= 1 and all(set(s) == {"path"} for s in sources)
        if not single and self.manifest:
            raise ParameterError(
                "--manifest applies to a single --meshes folder; give each source its own (--meshes DIR,manifest=CSV)"
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
                raise ParameterError(f"--category-split {item!r}: write CATEGORY=SPLIT, e.g. suv=test")
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


def _distance(text: str) -> tuple[float, float]:
    """``"MIN:MAX"`` (or ``"MIN,MAX"``) metres -> ``(min, max)``; checked by :meth:`BuildConfig.validate`."""
    try:
        a, b = (float(x) for x in text.replace(",", ":").split(":"))
    except ValueError:
        raise ParameterError(f"--distance {text!r}: write MIN:MAX in metres, e.g. 4:40") from None
    return a, b


def build_from_request(request: BuildRequest) -> BuildReport:
    """Build the dataset a :class:`BuildRequest` describes into ``request.out`` (see :func:`build_dataset`)."""
    return build_dataset(request.config(), request.out, request.settings())


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
