"""What a completer is asked to do (:class:`CompletionRequest`: the scans and every option of their completion, and
their checks), the :data:`DEFAULT` clip, and the helpers the completers share (:func:`accepts`, :func:`mirrored`).
Re-exported by :mod:`spotlights.learning.inference`, whose :class:`~spotlights.learning.inference.BaseCompleter`
takes these requests."""

from __future__ import annotations

import inspect
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ParameterError
from ..geometry.evidence import SnapTargets, snap_radius

if TYPE_CHECKING:
    from .inference import BaseCompleter

__all__ = ["DEFAULT", "CompletionRequest", "accepts", "mirrored"]


class _Default:
    """The type of :data:`DEFAULT` (shown as ``default`` in signatures and help)."""

    def __repr__(self) -> str:
        return "default"


DEFAULT = _Default()
"""Sentinel for "the model's configured clip" (SA-Net: 0.2), shared by every completer."""


@dataclass
class CompletionRequest:
    """What :meth:`BaseCompleter.complete` is asked to do: the scans and every option of their completion.

    Attributes
    ----------
    partials : (B, K, 3) float32 unit-frame points (K = 256 as in training; any K >= 1
        works, the encoder max-pools), or one (K, 3) scan.
    clip : SA-Net depth threshold: :data:`DEFAULT` = the model's (0.2 for the paper SA-Net), ``None`` = keep
        every ray with depth > 0. Ignored by the point models. The hit-aware SA-Net keeps
        the rays with p(hit) >= its stored threshold (:attr:`threshold`); its default clip is none.
    batch_size : forward passes are chunked to this many scans.
    extents : (B, 3) (or (3,) for all) box half-extents of each scan in its unit frame,
        ``size / |size|`` for a box of size (l, w, h) (:func:`~spotlights.geometry.boxes.unit_extents`).
        Required when :attr:`needs_box` (SA-Net on a box-targeted rig: each scan decodes
        with the rays aimed at its own box); ignored otherwise.
    sensor_origins : (B, 3) (or (3,)) the LiDAR's optical centre in each scan's unit frame, for models that
        read free space (``sanet-local``; None or NaN rows: no free-space evidence) and for ``snap``'s
        occlusion rule; ignored by the others.
    classes : B class names (or None each) for a class-conditioned model (its :attr:`classes`; a name it
        lacks: no class input); ignored by the others.
    box_half : (B, 3) half-extents of a box per scan in its unit frame (e.g. the box grown by 0.15 m):
        the SA-Nets clip every kept ray's depth to it, exactly along the ray (``inside``, a list, gets each
        scan's share of points inside before the clip); the point models ignore both.
    snap : radius R > 0 (unit frame) to snap each scan's rays to its observed points (SA-Nets only;
        :func:`spotlights.geometry.evidence.snap_to_observed`: a ray passing within R of an observed point
        takes its depth from the scan; with ``sensor_origins``, not onto a point hidden behind the predicted
        surface unless the LiDAR saw through it); None or 0: off (default).
    observed : with ``snap``, B arrays (K_b, 3) of each scan's observed points, unit frame (default: the
        partials themselves).
    snap_mirror : with ``snap``, also snap to the observed points' mirror image across the box's x-z plane
        (``y -> -y``: vehicles are left-right symmetric), so the side the LiDAR did not see follows the one
        it saw.
    seen : with ``snap`` and ``sensor_origins``, B arrays (K'_b, 3) of the points each scan's LiDAR saw from
        its sensor origin, unit frame: the free space the occlusion rule carves (default: the observed points;
        give them when other frames' points were fused into the input, which were seen from elsewhere).
    inside : a list that receives each scan's share of points inside ``box_half`` before the clip (SA-Nets).
    """

    partials: np.ndarray
    clip: Any = DEFAULT
    batch_size: int = 256
    extents: np.ndarray | None = None
    sensor_origins: np.ndarray | None = None
    classes: Sequence[str | None] | None = None
    box_half: np.ndarray | None = None
    inside: list | None = None
    snap: float | None = None
    observed: Sequence[np.ndarray] | None = None
    snap_mirror: bool = False
    seen: Sequence[np.ndarray] | None = None

    def checked_partials(self) -> np.ndarray:
        """The partials as (B, K, 3) float32 (one (K, 3) scan becomes B = 1), checked: K >= 1, finite."""
        x = np.asarray(self.partials, dtype=np.float32)
        if x.ndim == 2:
            x = x[None]
        if x.ndim != 3 or x.shape[-1] != 3:
            raise ParameterError(f"`partials` must have shape (B, K, 3), got {x.shape}", "partials")
        if x.shape[0] and x.shape[1] == 0:
            raise ParameterError("partial scans are empty (K = 0 points)", "partials")
        if not np.all(np.isfinite(x)):
            raise ParameterError("partial scans contain NaN or infinite coordinates", "partials")
        return x

    def checked_extents(self, completer: BaseCompleter, n: int) -> np.ndarray | None:
        """(n, 3) float64 box half-extents when ``completer`` needs each scan's box, else None."""
        if not completer.needs_box:
            return None
        if self.extents is None:
            raise ParameterError(
                f"this SA-Net regresses the box-targeted rig {completer.rig.name}: give each scan's box "
                "half-extents (`extents` = size / |size|)",
                "extents",
            )
        e = np.asarray(self.extents, dtype=np.float64)
        e = np.broadcast_to(e, (n, 3)) if e.shape == (3,) else e
        if e.shape != (n, 3):
            raise ParameterError(f"`extents` must have shape ({n}, 3) or (3,), got {np.shape(self.extents)}", "extents")
        return e

    def checked_classes(self, n: int) -> list | None:
        """The class names as a list of n, or None."""
        names = None if self.classes is None else list(self.classes)
        if names is not None and len(names) != n:
            raise ParameterError(f"{len(names)} class names for {n} scans", "classes")
        return names

    def checked_snap(self, completer: BaseCompleter, n: int) -> float | None:
        """The snap radius (None: off), checked against the completer and the point sets given with it."""
        snap = snap_radius(self.snap, option="snap")
        if snap is None:
            if self.snap_mirror or self.observed is not None or self.seen is not None:
                raise ParameterError(
                    "`snap_mirror`, `observed` and `seen` go with a snap radius (`snap`=R)",
                    "snap_mirror",
                    "observed",
                    "seen",
                    "snap",
                )
            return None
        if completer.rig is None or not accepts(completer._forward, "snap"):  # noqa: SLF001 - its own runtime
            raise ParameterError(
                f"{completer.model_name} has no rays to snap: snapping to the observed points needs an SA-Net"
            )
        for name, sets in (("observed", self.observed), ("seen", self.seen)):
            if sets is not None and len(sets) != n:
                raise ParameterError(f"{len(sets)} `{name}` point sets for {n} scans", name)
        return snap

    def snap_targets(self, x: np.ndarray, chunk: slice, snap: float, origins: np.ndarray | None) -> SnapTargets:
        """The snap targets of the scans ``x[chunk]`` (their observed points, mirrored with ``snap_mirror``)."""
        obs = x[chunk] if self.observed is None else self.observed[chunk]
        pts = [np.asarray(o, dtype=np.float64).reshape(-1, 3) for o in obs]
        seen = self.seen
        carve = pts if seen is None else [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in seen[chunk]]
        return SnapTargets([mirrored(p) for p in pts] if self.snap_mirror else pts, snap, origins, carve)


def accepts(fn, name: str) -> bool:
    """True when callable ``fn`` takes a keyword argument ``name`` (or ``**kwargs``): the optional inputs
    (``classes``, ``box_half``) go only to completers and runtimes that take them."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False
    return name in params or any(p.kind is p.VAR_KEYWORD for p in params.values())


def mirrored(points: np.ndarray) -> np.ndarray:
    """(2K, 3) the points (K, 3) of a box's unit (or object) frame, then their mirror image across its x-z plane
    (``y -> -y``), same dtype."""
    p = np.asarray(points).reshape(-1, 3)
    return np.concatenate([p, p * np.array([1, -1, 1], dtype=p.dtype)])
