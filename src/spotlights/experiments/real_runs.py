"""Real-data runs from files, as settings and one function each: what ``spotlights real extract``,
``real evaluate`` and ``real show`` do.

- :func:`extract_file` (:class:`ExtractSettings`): a dataset's vehicle boxes -> an observation file (HDF5).
- :func:`evaluate_file` (:class:`EvaluateSettings`): an observation file + models -> the consistency report
  ``PREFIX.md`` / ``PREFIX.json`` (:func:`~spotlights.experiments.real_evaluation.evaluate_consistency`), with
  the report's naming (default prefix, row names that tell two checkpoints of one model apart) and its
  resumption (``PREFIX.partial.json``, written after every model, and ``resume``).
- :func:`show_file` (:class:`ShowSettings`): one frame of an observation file drawn (PNG and/or HTML), sensor frame.

Each takes ``say`` (summary lines) and ``warn`` (warnings) callbacks; nothing is printed otherwise.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from .. import logs
from ..completion.frame import HEADING_MARGIN
from ..completion.frame_selection import ReaderOptions
from ..completion.names import file_stem
from ..completion.scan import Say, parse_classes
from ..data.real.base import CLASSES
from ..data.real.extract import ExtractConfig, Observations, extract, read_observations, write_observations
from ..data.real.frames import frame_rows
from ..errors import InputFileError, ParameterError, SpotlightsError
from ..metrics.consistency import consecutive_pairs
from ..outputs import check_suffix, check_writable
from ..viz import html, render_frame
from ..viz.scene import frame_objects, read_frame_scan
from .real_evaluation import (
    RealEvaluationSettings,
    complete_all,
    evaluate_consistency,
    reference_shapes,
    report_markdown,
    write_report,
    write_report_json,
)

# ---------------------------------------------------------------------------- extract


@dataclass(kw_only=True)
class ExtractSettings(ReaderOptions):
    """What ``spotlights real extract`` does: a dataset (:class:`~spotlights.completion.frame_selection.ReaderOptions`) cut into
    unit-frame partial observations.

    out : the observation file (``.h5``); margin, ground_clearance : the crop (metres); min_points : boxes
    with fewer points are skipped; points : points per observation after resampling; seed : its seed;
    classes : comma-separated classes to keep; frames : kitti360's ``(start, stop, step)`` range; quiet : no
    progress bar.
    """

    out: str
    margin: float = 0.15
    ground_clearance: float = 0.10
    min_points: int = 10
    points: int = 256
    seed: int = 0
    classes: str = "car,truck,caravan,trailer"
    frames: tuple | None = None
    quiet: bool = False


def observation_lines(obs: Observations) -> list[str]:
    """The summary of an observation file: counts per class, tracked objects and pairs, skipped boxes."""
    classes = Counter(obs.cls)
    pairs = consecutive_pairs(obs.object_keys(), obs.timestamp)
    tracked = {obs.object_keys()[i] for p in pairs for i in p}
    lines = [
        f"{len(obs)} observations from {obs.meta['n_frames']} frames ({obs.meta['n_boxes']} boxes): "
        + (", ".join(f"{c} {n}" for c, n in sorted(classes.items())) or "none"),
        f"objects observed in two or more frames: {len(tracked)} ({len(pairs)} consecutive pairs)",
        "skipped boxes: " + ", ".join(f"{k} {v}" for k, v in obs.meta["skipped"].items()),
    ]
    if obs.meta["skipped_labels"]:
        lines.append("  excluded labels: " + ", ".join(f"{k} {v}" for k, v in obs.meta["skipped_labels"].items()))
    return lines


def extract_file(s: ExtractSettings, say: Say = logs.info) -> Observations:
    """Extract every vehicle box of a dataset into ``s.out`` (HDF5, see
    :func:`spotlights.data.real.extract.extract`); ``say`` receives its summary. Returns the observations."""
    check_suffix(s.out, (".h5", ".hdf5"), "the observations file (HDF5)")
    check_writable(s.out)
    config = ExtractConfig(
        margin=s.margin,
        ground_clearance=s.ground_clearance,
        min_points=s.min_points,
        n_points=s.points,
        seed=s.seed,
        classes=tuple(c.strip() for c in s.classes.split(",") if c.strip()),
    )
    obs = extract(s.open(s.frames), config, progress=not s.quiet)
    write_observations(s.out, obs)
    for line in observation_lines(obs) + [f"wrote {s.out}"]:
        say(line)
    return obs


# ---------------------------------------------------------------------------- evaluate


def load_completers(checkpoints: Sequence[str], device: str | None = None) -> list:
    """The torch completers of ``checkpoints`` (files or short names), every one checked before any is loaded."""
    try:
        from ..learning.checkpoint import resolve_checkpoint
        from ..learning.inference import load_completer
    except ImportError as exc:
        raise SpotlightsError(f"model loading is not available ({exc}); install spotlights[learn]") from None
    for p in checkpoints:
        resolve_checkpoint(p)  # every file or name checked before any model is loaded
    return [load_completer(p, device=device) for p in checkpoints]


def report_names(model_names: Sequence[str], checkpoints: Sequence[str]) -> list[str]:
    """Report row names: each model's name; two checkpoints of one model told apart by file name
    (``sanet (run1)``), or by run folder for ``best.pt`` / ``last.pt``."""
    names = list(model_names)
    dup = {n for n in names if names.count(n) > 1}
    tag = [Path(p).parent.name if Path(p).stem in ("best", "last") else Path(p).stem for p in checkpoints]
    return [f"{n} ({t})" if n in dup else n for n, t in zip(names, tag)]


@dataclass(kw_only=True)
class EvaluateSettings:
    """What ``spotlights real evaluate`` does (one field per option, same defaults).

    file : the observation file; checkpoint : the models (None: the default model); names : their row names;
    out : the report prefix (None: FILE without ``.h5`` + ``_consistency``); classes : comma-separated
    classes to score; equal_points, equal_density, no_noise_floor, no_heading_check, heading_margin,
    batch_size, clip, snap, snap_mirror, fit, fit_steps : the scoring (:class:`~.real_evaluation.RealEvaluationSettings`);
    device : torch device;
    reference, reference_split : the MMD reference dataset and split; resume : reuse the models of an earlier
    report with the same settings; quiet : no progress bars.
    """

    file: str
    checkpoint: list | None = None
    classes: str | None = None
    equal_points: int = 512
    equal_density: float = 0.1
    no_noise_floor: bool = False
    no_heading_check: bool = False
    heading_margin: float | None = None
    names: list | None = None
    out: str | None = None
    batch_size: int = 64
    clip: float | None = None
    snap: float = 0.0
    snap_mirror: bool = False
    fit: bool = False
    fit_steps: int | None = None
    device: str | None = None
    reference: str | None = None
    reference_split: str | None = None
    resume: bool = False
    quiet: bool = False

    @property
    def checkpoints(self) -> list[str]:
        """The checkpoints to score (``["default"]`` when none is given)."""
        return self.checkpoint or ["default"]

    @property
    def prefix(self) -> str:
        """The report's path without ``.md`` / ``.json``."""
        return self.out or str(Path(self.file).with_suffix("")) + "_consistency"

    def scoring(self) -> RealEvaluationSettings:
        """The :class:`~.real_evaluation.RealEvaluationSettings` of these options, checked (one-line errors)."""
        if self.reference_split and not self.reference:
            raise ParameterError("`reference_split` needs `reference` DATASET.h5", "reference_split", "reference")
        if self.equal_points < 0:
            raise ParameterError(f"`equal_points` must be >= 0, got {self.equal_points}", "equal_points")
        if not (self.equal_density >= 0 and self.equal_density < float("inf")):
            raise ParameterError(
                f"`equal_density` must be a voxel size >= 0, got {self.equal_density}", "equal_density"
            )
        margin = HEADING_MARGIN if self.heading_margin is None else self.heading_margin
        if not 0.0 <= margin < 1.0:
            raise ParameterError(f"`heading_margin` must be in [0, 1), got {self.heading_margin}", "heading_margin")
        n = len(self.checkpoints)
        if self.names is not None and (len(self.names) != n or len(set(self.names)) != len(self.names)):
            raise ParameterError(
                f"`names`: give {n} distinct names, one per checkpoint, got {len(self.names)}: " + " ".join(self.names),
                "names",
            )
        return RealEvaluationSettings(
            classes=parse_classes(self.classes),
            clip=self.clip,
            equal_points=self.equal_points or None,
            equal_density=self.equal_density or None,
            noise_floor=not self.no_noise_floor,
            heading_check=not self.no_heading_check,
            heading_margin=margin,
            batch_size=self.batch_size,
            snap=float(self.snap),
            snap_mirror=bool(self.snap_mirror),
            fit=bool(self.fit),
            fit_steps=self.fit_steps,
        )


def earlier_reports(paths: Sequence[Path], warn: Say = logs.warning) -> list[dict]:
    """The reports of ``paths`` that exist and read as ``real evaluate`` reports with settings (others: a
    warning each, not reused)."""
    previous = []
    for f in paths:
        if f.is_file():
            try:
                earlier = json.loads(f.read_text(encoding="utf-8"))
                if not isinstance(earlier["data"]["settings"], dict) or not isinstance(earlier["models"], list):
                    raise TypeError
            except (OSError, ValueError, KeyError, TypeError):
                warn(f"{f}: not a report of 'real evaluate' with settings; not reused")
                continue
            previous.append(earlier)
    return previous


def evaluate_file(s: EvaluateSettings, say: Say = logs.info, warn: Say = logs.warning) -> dict:
    """Score the consistency of ``s.checkpoint`` on the observation file ``s.file`` and write ``PREFIX.md`` and
    ``PREFIX.json`` (:func:`~.real_evaluation.evaluate_consistency`, :func:`~.real_evaluation.write_report`).

    Every option, the destination and the file are checked before a model is loaded. After each model the
    report so far is written to ``PREFIX.partial.json`` (removed at the end); with ``s.resume`` the models of
    ``PREFIX.json`` and ``PREFIX.partial.json`` scored with the same settings, name and checkpoint content are
    reused. ``say`` receives the headline table and the files written, ``warn`` the warnings. Returns the report.
    """
    scoring = s.scoring()
    prefix = s.prefix
    check_writable(prefix + ".md")
    obs = read_observations(s.file)  # validate before loading models
    bad = [c for c in scoring.classes or () if c not in CLASSES]
    if bad:
        raise ParameterError(f"unknown class(es) {', '.join(bad)}; choose among {', '.join(CLASSES)}")
    refs, ref_info = reference_shapes(s.reference, s.reference_split) if s.reference else (None, None)
    completers = load_completers(s.checkpoints, s.device)
    names = s.names or report_names([c.model_name for c in completers], s.checkpoints)
    js_path, partial = Path(prefix + ".json"), Path(prefix + ".partial.json")
    previous = earlier_reports((js_path, partial), warn) if s.resume else []
    reused = []

    def save_partial(report_so_far: dict, was_reused: bool) -> None:
        if was_reused:
            reused.append(report_so_far["models"][-1]["name"])
            say(f"reusing {reused[-1]} (same checkpoint and settings) from {prefix}")
        report_so_far["data"]["file"] = str(s.file)
        write_report_json(report_so_far, partial)

    try:
        report = evaluate_consistency(
            obs,
            completers,
            scoring,
            names=names,
            checkpoints=s.checkpoints,
            progress=not s.quiet,
            references=refs,
            reference_info=ref_info,
            previous=previous,
            on_model=save_partial,
        )
    except InputFileError as exc:
        if exc.path != "<observations>":
            raise
        raise InputFileError(s.file, exc.problem) from None  # name the file the user gave
    report["data"]["file"] = str(s.file)
    md, js = write_report(report, prefix)
    partial.unlink(missing_ok=True)
    if any(rep["models"] for rep in previous) and not reused:
        warn(f"--resume: no model of {prefix} was reused (other settings, names or checkpoint files)")
    for m in report["models"]:
        if m.get("out_of_domain", {}).get("n_observations"):
            warn(
                f"{m['name']}: {m['out_of_domain']['n_observations']} of {report['data']['n_observations_tracked']} "
                "observations are outside what the model learned (see the report)"
            )
    say(report_markdown(report).split("\n## ")[0].strip())
    say(f"wrote {md} and {js}")
    return report


# ---------------------------------------------------------------------------- show


@dataclass(kw_only=True)
class ShowSettings:
    """What ``spotlights real show`` does: one frame of an observation file drawn, sensor frame (metres).

    file : the observation file; checkpoint : the model (None: the default); no_completion : draw no model;
    frame, sequence : the frame (None: the one with the most observations); max_objects : close-ups of the
    objects with most points; out : the PNG (None: FILE_FRAME.png, or no picture with ``html`` alone);
    clip : the model's depth clip; device : torch device; html : an interactive page.
    """

    file: str
    checkpoint: str | None = None
    no_completion: bool = False
    frame: str | None = None
    sequence: str | None = None
    max_objects: int = 6
    out: str | None = None
    clip: float | None = None
    device: str | None = None
    html: str | None = None


def show_file(s: ShowSettings, say: Say = logs.info) -> Path | None:
    """Draw one frame of ``s.file``: the raw scan (grey), partial inputs (purple) and completions (green) of the
    ``s.max_objects`` objects with most points, as a PNG and/or an HTML page. Returns the PNG (None: page only)."""
    if s.max_objects < 1:
        raise ParameterError("`max_objects` must be >= 1", "max_objects")
    check_suffix(s.out, (".png",), "the picture")
    check_suffix(s.html, (".html", ".htm"), "the page (HTML)", "html")
    obs = read_observations(s.file)
    rows = frame_rows(obs, s.sequence, s.frame)
    rows = sorted(rows, key=lambda i: -int(obs.n_points_raw[i]))[: s.max_objects]
    default_out = str(Path(s.file).with_suffix("")) + f"_{file_stem(obs.frame_id[rows[0]])}.png"
    check_writable(s.out or (None if s.html else default_out), s.html)
    completions, model = None, None
    if s.no_completion and s.checkpoint:
        raise ParameterError("`no_completion` draws no model: it takes no `checkpoint`", "no_completion", "checkpoint")
    if not s.no_completion:
        completer = load_completers([s.checkpoint or "default"], s.device)[0]
        completions = complete_all(
            completer, obs.partial[rows], progress=False, clip=s.clip, box_sizes=obs.box_size[rows]
        )
        model = completer.model_name
    i0 = rows[0]
    frame = obs.frame_id[i0]
    title = f"{obs.meta.get('source_format')} {obs.sequence[i0] + '/' if obs.sequence[i0] else ''}{frame}" + (
        f" - {model}" if model else ""
    )
    objects = f"{len(rows)} object{'' if len(rows) == 1 else 's'} of frame {frame}"
    if s.html:
        scene = html.scene_traces(read_frame_scan(obs, i0), frame_objects(obs, rows, completions))
        html.write_html(s.html, html.page([("scene", scene)], title))
        say(f"wrote {s.html} ({objects}, interactive)")
        if not s.out:
            return None
    out = s.out or default_out
    render_frame(out, obs, rows, completions, title=title)
    say(f"wrote {out} ({objects})")
    return Path(out)


__all__ = [
    "EvaluateSettings",
    "ExtractSettings",
    "ShowSettings",
    "earlier_reports",
    "evaluate_file",
    "extract_file",
    "load_completers",
    "observation_lines",
    "report_names",
    "show_file",
]
