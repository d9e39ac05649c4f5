"""The Spotlights ray rig (paper Sections 3.1-3.2).

A rig is N *primary* viewpoints on the unit sphere (the paper's spherical
Fibonacci lattice) each casting M rays toward the centre, the ray directions
being M *secondary* points Fibonacci-sampled with equal area on a spherical cap
of polar half-angle ``omega`` around the inward direction.

The module holds the rig types: :class:`RigSpec` (a rig's box-independent description, what
datasets, models and the command line hold) and :class:`Rig` (a spec plus, for box-targeted
rigs, the object's box: the concrete rays, cached), their constructors (:func:`make_rig`,
:func:`make_rig_spec`, :func:`parse_rig`) and validation. The rays themselves come from
:mod:`spotlights.geometry.lattice` (the paper's Fibonacci lattices and cap rays, with the
conventions that fix the ray order) and :mod:`spotlights.geometry.box_rays` (box-targeted rays,
beyond the paper: docs/box-rig.md); their public functions are importable from here too.

All arrays are float64 in the *unit frame* (the object's circumscribed sphere
scaled to radius 1).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from ..errors import ParameterError
from .box_rays import BOX_TARGETS, box_directions, box_face_solid_angles, box_targets
from .boxes import unit_extents
from .lattice import (
    GOLDEN_RATIO,
    HALTON_BASES,
    angle_from_radius,
    cap_directions,
    cap_ray_directions,
    check_angle,
    check_count,
    fibonacci_lattice_2d,
    fibonacci_sphere,
    halton,
    viewpoint_frames,
)

__all__ = [
    "BOX_DEFAULTS",
    "BOX_TARGETS",
    "GOLDEN_RATIO",
    "HALTON_BASES",
    "MAX_RAYS",
    "RIG_KINDS",
    "Rig",
    "RigSpec",
    "angle_from_radius",
    "box_directions",
    "box_face_solid_angles",
    "box_targets",
    "cap_directions",
    "cap_ray_directions",
    "check_extents",
    "extents_from_normalization",
    "fibonacci_lattice_2d",
    "fibonacci_sphere",
    "halton",
    "make_rig",
    "make_rig_spec",
    "parse_rig",
    "viewpoint_frames",
]

MAX_RAYS = 1 << 24
"""Most rays one rig may hold (N * M): 16.8 million, ~1.2 GB of float64 rays."""
RIG_KINDS = ("cap", "box")
# Parameters of a box rig left unset (the best variant of docs/box-rig.md).
BOX_DEFAULTS = {"scale": 1.0, "targets": "ellipsoid", "cap_share": 0.0}


@dataclass(frozen=True, init=False)
class Rig:
    """A Spotlights rig: N viewpoints x M rays, on the paper's cap or aimed at a box.

    A rig is its box-independent :class:`RigSpec` plus, for box rigs, the box: ``spec.for_box(extents)``
    or :meth:`from_spec` builds it from the two. The constructor takes the spec's fields and the box,
    ``Rig(n_primary, n_secondary, angle, kind, box, scale, targets, cap_share)``.

    Attributes
    ----------
    spec : the :class:`RigSpec`; ``n_primary`` (N, >= 1), ``n_secondary`` (M, >= 1), ``angle`` (the cap
        polar half-angle omega in degrees, in (0, 90]; box rigs: the half-angle of their cap part, used
        only when ``cap_share > 0``), ``kind`` (``"cap"``, the paper's rig, or ``"box"``, box-targeted,
        docs/box-rig.md), ``scale``, ``targets`` and ``cap_share`` (box rigs only: target scale s in
        (0, 1], target set of ``BOX_TARGETS``, share of each viewpoint's rays on the cap in [0, 1);
        defaults ``BOX_DEFAULTS``) read through to it.
    box : box rigs only: (3,) box half-extents ``e`` in the unit frame (``size / 2R``),
        a tuple of floats.

    Cap rigs have ``box`` and the three box parameters ``None``. The ray arrays are computed once
    and cached; they are float64, unit frame.
    """

    spec: RigSpec
    box: tuple | None = None

    def __init__(
        self,
        n_primary: int = 32,
        n_secondary: int = 64,
        angle: float = 60.0,
        kind: str = "cap",
        box: tuple | None = None,
        scale: float | None = None,
        targets: str | None = None,
        cap_share: float | None = None,
    ):
        spec = RigSpec(n_primary, n_secondary, angle, kind, scale, targets, cap_share)  # validates, fills defaults
        object.__setattr__(self, "spec", spec)
        object.__setattr__(self, "box", _checked_box(spec, box))

    @classmethod
    def from_spec(cls, spec: RigSpec, box=None) -> Rig:
        """The rig of ``spec`` for the box of half-extents ``box`` (3,) in the unit frame (box rigs; cap rigs:
        None). :meth:`RigSpec.for_box` is the cached form of this."""
        if not isinstance(spec, RigSpec):
            raise ParameterError(f"Rig.from_spec needs a RigSpec, got {type(spec).__name__}")
        rig = object.__new__(cls)
        object.__setattr__(rig, "spec", spec)
        object.__setattr__(rig, "box", _checked_box(spec, box))
        return rig

    @property
    def n_primary(self) -> int:
        """N, number of viewpoints (the spec's)."""
        return self.spec.n_primary

    @property
    def n_secondary(self) -> int:
        """M, rays per viewpoint (the spec's)."""
        return self.spec.n_secondary

    @property
    def angle(self) -> float:
        """Cap half-angle omega in degrees (the spec's)."""
        return self.spec.angle

    @property
    def kind(self) -> str:
        """``"cap"`` or ``"box"`` (the spec's)."""
        return self.spec.kind

    @property
    def scale(self) -> float | None:
        """Box rigs: the target scale s (the spec's); cap rigs: None."""
        return self.spec.scale

    @property
    def targets(self) -> str | None:
        """Box rigs: the target set (the spec's); cap rigs: None."""
        return self.spec.targets

    @property
    def cap_share(self) -> float | None:
        """Box rigs: the share of rays on the cap (the spec's); cap rigs: None."""
        return self.spec.cap_share

    @property
    def n_rays(self) -> int:
        """N * M."""
        return self.spec.n_rays

    @property
    def name(self) -> str:
        """A stable identifier such as ``"cap-32x64-60"`` or ``"box-32x64-visible-s0.9"``.

        A box rig's name is its spec's (:attr:`RigSpec.name`): it names the rule, not
        the box, so rigs of one spec for different boxes share it.
        """
        return self.spec.name

    @property
    def extents(self) -> np.ndarray | None:
        """(3,) float64 box half-extents (unit frame) of a box rig, else None."""
        return None if self.box is None else np.array(self.box, dtype=np.float64)

    @property
    def small_sphere_radius(self) -> float:
        """The paper's small-sphere radius r / R = 2 cos(omega)."""
        return 2.0 * math.cos(math.radians(self.angle))

    @cached_property
    def primary(self) -> np.ndarray:
        """(N, 3) float64 viewpoint positions on the unit sphere."""
        return _readonly(fibonacci_sphere(self.n_primary))

    @cached_property
    def frames(self) -> np.ndarray:
        """(N, 3, 3) float64 local frames, rows ``u, v, w`` (``w`` toward the centre)."""
        return _readonly(viewpoint_frames(self.primary))

    @cached_property
    def origins(self) -> np.ndarray:
        """(N*M, 3) float64 ray origins: row ``i*M + k`` is ``p_i``."""
        return _readonly(np.repeat(self.primary, self.n_secondary, axis=0))

    @cached_property
    def directions(self) -> np.ndarray:
        """(N*M, 3) float64 unit ray directions: row ``i*M + k`` is sample k of viewpoint i."""
        if self.kind == "box":
            d = box_directions(
                self.primary, self.n_secondary, self.extents, self.scale, self.targets, self.cap_share, self.angle
            )
            return _readonly(np.ascontiguousarray(d))
        return _readonly(cap_ray_directions(self.primary, self.n_secondary, self.angle).reshape(-1, 3))

    @property
    def secondary(self) -> np.ndarray:
        """(N*M, 3) float64 secondary points ``P2 = P1 + r d`` on the small sphere (r = 2 cos omega; cap rigs)."""
        return self.origins + self.small_sphere_radius * self.directions

    @cached_property
    def chord_lengths(self) -> np.ndarray:
        """(N*M,) float64 length of each ray's chord inside the unit sphere (``-2 o.d``)."""
        return _readonly(np.clip(-2.0 * np.einsum("ij,ij->i", self.origins, self.directions), 0.0, 2.0))

    @cached_property
    def half_chords32(self) -> np.ndarray:
        """(N*M,) float32 half chord lengths (+ 5e-7 float32 slack): the largest valid depth per ray."""
        return _readonly((self.chord_lengths / 2.0 + 5e-7).astype(np.float32))

    @cached_property
    def rays32(self) -> tuple[np.ndarray, np.ndarray]:
        """``(origins, directions)`` as C-contiguous float32 (N*M, 3) arrays, for ray engines."""
        return _readonly(self.origins.astype(np.float32)), _readonly(self.directions.astype(np.float32))

    def to_dict(self) -> dict:
        """JSON-serialisable description; ``Rig.from_dict`` rebuilds the identical rig.

        Cap rigs: ``{"kind", "n_primary", "n_secondary", "angle"}``; box rigs add
        ``"box"`` (3 floats), ``"scale"``, ``"targets"`` and ``"cap_share"``.
        """
        d = self.spec.to_dict()
        if self.box is not None:
            d["box"] = list(self.box)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Rig:
        """Rebuild a rig from :meth:`to_dict` output (either kind)."""
        spec = RigSpec.from_dict(d)
        if spec.needs_box and d.get("box") is None:
            raise ParameterError(
                f"rig description {d!r} has no box: it is a RigSpec (RigSpec.from_dict(d).for_box(extents))"
            )
        return spec.for_box(d.get("box"))


@dataclass(frozen=True)
class RigSpec:
    """A rig's box-independent description; ``for_box(extents)`` gives the concrete :class:`Rig`.

    Same fields as :class:`Rig` without ``box``. A cap spec's rig does not depend on
    the box (``for_box`` accepts ``None``); a box spec's rig does. This is what a
    dataset, a model or a command line holds; each object's encoding stores the
    concrete rig (``Rig.to_dict()`` carries the box), so it always decodes alone.

    Per-object rigs (datasets with one box per model, models predicting per-sample
    depths): ``spec.for_box(e)`` is cached by the exact extents (the last 64
    boxes); for a batch, :meth:`directions_for_boxes` gives every sample's rays in
    one vectorised call, and :attr:`origins` are shared by all boxes.
    """

    n_primary: int = 32
    n_secondary: int = 64
    angle: float = 60.0
    kind: str = "cap"
    scale: float | None = None
    targets: str | None = None
    cap_share: float | None = None

    def __post_init__(self):
        if self.kind not in RIG_KINDS:
            raise ParameterError(f"unknown rig kind {self.kind!r}; known: {', '.join(RIG_KINDS)}")
        object.__setattr__(self, "n_primary", check_count(self.n_primary, "number of primary viewpoints N"))
        object.__setattr__(self, "n_secondary", check_count(self.n_secondary, "number of secondary rays M"))
        if self.n_primary * self.n_secondary > MAX_RAYS:
            raise ParameterError(
                f"N * M = {self.n_primary * self.n_secondary:,} rays is more than the {MAX_RAYS:,} "
                "one rig may hold (its arrays alone would need > 1 GB)"
            )
        object.__setattr__(self, "angle", float(check_angle(self.angle)))
        for key, value in _check_box_params(self.kind, self.scale, self.targets, self.cap_share).items():
            object.__setattr__(self, key, value)

    @property
    def needs_box(self) -> bool:
        """True when the rays depend on the object's box (box rigs)."""
        return self.kind == "box"

    @property
    def n_rays(self) -> int:
        """N * M."""
        return self.n_primary * self.n_secondary

    @property
    def name(self) -> str:
        """``"cap-32x64-60"``; box specs ``"box-32x64-visible-s0.9"`` (+ ``"-cap0.25@60"`` when mixed)."""
        if self.kind == "cap":
            return f"cap-{self.n_primary}x{self.n_secondary}-{self.angle:g}"
        name = f"box-{self.n_primary}x{self.n_secondary}-{self.targets}-s{self.scale:g}"
        return name + (f"-cap{self.cap_share:g}@{self.angle:g}" if self.cap_share else "")

    @classmethod
    def from_name(cls, name: str) -> RigSpec:
        """Parse :attr:`name` (``"cap-32x64-60"``, ``"box-32x64-ellipsoid-s1"``, ``"box-32x64-volume-s0.8-cap0.25@60"``).

        Names print numbers with 6 significant digits, so only such parameters round-trip
        exactly (``to_dict`` always does).
        """
        s = str(name).strip().lower()
        m = re.fullmatch(r"cap-(\d+)x(\d+)-([0-9.]+)", s)
        if m:
            return cls(int(m.group(1)), int(m.group(2)), float(m.group(3)))
        m = re.fullmatch(r"box-(\d+)x(\d+)-([a-z]+)-s([0-9.]+)(?:-cap([0-9.]+)@([0-9.]+))?", s)
        if m:
            return cls(
                int(m.group(1)),
                int(m.group(2)),
                float(m.group(6) or 60.0),
                "box",
                float(m.group(4)),
                m.group(3),
                float(m.group(5) or 0.0),
            )
        raise ParameterError(f"rig name {name!r} not understood; e.g. cap-32x64-60 or box-32x64-visible-s0.9")

    @property
    def origins(self) -> np.ndarray:
        """(N*M, 3) float64 ray origins, the same for every box (read-only)."""
        return _spec_rig(RigSpec(self.n_primary, self.n_secondary, self.angle), None).origins

    def for_box(self, extents=None) -> Rig:
        """The concrete rig for a box of half-extents ``extents`` (3,) in the unit frame (``size / 2R``).

        Cap specs ignore ``extents`` (may be None). Results are cached by the exact
        extents, so repeated calls for one object are free.
        """
        if not self.needs_box:
            return _spec_rig(self, None)
        if extents is None:
            raise ParameterError(f"rig {self.name} is aimed at the object's box: give its half-extents")
        return _spec_rig(self, check_extents(extents))

    def for_normalization(self, normalization) -> Rig:
        """The concrete rig for an object normalised by ``normalization`` (its box: ``size / 2R``)."""
        if not self.needs_box:
            return self.for_box(None)
        return self.for_box(extents_from_normalization(normalization))

    def directions_for_boxes(self, extents: np.ndarray) -> np.ndarray:
        """Ray directions for a batch of boxes, vectorised (no per-box rig objects).

        Parameters
        ----------
        extents : (B, 3) float box half-extents, unit frame (ignored by cap specs,
            whose directions are broadcast).

        Returns
        -------
        (B, N*M, 3) float64 unit vectors; row b equals ``for_box(extents[b]).directions``.
        """
        e = np.asarray(extents, dtype=np.float64).reshape(-1, 3)
        if not self.needs_box:
            return np.broadcast_to(self.for_box(None).directions, (len(e), self.n_rays, 3))
        check_extents(e)
        return box_directions(
            fibonacci_sphere(self.n_primary), self.n_secondary, e, self.scale, self.targets, self.cap_share, self.angle
        )

    def to_dict(self) -> dict:
        """JSON-serialisable description (cap specs: exactly a cap rig's ``to_dict()``)."""
        d = {"kind": self.kind, "n_primary": self.n_primary, "n_secondary": self.n_secondary, "angle": self.angle}
        if self.kind == "box":
            d.update(scale=self.scale, targets=self.targets, cap_share=self.cap_share)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> RigSpec:
        """Rebuild from :meth:`to_dict` output; a rig's ``to_dict()`` also works (its box is dropped)."""
        try:
            return cls(
                int(d["n_primary"]),
                int(d["n_secondary"]),
                float(d["angle"]),
                str(d.get("kind", "cap")),
                _opt(float, d.get("scale")),
                _opt(str, d.get("targets")),
                _opt(float, d.get("cap_share")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ParameterError(f"invalid rig description {d!r}: {exc}") from None


@lru_cache(maxsize=64)
def _spec_rig(spec: RigSpec, box: tuple | None) -> Rig:
    return Rig.from_spec(spec, box)


def _checked_box(spec: RigSpec, box) -> tuple | None:
    """A rig's box: validated half-extents (a tuple of 3 floats) for box specs, None for cap specs."""
    if spec.kind == "box":
        if box is None:
            raise ParameterError(
                "a box rig needs the box half-extents (box=...); a description without a box is a "
                "RigSpec: RigSpec.from_dict(d).for_box(extents)"
            )
        return check_extents(box)
    if box is not None:
        raise ParameterError("box half-extents are only for box rigs (kind='box')")
    return None


def check_extents(extents) -> tuple:
    """Validate box half-extents (unit frame): 3 finite values >= 0, not all 0, norm <= 1 (+1e-6).

    ``extents`` is (3,) or a batch (B, 3) (every row checked). Returns the (3,) input
    as a tuple of 3 Python floats (the form :class:`Rig` stores), a batch as a
    tuple of such tuples.
    """
    try:
        e = np.asarray(extents, dtype=np.float64)
        rows = e.reshape(-1, 3) if e.ndim == 2 else e.reshape(1, 3)
    except (TypeError, ValueError):
        raise ParameterError(f"box half-extents must be 3 numbers (or rows of 3), got {extents!r}") from None
    bad = ~np.all(np.isfinite(rows), axis=1) | np.any(rows < 0, axis=1) | ~np.any(rows > 0, axis=1)
    if np.any(bad):
        raise ParameterError(
            f"box half-extents must be finite, >= 0 and not all 0, got {rows[np.argmax(bad)].tolist()}"
        )
    norm = np.linalg.norm(rows, axis=1)
    if np.any(norm > 1.0 + 1e-6):
        j = int(np.argmax(norm))
        raise ParameterError(
            f"box half-extents {rows[j].tolist()} reach outside the unit sphere (norm {norm[j]:.6g} > 1)"
        )
    out = tuple(tuple(float(x) for x in row) for row in rows)
    return out if e.ndim == 2 else out[0]


def extents_from_normalization(normalization) -> np.ndarray:
    """(3,) float64 box half-extents in the unit frame, ``size / (2 R)``, of a :class:`Normalization`."""
    size = getattr(normalization, "size", None)
    if size is None:
        raise ParameterError("this normalisation has no box size; a box rig needs the object's box")
    return unit_extents(size, float(normalization.radius))


def make_rig(
    primary: int = 32,
    secondary: int = 64,
    angle: float | None = 60.0,
    radius: float | None = None,
    *,
    kind: str = "cap",
    box=None,
    scale: float | None = None,
    targets: str | None = None,
    cap_share: float | None = None,
) -> Rig:
    """Build a rig: the paper's cap rig by default, a box-targeted rig with ``kind="box"``.

    Parameters
    ----------
    primary : N viewpoints (paper: 32).
    secondary : M rays per viewpoint (paper: 64).
    angle : cap half-angle omega in degrees, in (0, 90] (paper: 60).
    radius : alternatively the small-sphere radius r / R; ``omega = arccos(r / 2R)``
        (the paper's r = R/4 gives 82.82 degrees). Overrides ``angle`` when given.
    kind : ``"cap"`` or ``"box"``.
    box : box rigs: (3,) box half-extents in the unit frame (required).
    scale, targets, cap_share : box rigs: see :class:`Rig` (defaults ``BOX_DEFAULTS``).
    """
    return make_rig_spec(
        primary, secondary, angle, radius, kind=kind, scale=scale, targets=targets, cap_share=cap_share
    ).for_box(box)


def make_rig_spec(
    primary: int = 32,
    secondary: int = 64,
    angle: float | None = 60.0,
    radius: float | None = None,
    *,
    kind: str = "cap",
    scale: float | None = None,
    targets: str | None = None,
    cap_share: float | None = None,
) -> RigSpec:
    """Build a :class:`RigSpec` (same parameters as :func:`make_rig`, without the box)."""
    if radius is not None:
        angle = angle_from_radius(float(radius))
    if angle is None:
        raise ParameterError("give the cap angle or the small-sphere radius")
    return RigSpec(primary, secondary, angle, kind, scale, targets, cap_share)


def parse_rig(spec: str | Rig | RigSpec) -> Rig | RigSpec:
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
    m = re.fullmatch(r"(\d+)x(\d+)(?:@(\d+(?:\.\d*)?|\.\d+))?", s) or re.fullmatch(
        r"cap-(\d+)x(\d+)-(\d+(?:\.\d*)?)", s
    )
    if not m:
        raise ParameterError(
            f"rig {spec!r} not understood; write NxM or NxM@DEG, e.g. 64x32@60 (N viewpoints, "
            "M rays each, cap half-angle in degrees, default 60), or a rig name such as "
            "cap-32x64-60 or box-32x64-ellipsoid-s1 (box-targeted, docs/box-rig.md)"
        )
    return make_rig(int(m.group(1)), int(m.group(2)), angle=float(m.group(3)) if m.group(3) else 60.0)


def _check_box_params(kind: str, scale, targets, cap_share) -> dict:
    """Validated box parameters (defaults filled in) for box kinds; all None for cap kinds."""
    if kind != "box":
        if any(v is not None for v in (scale, targets, cap_share)):
            raise ParameterError("scale, targets and cap_share are only for box rigs (kind='box')")
        return {"scale": None, "targets": None, "cap_share": None}
    scale = BOX_DEFAULTS["scale"] if scale is None else scale
    targets = BOX_DEFAULTS["targets"] if targets is None else targets
    cap_share = BOX_DEFAULTS["cap_share"] if cap_share is None else cap_share
    try:
        scale, cap_share = float(scale), float(cap_share)
    except (TypeError, ValueError):
        raise ParameterError(f"box scale and cap share must be numbers, got {scale!r}, {cap_share!r}") from None
    if not (0.0 < scale <= 1.0):
        raise ParameterError(f"box target scale must be in (0, 1], got {scale!r}")
    if targets not in BOX_TARGETS:
        raise ParameterError(f"unknown box target set {targets!r}; known: {', '.join(BOX_TARGETS)}")
    if not (0.0 <= cap_share < 1.0):
        raise ParameterError(f"cap share must be in [0, 1), got {cap_share!r}")
    return {"scale": scale, "targets": str(targets), "cap_share": cap_share}


def _opt(cast, value):
    return None if value is None else cast(value)


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a
