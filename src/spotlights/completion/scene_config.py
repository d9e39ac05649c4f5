"""Settings of a frame's completion (:class:`SceneConfig`), the heading check's rule and the ``source`` codes of the
output points."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..data.real.base import CLASSES
from ..data.real.scans import MIN_SCAN_POINTS
from ..errors import ParameterError, parameter_names, shown
from ..geometry.evidence import snap_radius
from ..learning.fit import FIT_STEPS, FitSettings, check_fit_options, check_fit_steps
from ..learning.inference import DEFAULT
from ..options import check_seed

SOURCE_RAW, SOURCE_PARTIAL, SOURCE_COMPLETION = 0, 1, 2


HEADING_MARGIN = 0.5
"""The heading check turns a box around only when the turned completion's fidelity is lower by more than this
share (0.5: below half the given heading's). Measured with the default model (``benchmarks/heading.py
--checkpoint default``, docs/real-data.md): on 280 synthetic test scans no right box is turned at any margin
up to 0.6 and 70% of backward boxes are turned back at 0.5 (98% at 0.3); on *correct* annotated real boxes its
dense completions fit the observed points almost as well either way round, so lower margins turn many of them
(at 0.3: 15.6% on AV2, 5.5% on nuScenes, 7.7% on KITTI); at 0.5: 3.1%, 0.5% and 0%. (The paper SA-Net turned
none of the real cars at 0.3: with ``--checkpoint paper`` a margin of 0.3 recovers more.) A backward box
multiplies the completion's error by 3.2-3.5."""


HEADING_DOC = (
    "complete each box also turned by 180 degrees and keep the heading whose completion is clearly closer "
    "to the observed points (fidelity lower by more than the margin)"
)


def heading_turns(f_given, f_turned, margin: float = HEADING_MARGIN):
    """True where the turned heading wins: its fidelity is finite and below ``(1 - margin)`` x the given one's
    (a given heading with an empty completion loses to any turned one). Scalars or arrays."""
    fg = np.asarray(f_given, dtype=np.float64)
    ft = np.asarray(f_turned, dtype=np.float64)
    return np.isfinite(ft) & (~np.isfinite(fg) | (ft < (1.0 - margin) * fg))


@dataclass(frozen=True)
class SceneConfig:
    """Parameters of :func:`complete_scene` (lengths in metres).

    classes : classes to complete (None: every vehicle class); ``any_label=True`` completes
        every valid box whatever its label (the single-object form of ``complete``).
    crop : False uses every scan point as the object's input (a scan that is already cropped).
    resample, seed : the 256-point input (see :func:`spotlights.learning.inference.prepare_partial`).
    clip : SA-Net depth clip (``DEFAULT`` = the checkpoint's; None = no clip).
    keep_observed : return each object's observed points (the model's input points, repeats removed) after
        its predicted ones in ``completion`` / ``completion_unit`` (PoinTr-style); fidelity and the heading
        check are scored on the predicted points alone. Off here; ``complete`` and ``real complete`` turn it
        on by default (``--no-keep-observed``).
    complete_unknown : also complete the boxes the model did not learn (``LearnedDomain.gate``: a class
        outside its classes, or a size far outside its class's range); by default they are left as their
        observed points, status ``not_learned`` (counted per class in the summary's ``not_completed``).
    snap : > 0: the SA-Nets' rays that pass within ``snap`` (unit frame: the box's half diagonal) of one of the
        object's input points take their depth from the scan
        (:func:`spotlights.geometry.evidence.snap_to_observed`); 0: off (default). Fidelity is then scored on
        the snapped completion (near 0 by construction), so it does not go with the heading check.
    snap_mirror : with ``snap``, also snap to the input's mirror image across the box's x-z plane (``y -> -y``).
    fit : fit each SA-Net completion to its object's evidence (observed points and the free space in front of
        them) with ``fit_steps`` Adam steps, kept only where it lowers the fidelity
        (:func:`spotlights.learning.fit.fit_completions`; a fallback that cannot be fitted completes unfitted);
        off by default. Not with ``snap``. fit_steps : 1..:data:`~spotlights.learning.fit.MAX_FIT_STEPS`.
    """

    margin: float = 0.15
    ground_clearance: float = 0.10
    min_points: int = MIN_SCAN_POINTS
    classes: tuple | None = None
    any_label: bool = False
    crop: bool = True
    resample: str = "random"
    seed: int = 0
    heading_check: bool = False
    heading_margin: float = HEADING_MARGIN
    clip: object = "default"
    keep_observed: bool = False
    complete_unknown: bool = False
    snap: float = 0.0
    snap_mirror: bool = False
    fit: bool = False
    fit_steps: int = FIT_STEPS

    def __post_init__(self):
        _check_option_types(self)
        check_seed(self.seed, "the seed")
        _check_clip(self.clip)
        _check_ranges(self)
        object.__setattr__(self, "snap", snap_radius(self.snap, self.snap_mirror) or 0.0)  # None (off): 0.0
        if self.snap > 0 and self.heading_check:
            raise ParameterError(
                "`snap` does not go with `heading_check`: the check compares how close each heading's completion "
                "comes to the observed points, and snapping puts both on them",
                "snap",
                "heading_check",
            )
        check_fit_options(self.fit, self.snap)
        check_fit_steps(self.fit_steps)
        _check_classes(self.classes)

    @property
    def fit_settings(self) -> FitSettings | None:
        """The :class:`~spotlights.learning.fit.FitSettings` of ``fit``/``fit_steps``, or None when ``fit`` is off."""
        return FitSettings(steps=int(self.fit_steps)) if self.fit else None


def _check_option_types(config: SceneConfig) -> None:
    """Refuse a :class:`SceneConfig` whose real-valued options are not numbers or whose counts are not whole."""
    for name in ("margin", "ground_clearance", "heading_margin"):  # snap: snap_radius below
        v = getattr(config, name)
        if isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise ParameterError(f"{shown(name)} must be a number, got {v!r}", *parameter_names(name))
    for name in ("min_points", "seed"):
        v = getattr(config, name)
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise ParameterError(f"{shown(name)} must be a whole number, got {v!r}", *parameter_names(name))


def _check_clip(clip: Any) -> None:
    """Refuse a ``clip`` that is not a depth threshold in [0, 1], None, ``DEFAULT`` or ``"default"``."""
    number = isinstance(clip, numbers.Real) and not isinstance(clip, bool)
    if not (
        clip is None or clip is DEFAULT or (isinstance(clip, str) and clip == "default") or (number and 0 <= clip <= 1)
    ):
        raise ParameterError(
            f"clip must be a depth threshold in [0, 1] (unit frame), None (no clip) or 'default', got {clip!r}"
        )


def _check_ranges(config: SceneConfig) -> None:
    """Refuse a :class:`SceneConfig` whose margin, ground clearance, heading margin or minimum point count is out
    of range."""
    if not (math.isfinite(config.margin) and config.margin >= 0):
        raise ParameterError(f"margin must be >= 0 metres, got {config.margin}")
    if not math.isfinite(config.ground_clearance):
        raise ParameterError(f"ground clearance must be finite, got {config.ground_clearance}")
    if not 0.0 <= config.heading_margin < 1.0:
        raise ParameterError(f"the heading margin must be in [0, 1), got {config.heading_margin}")
    if config.min_points < 1:
        raise ParameterError(f"the minimum point count must be >= 1, got {config.min_points}")


def _check_classes(classes) -> None:
    """Refuse an empty ``classes`` list or one naming a class outside ``CLASSES`` (None: every vehicle class)."""
    if classes is not None:
        bad = [c for c in classes if c not in CLASSES]
        if bad or not classes:
            raise ParameterError(
                f"unknown class(es) {', '.join(bad) or '(none given)'}; choose among {', '.join(CLASSES)}"
            )
