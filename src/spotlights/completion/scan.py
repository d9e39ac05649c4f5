"""Completing one scan from files: what ``spotlights complete`` runs, as settings and one function.

:class:`CompletionOptions` holds the options ``complete`` and ``real complete`` share (model, runtime,
class selection, crop, model input, heading check), one field per command-line option, with the same
defaults; :meth:`CompletionOptions.scene_config` turns them into the
:class:`~spotlights.completion.frame.SceneConfig` of :func:`~spotlights.completion.frame.complete_scene`
and :meth:`CompletionOptions.load_completer` loads the model with the runtime
(:func:`spotlights.learning.runtime.load_completer`, the one place that chooses torch or ONNX).

:class:`ScanSettings` adds the scan, its boxes (a box file of the whole frame, or one object's box) and the
outputs; :func:`complete_scan` checks every option and destination, reads, completes, writes
(``OUT.ply``, per-object files, a JSON summary, a PNG, an HTML page) and reports through callbacks.

Frames: the scan's points and boxes are in the scan's frame (metres); ``up``/``forward`` name the scan's
axes (:func:`spotlights.geometry.io.axes_rotation`), and every output is in the scan's frame.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import logs
from ..data.real.boxfiles import read_box_file, with_class
from ..data.real.scans import read_scan
from ..data.tracks import MAX_GAP_S, WindowPolicy, parse_window
from ..errors import ParameterError
from ..geometry.box_json import box_from_dict
from ..geometry.boxes import Box
from ..geometry.io import axes_rotation
from ..inputs import read_json
from ..learning.fit import FIT_STEPS
from ..learning.inference import BaseCompleter
from ..learning.runtime import Runtime, fallback_runtime, load_completer, runs_with, shipped_onnx
from ..options import check_threads
from ..outputs import check_distinct_paths, check_suffix, check_writable, same_file
from .frame import (
    HEADING_MARGIN,
    SceneConfig,
    SceneResult,
    check_completed,
    complete_scene,
    describe,
    require_points,
    require_rays_to_snap,
    require_sensor,
    write_scene,
)
from .fusion import threads_beside_worker
from .pictures import render_result, render_result_html
from .writing import write_json

Say = Callable[[str], None]
"""A callback taking one line of text (``print`` for the summary lines; a warning printer for warnings)."""


def silent(line: str) -> None:
    """The default :data:`Say` callback: say nothing."""


def parse_classes(text: str | tuple | list | None) -> tuple[str, ...] | None:
    """``--classes`` text (``"car, Truck"``) -> a tuple of lower-case class names (``("car", "truck")``);
    None stays None, a tuple or list is taken as it is."""
    if text is None:
        return None
    if isinstance(text, (tuple, list)):
        return tuple(text)
    return tuple(c.strip().lower() for c in text.split(",") if c.strip())


#: ``--fallback``'s default: the packaged class model beside the default model (:func:`resolve_fallback`)
AUTO_FALLBACK = "auto"
#: the packaged model that ``"auto"`` picks: cars, vans, trucks, buses and trailers (docs/real-data.md)
CLASS_MODEL = "classes"


def resolve_fallback(fallback: str | None, checkpoint: str | None = None, runtime: str | None = None) -> str | None:
    """The fallback model a completion runs, from ``--fallback`` and the main model.

    ``"auto"`` (the default) is the packaged class model (``"classes"``) when the main model is the packaged
    car-only default (``checkpoint`` None or ``"default"``) on any runtime that can run it (``runtime`` None,
    ``"auto"`` or ``"torch"``; ``"onnx"`` where its export is shipped, so an ONNX run stays torch-free), else no
    fallback: a model the user chose is not second-guessed. ``"none"`` (any case) or None: no fallback. Any other text is a checkpoint file or short name,
    returned as it is."""
    if fallback is None or str(fallback).strip().lower() == "none":
        return None
    if str(fallback).strip().lower() != AUTO_FALLBACK:
        return str(fallback)
    is_default = checkpoint is None or str(checkpoint) == "default"
    runs = runtime in (None, "auto", "torch") or (runtime == "onnx" and shipped_onnx(CLASS_MODEL) is not None)
    return CLASS_MODEL if is_default and runs else None


@dataclass(kw_only=True)
class CompletionOptions:
    """The options of ``complete`` and ``real complete`` (one field per command-line option, same defaults).

    checkpoint : a checkpoint file, a short name (``"default"``, ``"paper"``, ``"classes"``) or a ``.onnx`` file; None: default.
    classes : comma-separated classes to complete (text or tuple); None: every vehicle class.
    keep_observed : return each object's observed points beside its predicted ones.
    snap : > 0: snap the SA-Nets' rays to each object's observed points within this radius (unit frame; 0: off;
        :class:`~spotlights.completion.frame.SceneConfig`); snap_mirror : and to their mirror image (``y -> -y``).
    fit, fit_steps : fit each SA-Net completion to its object's evidence with ``fit_steps`` Adam steps (None: the
        default, :data:`~spotlights.learning.fit.FIT_STEPS`), kept where it lowers the fidelity (SceneConfig); a
        runtime left to choose (None, ``"auto"``) is then torch, which the fit needs.
    complete_unknown : also complete boxes whose class (or size, far outside its class's range) the model did not
        learn (default: left as their observed points, status ``not_learned``, counted per class).
    fallback : a second model (file or short name, e.g. ``"classes"``) for the boxes :attr:`checkpoint`'s model
        did not learn but it did; ``"auto"`` (default): the packaged class model beside the default model
        (:func:`resolve_fallback`); ``"none"`` or None: such boxes are left as observed points (or
        ``complete_unknown``).
    heading_check, heading_margin : complete each box also turned by 180 degrees (margin None: 0.5).
    margin : metres the box is grown by on its sides and top (None: 0.15).
    ground_clearance : metres above the box bottom under which points are dropped (ground returns).
    min_points : boxes with fewer points are not completed; a scan needs at least this many.
    resample, seed : how the 256-point model input is drawn (``"random"`` or ``"fps"``) and its seed.
    clip, no_clip : SA-Net depth clip in [0, 1] (None: the checkpoint's); ``no_clip`` keeps every ray.
    device, precision, runtime : torch device; ``auto`` (default: bf16 with torch on a CPU with native bfloat16,
        else fp32), ``fp32`` or ``bf16``; ``auto`` (default: onnxruntime for a packaged model shipped with its
        export, on the CPU; :func:`spotlights.learning.runtime.choose_runtime`), ``torch`` or ``onnx``.
    threads : torch CPU threads for the run (None: torch's default; with a track worker process, the usable CPUs less
        one: :func:`spotlights.completion.fusion.threads_beside_worker`); a given count is used as it is, and with
        ``runtime="onnx"`` it is onnxruntime's intra-op thread count too.
    """

    checkpoint: str | None = None
    classes: str | tuple | None = None
    keep_observed: bool = True
    snap: float = 0.0
    snap_mirror: bool = False
    fit: bool = False
    fit_steps: int | None = None
    complete_unknown: bool = False
    fallback: str | None = AUTO_FALLBACK
    heading_check: bool = False
    heading_margin: float | None = None
    margin: float | None = None
    ground_clearance: float = 0.10
    min_points: int = 10
    resample: str = "random"
    seed: int = 0
    clip: float | None = None
    no_clip: bool = False
    device: str | None = None
    precision: str = "auto"
    runtime: Runtime | None = "auto"
    threads: int | None = None

    def __post_init__(self) -> None:
        # the evidence fit differentiates the torch model: where the runtime is left to choose, torch runs it
        if self.fit and self.runtime in (None, "auto") and not str(self.checkpoint or "").lower().endswith(".onnx"):
            self.runtime = "torch"

    @property
    def checkpoint_name(self) -> str:
        """The checkpoint as recorded in summaries (and compared by ``real complete --resume``): the given text, or
        ``"default"``; with a fallback model (:attr:`fallback_model`), ``"NAME + fallback FALLBACK"``."""
        name = str(self.checkpoint) if self.checkpoint else "default"
        fb = self.fallback_model
        return name if fb is None else f"{name} + fallback {fb}"

    @property
    def fallback_model(self) -> str | None:
        """The fallback model these options run (:func:`resolve_fallback` of :attr:`fallback`), or None."""
        return resolve_fallback(self.fallback, self.checkpoint, self.runtime)

    def scene_config(self, margin: float | None = None, crop: bool = True) -> SceneConfig:
        """The :class:`~spotlights.completion.frame.SceneConfig` of these options (``margin``: the crop
        margin in metres when given another way, else :attr:`margin`; ``crop=False``: every scan point is the
        object's input). Raises :class:`ParameterError` for options that do not go together."""
        margin = self.margin if margin is None else margin
        clip = None if self.no_clip else ("default" if self.clip is None else float(self.clip))
        if self.heading_margin is not None and not self.heading_check:
            raise ParameterError("`heading_margin` goes with `heading_check`", "heading_margin", "heading_check")
        if not crop and margin is not None:
            raise ParameterError("`no_crop` uses every point: it takes no `margin`/`crop`", "no_crop", "margin", "crop")
        if self.fit_steps is not None and not self.fit:
            raise ParameterError("`fit_steps` goes with `fit`", "fit_steps", "fit")
        return SceneConfig(
            margin=0.15 if margin is None else float(margin),
            ground_clearance=float(self.ground_clearance),
            min_points=int(self.min_points),
            classes=parse_classes(self.classes),
            crop=crop,
            resample=self.resample,
            seed=int(self.seed),
            heading_check=bool(self.heading_check),
            clip=clip,
            keep_observed=bool(self.keep_observed),
            snap=float(self.snap),
            snap_mirror=bool(self.snap_mirror),
            fit=bool(self.fit),
            fit_steps=FIT_STEPS if self.fit_steps is None else self.fit_steps,
            complete_unknown=bool(self.complete_unknown),
            heading_margin=HEADING_MARGIN if self.heading_margin is None else float(self.heading_margin),
        )

    def load_completer(self, threads: int | None = None, frames: int = 1) -> BaseCompleter:
        """The model of :attr:`checkpoint` run with :attr:`runtime` on :attr:`device` at :attr:`precision`
        (:func:`spotlights.learning.runtime.load_completer`, ``frames`` the frames it will complete); onnxruntime's
        threads: :attr:`threads`, else ``threads`` (None: its default; a run with a track worker leaves that process
        a core)."""
        return load_completer(
            self.checkpoint,
            runtime=self.runtime,
            device=self.device,
            precision=self.precision,
            threads=check_threads(self.threads) or threads,
            frames=frames,
        )

    def check_snap(self, completer: BaseCompleter) -> None:
        """Refuse ``--snap`` for a main model without rays before any work (:func:`~spotlights.completion.frame.
        require_rays_to_snap`, which :func:`~spotlights.completion.frame.complete_scene` runs again per scan)."""
        require_rays_to_snap(completer, self.snap)

    def load_fallback(self, threads: int | None = None, frames: int = 1) -> BaseCompleter | None:
        """The model of :attr:`fallback_model` (same device, precision, threads and runtime where it can run with it:
        :func:`~spotlights.learning.runtime.fallback_runtime`), or None."""
        fb = self.fallback_model
        if fb is None:
            return None
        runtime = fallback_runtime(self.runtime, fb)
        threads = check_threads(self.threads) or threads
        return load_completer(
            fb, runtime=runtime, device=self.device, precision=self.precision, threads=threads, frames=frames
        )


@dataclass(kw_only=True)
class ScanSettings(CompletionOptions):
    """What ``spotlights complete`` does: the scan, its boxes, the outputs, and the :class:`CompletionOptions`.

    input : the scan file (KITTI ``.bin``, nuScenes ``.pcd.bin``, AV2 ``.feather``, PLY, PCD, NPY, ...).
    out : the scene (``.ply`` with ``source`` and ``object`` fields; other suffixes: completion points only).
    boxes, calib : every box of the frame (JSON, or a KITTI ``label_2`` file with its calib file); or
    box : one object's box file (JSON); or center, size, yaw : one object's box given inline (metres, radians;
    yaw None: 0, and refused without center/size).
    crop : the crop margin's older name (same as ``margin``); no_crop : one object, every scan point used.
    sensor : the LiDAR's position in the scan's frame (metres; None: the scan's origin, as a sensor-frame scan
    has it): the free space the ray-local model reads and ``--snap``'s occlusion rule; one scan only.
    up, forward : the scan's axes; per_object : folder of ``object_<id>.ply``; summary : JSON file;
    show : PNG picture (a bird's-eye raster); closeups : and a matplotlib close-up per object in it; html :
    interactive page; quiet : no summary lines.
    fuse, refine_boxes, max_gap, rerun, track_worker, track_shape : for a multi-frame scene (:attr:`multi_frame`:
    ``input`` a folder of frames or a sequence ``.json`` of the generic format), as :class:`~spotlights.completion.
    frame_selection.FramesSettings` has them; a single scan refuses a fusing window, ``refine_boxes``, ``rerun``,
    ``track_worker=False`` and ``track_shape``
    (:meth:`check_single_scan`).
    """

    input: str
    out: str
    boxes: str | None = None
    calib: str | None = None
    box: str | None = None
    center: list | None = None
    size: list | None = None
    yaw: float | None = None
    crop: float | None = None
    no_crop: bool = False
    sensor: list | None = None
    up: str = "z"
    forward: str = "x"
    per_object: str | None = None
    summary: str | None = None
    show: str | None = None
    closeups: bool = False
    html: str | None = None
    quiet: bool = False
    fuse: WindowPolicy | str = field(default_factory=lambda: parse_window("none"))
    refine_boxes: bool = False
    max_gap: float = MAX_GAP_S
    rerun: str | None = None
    track_worker: bool = True
    track_shape: bool = False

    @property
    def multi_frame(self) -> bool:
        """``input`` is a multi-frame generic scene (a folder of frames or a sequence ``.json``), not one scan."""
        return Path(self.input).is_dir() or Path(self.input).suffix.lower() == ".json"

    def check_single_scan(self) -> None:
        """Refuse in one line the options of a multi-frame scene (track fusion, rerun) for one scan."""
        window = parse_window(self.fuse) if isinstance(self.fuse, str) else self.fuse
        given = [
            name
            for name, on in (
                (f"--fuse {window}", window.fuses),
                ("--refine-boxes", self.refine_boxes),
                ("--rerun", self.rerun is not None),
                ("--no-track-worker", not self.track_worker),
                ("--track-shape", self.track_shape),
            )
            if on
        ]
        require_sensor(None if self.sensor is None else tuple(self.sensor), "--sensor")  # before any work
        if given:
            raise ParameterError(
                f"{self.input}: {given[0]} needs a multi-frame scene (a folder of scans with NAME.json box files, or "
                "a sequence .json); this is one scan"
            )

    @property
    def single(self) -> bool:
        """One object (``box`` or ``center``/``size``) rather than a frame's box file."""
        return self.boxes is None

    def check_boxes(self) -> None:
        """Raise a one-line :class:`ParameterError` when the box options do not describe one frame or one object."""
        single_given = [
            n
            for n, v in (("--box", self.box), ("--center/--size", self.center is not None or self.size is not None))
            if v
        ]
        if self.boxes is not None and single_given:
            raise ParameterError(
                f"give the boxes either as `boxes` or as {single_given[0]} (one object), not both", "boxes"
            )
        if len(single_given) > 1:
            raise ParameterError(
                "give the box either as `box` BOX.json or as `center`/`size`/`yaw`, not both",
                "box",
                "center",
                "size",
                "yaw",
            )
        if self.calib is not None and self.boxes is None:
            raise ParameterError("`calib` goes with a KITTI label_2 file in `boxes`", "calib", "boxes")
        if self.single and (self.center is None) != (self.size is None) and self.box is None:
            raise ParameterError("one object's box needs both `center` X Y Z and `size` L W H", "center", "size")
        if self.yaw is not None and self.center is None:
            raise ParameterError(
                "`yaw` goes with `center`/`size` (a box file gives its own heading)", "yaw", "center", "size"
            )
        if self.single and self.box is None and self.center is None:
            raise ParameterError(
                "the boxes are missing: pass `boxes` BOXES (a frame), or one object's `box` BOX.json or "
                "`center` X Y Z `size` L W H [`yaw` RAD]",
                "boxes",
                "box",
                "center",
                "size",
                "yaw",
            )
        if not self.single and self.no_crop:
            raise ParameterError(
                "`no_crop` is for one object already cropped; the boxes of a frame are always cropped", "no_crop"
            )

    def scan_config(self) -> SceneConfig:
        """The :class:`SceneConfig` of a scan: :meth:`scene_config` with ``--crop`` (an alias of ``--margin``) and
        ``--no-crop`` for one object, whose box is completed whatever its label."""
        if not self.single:
            return self.scene_config()
        margin = self.margin
        if self.crop is not None:
            if margin is not None and margin != self.crop:
                raise ParameterError("give the crop margin once: `margin` or `crop`", "margin", "crop")
            margin = self.crop
        config = self.scene_config(margin, crop=not self.no_crop)
        if self.classes is not None:
            raise ParameterError(
                "`classes` chooses among the boxes of `boxes`; one object's box is always completed", "classes", "boxes"
            )
        return dataclasses.replace(config, any_label=True)

    def check_paths(self) -> None:
        """Refuse, before any work, an output that would overwrite an input (the scan, a box or calib file) or
        another output, per-object files (``--per-object DIR``'s ``object_<id>.ply``) included: one line naming
        both options (:func:`spotlights.outputs.check_distinct_paths`)."""
        inputs = [("SCAN", self.input), ("--boxes", self.boxes), ("--calib", self.calib), ("--box", self.box)]
        outputs = [("--out", self.out), ("--summary", self.summary), ("--show", self.show), ("--html", self.html)]
        outputs.append(("--rerun", self.rerun))
        check_distinct_paths(inputs, outputs)
        if self.per_object is not None:
            for option, path in inputs + outputs:
                if path is not None and _PER_OBJECT_NAME.match(Path(path).name):
                    if same_file(Path(path).parent, self.per_object):
                        raise ParameterError(
                            f"{option} {path} is in `per_object` {self.per_object}, which receives object_<id>.ply "
                            "files: one would replace it; choose another folder",
                            "per_object",
                        )

    def check_outputs(self) -> None:
        """Refuse, before any work, an output whose suffix does not fit, that cannot be written, or that would
        overwrite an input or another output (:meth:`check_paths`)."""
        self.check_paths()
        if self.closeups and not self.show:
            raise ParameterError("`closeups` goes with `show` PNG (the picture they are drawn in)", "closeups", "show")
        check_suffix(self.show, (".png",), "the picture", "show")
        check_suffix(self.html, (".html", ".htm"), "the page (HTML)", "html")
        check_suffix(self.summary, (".json",), "the summary (JSON)", "summary")
        check_writable(self.out, self.show, self.html, self.summary)
        if self.per_object is not None:  # every destination before anything is written
            check_writable(Path(self.per_object) / "object_0.ply")

    @property
    def box_source(self) -> str:
        """Where the boxes come from, as errors name it: the box file, or ``--center/--size``."""
        return self.boxes or self.box or "--center/--size"

    def read_boxes(self, axes: np.ndarray) -> list[Box]:
        """The boxes (scan frame, metres, with ``cls``): every box of :attr:`boxes`, or the one object's box
        (its yaw about the scan's up axis, ``axes`` the (3, 3) rotation of :func:`axes_rotation`)."""
        if self.boxes is not None:
            return read_box_file(self.boxes, calib=self.calib, axes=axes).boxes
        if self.box is not None:
            box = box_from_dict(read_json(self.box), self.box, axes=axes)
        else:
            box = box_from_dict(
                {"center": self.center, "size": self.size, "yaw": self.yaw or 0.0}, "--center/--size", axes=axes
            )
        if not box.is_valid():
            raise ParameterError(f"{self.box_source}: box size must be positive, got {box.size.tolist()}")
        return [with_class(box)]


#: The names of ``--per-object DIR``'s files: ``object_<id>.ply`` (:func:`~spotlights.completion.frame.write_scene`).
_PER_OBJECT_NAME = re.compile(r"^object_-?\d+\.ply$")


def _check_single(s: ScanSettings, result: SceneResult, points: np.ndarray, axes: np.ndarray, warn: Say) -> None:
    """One object: a one-line error when its box held too few points or its completion is empty; a warning
    when most of an uncropped scan lies outside the box's sphere."""
    config = result.config
    o = result.objects[0]
    if o.status == "too_few_points":
        raise ParameterError(
            f"{s.box_source}: {len(o.input_indices)} scan point(s) lie in the box (grown by {config.margin} m, "
            f"bottom raised {config.ground_clearance} m); at least {config.min_points} are needed - check "
            "the box and the scan's frame (`no_crop` for an already cropped scan)",
            "no_crop",
        )
    if o.status == "empty_completion":
        raise ParameterError(
            f"{s.input}: the completion is empty (every ray was clipped); try `no_clip` or a lower `clip`",
            "no_clip",
            "clip",
        )
    if not config.crop:
        unit = (o.used_box or o.box).normalization().to_unit(np.asarray(points, dtype=np.float64) @ axes.T)
        outside = float(np.mean(np.linalg.norm(unit, axis=1) > 1.2))
        if outside > 0.5:
            warn(f"{outside:.0%} of the scan lies outside the box's sphere; is the box in the scan's frame?")


def complete_scan(
    s: ScanSettings, say: Say = logs.info, warn: Say = logs.warning, completer: BaseCompleter | None = None
) -> SceneResult:
    """Complete the vehicles of one scan file as ``spotlights complete`` does.

    Checks every option and destination first (one-line :class:`~spotlights.errors.SpotlightsError` naming the
    option or file), reads the scan ((N, 3) metres, scan frame) and its boxes, loads the model
    (:meth:`CompletionOptions.load_completer`), completes (:func:`~spotlights.completion.frame.complete_scene`)
    and writes ``s.out`` (+ per-object files, JSON summary, PNG, HTML). ``say`` receives the summary lines,
    ``warn`` one line per warning (out-of-domain boxes); ``completer``: a model already loaded (default: the
    one ``s`` names). Returns the :class:`SceneResult` (scan frame, metres).
    """
    s.check_single_scan()
    s.check_boxes()
    config = s.scan_config()
    check_threads(s.threads)  # also for a completer given: torch's OpenMP crashes on absurd counts
    s.check_outputs()
    axes = axes_rotation(s.up, s.forward)
    points = read_scan(s.input)
    require_points(points, config.min_points, s.input)
    boxes = s.read_boxes(axes)
    completer = s.load_completer() if completer is None else completer
    s.check_snap(completer)
    fallback = s.load_fallback()  # before the threads are set: a torch fallback imports torch
    with threads_beside_worker(None, s.threads):  # --threads, if given
        result = complete_scene(
            points,
            boxes,
            completer,
            config,
            axes=axes,
            checkpoint=s.checkpoint_name,
            sensor=None if s.sensor is None else np.asarray(s.sensor, dtype=np.float64),
            fallback=fallback,
            fallback_name=s.fallback_model,
        )
    if s.single:
        _check_single(s, result, points, axes, warn)
    else:
        check_completed(result, s.boxes)
    written = write_scene(result, s.out, per_object=s.per_object, scan_name=Path(s.input).name)
    title = f"{Path(s.input).name}: {result.model} completion of {len(result.completed)} object(s), scan frame"
    extra: list[Path] = []
    try:  # all or nothing, as write_scene: a failing --summary/--show/--html removes what this run wrote
        if s.summary:
            sensor = None if s.sensor is None else [float(v) for v in s.sensor]  # None: the scan's origin
            head = {"scan": str(s.input), "boxes": str(s.box_source), "out": str(s.out), "sensor": sensor}
            head["runtime"] = str(getattr(completer, "runtime", "torch"))  # what ran the model, and at what precision
            head["precision"] = str(getattr(completer, "precision", "fp32"))
            write_json(s.summary, {**head, **result.summary()})
            extra.append(Path(s.summary))
        if s.show:
            render_result(result, s.show, title, s.closeups)
            extra.append(Path(s.show))
        if s.html:
            render_result_html(result, s.html, title)
            extra.append(Path(s.html))
    except BaseException:
        for p in written + extra:
            p.unlink(missing_ok=True)
        raise
    for w in result.warnings():
        warn(w)
    say(
        f"{s.input}: {len(points)} points, {describe(result)} ({result.model}, {runs_with(completer)}) -> {s.out}"
        + (f" (+{len(written) - 1} per-object files in {s.per_object})" if s.per_object else "")
    )
    if s.show:
        say(f"picture -> {s.show}")
    if s.html:
        say(f"page -> {s.html}")
    return result


__all__ = ["CompletionOptions", "Say", "ScanSettings", "complete_scan", "parse_classes", "silent", "write_json"]
