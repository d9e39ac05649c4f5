"""Procedural vehicle meshes: parametric bodies for every vehicle class a real frame holds.

A source of *variety* for the completion dataset, not of beauty (docs/dataset.md, "Procedural
vehicles"): sedans, hatchbacks, SUVs, pickups (with an open cargo bed), vans, box trucks,
semi-tractors, box and flatbed trailers (semi-trailers, and drawbar trailers below 9 m), buses and
articulated trucks (a semi-tractor coupled to a box semi-trailer), each with wheels in wheel arches
and, where the body has one, a narrower greenhouse (cabin) on top of the beltline.

Construction
------------
Every vehicle is a few disjoint closed components, concatenated (no boolean operations, so no
extra dependency and no interior faces):

* **lofted bodies** (car bodies, cabs, buses): cross-sections at stations along the length, each
  a convex hexagon in the y-z plane (floor corners at the full width, beltline corners at the
  full width, roof corners at the greenhouse width), joined by quads and closed by fans at both
  ends. The side profile (roof line, hood, windscreen, rear window, tail) is a piecewise-linear
  function of the distance from the front; the floor rises over every wheel into a **wheel
  arch**: a circular tunnel of radius ``wheel radius + 4 cm`` over the full width, so the
  wheel stands inside it without touching the body.
* **boxes** (cargo boxes, trailer bodies, frames, pickup bed walls, landing legs, fifth wheels);
  a drawbar trailer's A-frame drawbar is one solid trapezoidal slab (0.2 m wide at the eye).
* **wheels**: 16-sided cylinders along y, tyre bottoms on the ground, inside the body's width.

Components are separated by gaps (1-10 cm), so the concatenation is watertight (every edge in
exactly two faces), consistently wound with outward normals (each component's winding is set by
its signed volume) and of positive volume.

Frame: the object frame of the project (x forward, y left, z up, metres), origin at the centre
of the mesh's axis-aligned box, like the ApolloScape meshes. The box is exactly
(length, width, height) of the drawn parameters.

Dimension ranges (metres; :data:`DIMENSIONS`)
---------------------------------------------
Legal limits: EU Directive (EU) 2015/719 amending Council Directive 96/53/EC, Annex I: width
<= 2.55 m (2.60 m for refrigerated bodies), height 4.00 m, motor vehicle (rigid truck) 12.00 m,
trailer 12.00 m, articulated vehicle 16.50 m, road train 18.75 m (Annex I 1.1), a
semi-trailer's kingpin-to-rear 12.00 m (13.6 m bodies), a two-axle bus 13.50 m, a three-axle bus
15.00 m; US: 23 CFR 658.15 width 102 in (2.59 m), 53 ft (16.15 m) semi-trailers in most states,
heights set by states, mostly 13 ft 6 in (4.11 m). Here widths stay <= 2.55 m and heights <=
4.1 m. Typical published dimensions (manufacturers' data sheets), body width without mirrors:

============== ========== =========== =========== =========== ============ =================================
body            length     width       height      wheelbase   clearance    from
============== ========== =========== =========== =========== ============ =================================
sedan           4.2-5.2    1.70-1.95   1.38-1.55   2.6-3.1     0.12-0.17    Toyota Corolla 4.63 x 1.78 x 1.44
                                                                            (wb 2.70), BMW 5 4.96 x 1.87 x
                                                                            1.48 (2.98), Mercedes S 5.18 x
                                                                            1.95 x 1.50 (3.11)
hatchback       3.6-4.45   1.63-1.82   1.42-1.56   2.35-2.7    0.12-0.16    Fiat Panda 3.65 x 1.64 x 1.55
                                                                            (2.30), VW Polo 4.05 x 1.75 x
                                                                            1.46 (2.55), Golf 4.28 x 1.79 x
                                                                            1.46 (2.64)
suv             4.2-5.4    1.78-2.06   1.60-1.95   2.55-3.1    0.18-0.25    RAV4 4.60 x 1.86 x 1.69 (2.69),
                                                                            Touareg 4.88 x 1.98 x 1.72
                                                                            (2.90), Tahoe 5.35 x 2.06 x 1.93
                                                                            (3.07)
pickup          5.0-6.2    1.80-2.10   1.75-2.00   3.0-3.9     0.21-0.28    Hilux 5.33 x 1.86 x 1.82 (3.09),
                                                                            F-150 SuperCrew 5.89 x 2.03 x
                                                                            1.96 (3.68), Ram 1500 5.82-6.14
van             4.8-7.0    1.90-2.05   1.90-2.80   3.0-4.3     0.15-0.20    VW Transporter 4.90 x 1.90 x
                                                                            1.99 (3.00), Ford Transit 5.53-
                                                                            6.70 x 2.06 (body 2.05) x 2.06-
                                                                            2.78, Sprinter 5.27-7.37 x 2.02
                                                                            x 2.36-2.83 (3.26-4.33)
box_truck       6.5-12.0   2.30-2.55   3.00-4.00   3.4-6.8     0.25-0.35    7.5-18 t rigid trucks (MAN TGL /
                                                                            TGM, Isuzu N/F series): bodies
                                                                            6-8.5 m, legal width/height caps;
                                                                            from 10 m 3-axle rigids (26 t
                                                                            6x2/6x4, rear tandem 1.35 m,
                                                                            wheelbase to ~6.5-7 m) up to the
                                                                            EU rigid maximum 12.00 m (96/53/EC
                                                                            Annex I 1.1; US straight trucks
                                                                            similar)
semi_tractor    5.8-7.5    2.45-2.55   3.20-4.00   3.6-5.0     0.25-0.35    EU cab-over 4x2 (Volvo FH, MAN
                                                                            TGX: ~6.0 x 2.50 x 3.5-4.0, wb
                                                                            3.6-3.9), US conventional 6x4
                                                                            (~7 m, wb 4.5-5.8)
trailer_box     5.0-16.2   2.45-2.55   3.60-4.10   (axles)     floor 1.1-   EU 13.6 m semi-trailer, US 48-53
                                                                1.3         ft (14.6-16.15 m), 13 ft 6 in; below
                                                                            9 m drawbar trailers: EU centre-axle
                                                                            trailers behind rigid trucks 7-8.5
                                                                            m, US enclosed cargo trailers 16-28
                                                                            ft (4.9-8.5 m); drawbar included
trailer_flatbed 5.0-16.2   2.45-2.55   1.40-1.70   (axles)     deck top     US flatbed deck ~60 in (1.52 m);
                                                                            below 9 m as the box trailers
bus             9.0-13.7   2.45-2.55   2.90-3.60   4.5-7.0     0.25-0.35    city buses 12.0 x 2.55 x 3.0-3.3
                                                                            (Citaro wb 5.85), coaches 12-
                                                                            13.7 x 2.55 x 3.5-3.9; 40/45 ft
articulated_   13.5-18.75 2.45-2.55   3.60-4.10   3.6-5.0     0.25-0.35    EU articulated vehicle 16.50 m
truck                                             (tractor)   (tractor)    (96/53/EC Annex I 1.1); above it US
                                                                            tractors with 48-53 ft semi-
                                                                            trailers (19-22 m overall: no US
                                                                            federal overall limit, 23 CFR
                                                                            658.13), capped at 18.75 m; a
                                                                            semi_tractor 5.8-7.5 m (at most
                                                                            5.8 + L - 13.5) and a box semi-
                                                                            trailer (the rest, 9.7-15.8 m),
                                                                            kingpin 0.9-1.7 m behind its front
                                                                            (EU swing radius <= 2.04 m)
============== ========== =========== =========== =========== ============ =================================

Detector classes (:data:`~spotlights.data.vehicle_classes.CLASS_BODIES`, the real readers' names):
``car`` = sedan, hatchback, SUV, pickup; ``caravan`` (vans; ``van`` is accepted) = van; ``truck`` =
box truck, semi-tractor, pickup, articulated truck; ``bus`` = bus; ``trailer`` = box and flatbed trailers. Pickups are
in both car and truck: datasets disagree (nuScenes labels pickups ``vehicle.truck``; Argoverse 2
``REGULAR_VEHICLE``, KITTI ``Car``).
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass

import numpy as np

from ...errors import ParameterError
from ..vehicle_classes import CATEGORY_CLASS, CLASS_BODIES, VEHICLE_CLASSES, class_of_category

__all__ = [
    "BODY_TYPES",
    "CATEGORY_CLASS",
    "CLASS_BODIES",
    "DIMENSIONS",
    "VEHICLE_CLASSES",
    "VehicleParams",
    "class_of_category",
    "draw_params",
    "generate_vehicle",
    "generate_trimesh",
    "mesh_digest",
    "vehicle_arrays",
]

BODY_TYPES = (
    "sedan",
    "hatchback",
    "suv",
    "pickup",
    "van",
    "box_truck",
    "semi_tractor",
    "trailer_box",
    "trailer_flatbed",
    "bus",
    "articulated_truck",
)

#: per body type: (min, max) of length, width, height, wheelbase, ground clearance (metres);
#: trailers: wheelbase unused, clearance = floor height (box) or deck thickness (flatbed)
DIMENSIONS = {
    "sedan": {"length": (4.2, 5.2), "width": (1.70, 1.95), "height": (1.38, 1.55), "wheelbase": (2.6, 3.1), "clearance": (0.12, 0.17)},
    "hatchback": {"length": (3.6, 4.45), "width": (1.63, 1.82), "height": (1.42, 1.56), "wheelbase": (2.35, 2.7), "clearance": (0.12, 0.16)},
    "suv": {"length": (4.2, 5.4), "width": (1.78, 2.06), "height": (1.60, 1.95), "wheelbase": (2.55, 3.1), "clearance": (0.18, 0.25)},
    "pickup": {"length": (5.0, 6.2), "width": (1.80, 2.10), "height": (1.75, 2.00), "wheelbase": (3.0, 3.9), "clearance": (0.21, 0.28)},
    "van": {"length": (4.8, 7.0), "width": (1.90, 2.05), "height": (1.90, 2.80), "wheelbase": (3.0, 4.3), "clearance": (0.15, 0.20)},
    "box_truck": {"length": (6.5, 12.0), "width": (2.30, 2.55), "height": (3.00, 4.00), "wheelbase": (3.4, 6.8), "clearance": (0.25, 0.35)},
    "semi_tractor": {"length": (5.8, 7.5), "width": (2.45, 2.55), "height": (3.20, 4.00), "wheelbase": (3.6, 5.0), "clearance": (0.25, 0.35)},
    "trailer_box": {"length": (5.0, 16.2), "width": (2.45, 2.55), "height": (3.60, 4.10), "wheelbase": (0.0, 0.0), "clearance": (1.10, 1.30)},
    "trailer_flatbed": {"length": (5.0, 16.2), "width": (2.45, 2.55), "height": (1.40, 1.70), "wheelbase": (0.0, 0.0), "clearance": (0.15, 0.22)},
    "bus": {"length": (9.0, 13.7), "width": (2.45, 2.55), "height": (2.90, 3.60), "wheelbase": (4.5, 7.0), "clearance": (0.25, 0.35)},
    "articulated_truck": {"length": (13.5, 18.75), "width": (2.45, 2.55), "height": (3.60, 4.10), "wheelbase": (3.6, 5.0), "clearance": (0.25, 0.35)},
}  # fmt: skip

#: wheel radius range per body type (m): passenger tyres 0.30-0.42, truck and bus 22.5 in rims 0.48-0.53
WHEEL_RADIUS = {
    "sedan": (0.30, 0.34),
    "hatchback": (0.29, 0.32),
    "suv": (0.34, 0.40),
    "pickup": (0.37, 0.42),
    "van": (0.33, 0.37),
    "box_truck": (0.45, 0.52),
    "semi_tractor": (0.49, 0.53),
    "trailer_box": (0.45, 0.52),
    "trailer_flatbed": (0.45, 0.52),
    "bus": (0.49, 0.53),
    "articulated_truck": (0.49, 0.53),
}
#: wheelbase / length range per body type (cars 0.55-0.66: Golf 0.62, BMW 5 0.60; buses ~0.49)
WHEELBASE_RATIO = {
    "sedan": (0.56, 0.63),
    "hatchback": (0.59, 0.67),
    "suv": (0.56, 0.63),
    "pickup": (0.55, 0.65),
    "van": (0.55, 0.63),
    "box_truck": (0.48, 0.62),
    "semi_tractor": (0.55, 0.68),
    "bus": (0.45, 0.56),
}
#: smallest front and rear overhang per body type (m): room for the wheel arch and a bumper
OVERHANG_MIN = {
    "sedan": (0.75, 0.75),
    "hatchback": (0.65, 0.55),
    "suv": (0.75, 0.70),
    "pickup": (0.80, 0.90),
    "van": (0.70, 0.60),
    "box_truck": (1.10, 1.00),
    "semi_tractor": (1.20, 0.80),
    "bus": (2.30, 2.20),
}
#: the share of the length left over that goes to the front overhang
FRONT_SHARE = {"sedan": 0.45, "hatchback": 0.5, "suv": 0.45, "pickup": 0.4, "van": 0.4, "box_truck": 0.1, "semi_tractor": 0.1, "bus": 0.25}  # fmt: skip
TANDEM_MIN_LENGTH = 6.8  # semi-tractors at least this long get a tandem rear axle (6x4)
TANDEM_SPACING = 1.35  # m between the two rear axles of a tandem
BOX_TANDEM_MIN_LENGTH = 10.0  # box trucks at least this long are 3-axle rigids (6x2/6x4: a rear tandem)
DRAWBAR_MAX_LENGTH = 9.0  # trailers shorter than this are drawbar / centre-axle trailers (A-frame drawbar)
DRAWBAR_TANDEM_MIN_LENGTH = 6.5  # drawbar trailers at least this long have two axles (else one)
DRAWBAR_AXLE_SPACING = 1.1  # m between the two axles of a drawbar trailer
ARCH_GAP = 0.04  # wheel arch radius = wheel radius + this (m)
WHEEL_SECTIONS = 16


@dataclass(frozen=True)
class VehicleParams:
    """The drawn parameters of one procedural vehicle (metres; ``variant`` picks a sub-shape:
    semi-tractor 0 cab-over / 1 conventional; box truck 0 cab-over / 1 short hood). An articulated
    truck's wheelbase, front overhang, clearance, wheel radius and variant are its tractor's, and its
    ``shape`` has 9 fractions (the last three: tractor length, kingpin setback, tractor height)."""

    body: str
    length: float
    width: float
    height: float
    wheelbase: float
    clearance: float
    wheel_radius: float
    front_overhang: float
    variant: int
    shape: tuple  # body-specific shape fractions in [0, 1], drawn uniformly

    def to_dict(self) -> dict:
        """JSON-serialisable dict of the parameters."""
        return asdict(self)


def check_body(body: str) -> str:
    """``body`` if it is one of :data:`BODY_TYPES`, else a ParameterError naming them."""
    if body not in DIMENSIONS:
        raise ParameterError(f"unknown vehicle body {body!r}; known: {', '.join(BODY_TYPES)}")
    return body


def _rng(seed) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    return np.random.default_rng(seed)


def draw_params(body: str, seed) -> VehicleParams:
    """Draw the parameters of one vehicle of ``body`` (:data:`BODY_TYPES`) from ``seed`` (an int,
    a SeedSequence or a Generator). Length, width, height and clearance are uniform in their
    :data:`DIMENSIONS` ranges, the wheel radius in :data:`WHEEL_RADIUS`; the wheelbase is uniform
    in its range intersected with :data:`WHEELBASE_RATIO` times the length and with what leaves
    both overhangs room (:data:`OVERHANG_MIN`); the spare length goes to the front overhang by
    the body's share (:data:`FRONT_SHARE`). Deterministic in ``seed``."""
    d = DIMENSIONS[check_body(body)]
    rng = _rng(seed)
    u = lambda key: float(rng.uniform(*d[key]))  # noqa: E731
    length, width, height = u("length"), u("width"), u("height")
    clearance = u("clearance")
    r = float(rng.uniform(*WHEEL_RADIUS[body]))
    shape = tuple(float(x) for x in rng.uniform(0.0, 1.0, size=6))
    variant = int(rng.integers(0, 2))
    x = float(rng.uniform())
    if body in ("trailer_box", "trailer_flatbed"):
        return VehicleParams(body, length, width, height, 0.0, clearance, r, 0.0, variant, shape)
    if body == "articulated_truck":
        # the tractor's: shape[6] its length, shape[7] the kingpin setback, shape[8] its height
        shape = shape + tuple(float(x) for x in rng.uniform(0.0, 1.0, size=3))
        variant = int(_tractor_length(length, shape[6]) >= TANDEM_MIN_LENGTH)
        wheelbase, front = _wheelbase_front("semi_tractor", _tractor_length(length, shape[6]), r, variant, x, shape[5])
        return VehicleParams(body, length, width, height, wheelbase, clearance, r, front, variant, shape)
    if body == "semi_tractor":
        variant = int(length >= TANDEM_MIN_LENGTH)  # long tractors: US conventional 6x4, else EU cab-over 4x2
    wheelbase, front = _wheelbase_front(body, length, r, variant, x, shape[5])
    return VehicleParams(body, length, width, height, wheelbase, clearance, r, front, variant, shape)


def _wheelbase_front(body: str, length: float, r: float, variant: int, x: float, f5: float) -> tuple[float, float]:
    """(wheelbase, front overhang) of a body of ``length`` with wheel radius ``r``: the wheelbase at
    fraction ``x`` of its allowed range (:func:`draw_params`), the front overhang from ``f5``."""
    d = DIMENSIONS[body]
    fm, rm = OVERHANG_MIN[body]
    if (body == "semi_tractor" and variant) or (body == "box_truck" and length >= BOX_TANDEM_MIN_LENGTH):
        rm = TANDEM_SPACING + r + 0.1
    a, b = WHEELBASE_RATIO[body]
    lo = max(d["wheelbase"][0], a * length)
    hi = min(d["wheelbase"][1], b * length, length - fm - rm)
    if lo > hi:
        lo = hi = min(max(d["wheelbase"][0], (a + b) / 2 * length), d["wheelbase"][1], length - fm - rm)
    wheelbase = lo + (hi - lo) * x
    front = fm + (length - wheelbase - fm - rm) * FRONT_SHARE[body] * (0.8 + 0.4 * f5)
    return wheelbase, front


def _tractor_length(length: float, f: float) -> float:
    """The tractor length of an articulated truck ``length`` long, at fraction ``f`` of the semi-tractor
    range; capped at 5.8 + (length - 13.5) m so that the semi-trailer keeps >= 7.7 m behind the tractor."""
    lo, hi = DIMENSIONS["semi_tractor"]["length"]
    hi = min(hi, lo + length - DIMENSIONS["articulated_truck"]["length"][0])
    return lo + (hi - lo) * f


# ----------------------------------------------------------------------------------------------
# primitives: (vertices (V, 3) float64, faces (F, 3) int64), outward winding
# ----------------------------------------------------------------------------------------------
def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _outward(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if _signed_volume(v, f) < 0:
        f = np.ascontiguousarray(f[:, ::-1])
    return v, f


def _loft(xs: np.ndarray, sections: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A closed tube through convex cross-sections: xs (S,) stations, sections (S, K, 2) (y, z)
    vertices of a convex polygon each, the same vertex order at every station; fan caps."""
    s, k = sections.shape[:2]
    v = np.concatenate([np.column_stack([np.full(k, x), sec]) for x, sec in zip(xs, sections)])
    i = np.arange(s - 1)[:, None] * k
    j = np.arange(k)[None, :]
    a, b = i + j, i + (j + 1) % k
    c, d = b + k, a + k
    quads = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    fan = np.arange(1, k - 1)
    front = np.column_stack([np.zeros_like(fan), fan + 1, fan])
    back = (s - 1) * k + np.column_stack([np.zeros_like(fan), fan, fan + 1])
    return _outward(v, np.concatenate([quads, front, back]).astype(np.int64))


def _box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box from corner ``lo`` to ``hi`` (3,) as a loft of two rectangles."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    rect = np.array([[y0, z0], [y1, z0], [y1, z1], [y0, z1]], dtype=np.float64)
    return _loft(np.array([x0, x1], dtype=np.float64), np.stack([rect, rect]))


def _wheel(x: float, y0: float, y1: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    """A wheel: a :data:`WHEEL_SECTIONS`-gon cylinder along y from ``y0`` to ``y1``, axle at
    height ``r`` and front-back position ``x``, its lowest vertex on the ground (z = 0)."""
    t = 2 * np.pi * np.arange(WHEEL_SECTIONS) / WHEEL_SECTIONS
    ring = np.column_stack([x + r * np.cos(t), r + r * np.sin(t)])  # (x, z)
    v = np.concatenate([np.column_stack([ring[:, 0], np.full(len(t), y), ring[:, 1]]) for y in (y0, y1)])
    n = WHEEL_SECTIONS
    j = np.arange(n)
    side = np.concatenate(
        [np.column_stack([j, (j + 1) % n, (j + 1) % n + n]), np.column_stack([j, (j + 1) % n + n, j + n])]
    )
    fan = np.arange(1, n - 1)
    caps = np.concatenate(
        [np.column_stack([np.zeros_like(fan), fan + 1, fan]), n + np.column_stack([np.zeros_like(fan), fan, fan + 1])]
    )
    return _outward(v, np.concatenate([side, caps]).astype(np.int64))


def _wheel_pair(s_axle: float, p: VehicleParams, tyre: float, x_of) -> list:
    """Left and right wheels of one axle at distance ``s_axle`` from the front, ``tyre`` wide,
    their outer faces 2 cm inside the body's width."""
    y1 = p.width / 2 - 0.02
    x = x_of(s_axle)
    return [_wheel(x, y1 - tyre, y1, p.wheel_radius), _wheel(x, -y1, -y1 + tyre, p.wheel_radius)]


# ----------------------------------------------------------------------------------------------
# lofted bodies
# ----------------------------------------------------------------------------------------------
def _body(
    p: VehicleParams,
    s0: float,
    s1: float,
    top: list,
    belt: float,
    floor: list,
    axles: list,
    roof_width: float,
    x_of,
    chamfer: float = 0.04,
) -> tuple[np.ndarray, np.ndarray]:
    """A lofted body from ``s0`` to ``s1`` (distance from the front). ``top``, ``floor``: lists of
    (s, z) control points of the roof line and the floor (piecewise linear); the floor rises into
    a wheel arch over every axle of ``axles`` (s positions); ``belt`` the beltline height;
    ``roof_width`` the greenhouse width (where the roof line is 0.25 m or more above the belt)."""
    ts, tz = np.array(top, dtype=np.float64).T
    fs, fz = np.array(floor, dtype=np.float64).T
    ra = p.wheel_radius + ARCH_GAP
    stations = [np.linspace(s0, s1, max(8, int((s1 - s0) / 0.15))), ts, fs]
    for a in axles:
        stations.append(a + ra * np.cos(np.linspace(np.pi, 0, 15)))
    s = np.unique(np.clip(np.concatenate(stations), s0, s1))
    s = s[np.concatenate([[True], np.diff(s) > 1e-4])]
    zt = np.interp(s, ts, tz)
    zf = np.interp(s, fs, fz)
    for a in axles:
        inside = np.abs(s - a) < ra
        zf[inside] = np.maximum(zf[inside], p.wheel_radius + np.sqrt(ra**2 - (s[inside] - a) ** 2))
    half = p.width / 2
    zb = np.minimum(belt, zt - chamfer)
    zb = np.maximum(zb, zf + 0.02)
    zt = np.maximum(zt, zb + 0.01)
    glass = np.clip((zt - belt) / 0.25, 0.0, 1.0)
    wt = (half - chamfer) - (half - chamfer - roof_width / 2) * glass
    secs = np.stack(
        [
            np.column_stack([np.full_like(s, -half), zf]),
            np.column_stack([np.full_like(s, half), zf]),
            np.column_stack([np.full_like(s, half), zb]),
            np.column_stack([wt, zt]),
            np.column_stack([-wt, zt]),
            np.column_stack([np.full_like(s, -half), zb]),
        ],
        axis=1,
    )
    return _loft(x_of(s), secs)


def _components(p: VehicleParams) -> list:
    """The closed components of a vehicle, built with the front at s = 0 (x = L - s)."""
    L, W, H, r, cl = p.length, p.width, p.height, p.wheel_radius, p.clearance
    f = p.shape
    x_of = lambda s: L - np.asarray(s, dtype=np.float64)  # noqa: E731
    sf = p.front_overhang
    sr = sf + p.wheelbase
    arch_top = 2 * r + ARCH_GAP
    parts = []
    car_tyre = 0.19 + 0.07 * f[4]
    if p.body in ("sedan", "hatchback", "suv", "pickup", "van"):
        nose = cl + 0.30 + 0.1 * f[0]
        floor = [(0, cl + 0.18), (0.35, cl), (L - 0.45, cl), (L, cl + 0.15)]
        if p.body == "sedan":
            hood = 0.64 + 0.06 * f[1]
            belt = max(0.62 * H, arch_top + 0.08)
            top = [(0, nose), (0.06 * L, hood * H), (0.27 * L, (hood + 0.04) * H), ((0.40 + 0.04 * f[2]) * L, H),
                   ((0.62 + 0.04 * f[3]) * L, H), ((0.82 + 0.03 * f[2]) * L, 0.72 * H), (0.97 * L, 0.70 * H), (L, 0.58 * H)]  # fmt: skip
            roof = W * (0.72 + 0.06 * f[3])
        elif p.body == "hatchback":
            hood = 0.60 + 0.06 * f[1]
            belt = max(0.60 * H, arch_top + 0.08)
            top = [(0, nose), (0.06 * L, hood * H), (0.22 * L, (hood + 0.05) * H), ((0.38 + 0.04 * f[2]) * L, H),
                   ((0.86 + 0.04 * f[3]) * L, 0.97 * H), (L, (0.62 + 0.1 * f[2]) * H)]  # fmt: skip
            roof = W * (0.74 + 0.06 * f[3])
        elif p.body == "suv":
            hood = 0.62 + 0.06 * f[1]
            belt = max(0.60 * H, arch_top + 0.1)
            top = [(0, max(nose, 0.5 * H)), (0.05 * L, hood * H), (0.22 * L, (hood + 0.05) * H),
                   ((0.34 + 0.03 * f[2]) * L, H), ((0.92 + 0.03 * f[3]) * L, 0.98 * H), (L, (0.70 + 0.08 * f[2]) * H)]  # fmt: skip
            roof = W * (0.78 + 0.06 * f[3])
        elif p.body == "pickup":
            hood = 0.58 + 0.06 * f[1]
            belt = max(0.60 * H, arch_top + 0.2)
            bed_floor = max(0.48 * H, arch_top + 0.06)
            cab_back = (0.50 + 0.08 * f[2]) * L  # crew cab ... regular cab
            top = [(0, max(nose, 0.48 * H)), (0.05 * L, hood * H), (0.24 * L, (hood + 0.03) * H),
                   ((0.34 + 0.02 * f[3]) * L, H), (cab_back - 0.05, H), (cab_back, 0.96 * H),
                   (cab_back + 0.01, bed_floor), (L, bed_floor)]  # fmt: skip
            roof = W * (0.80 + 0.06 * f[3])
            t = 0.06
            z0, z1 = bed_floor + 0.01, belt
            parts += [
                _box((x_of(L - 0.01)[()], W / 2 - t, z0), (x_of(cab_back + 0.03)[()], W / 2, z1)),
                _box((x_of(L - 0.01)[()], -W / 2, z0), (x_of(cab_back + 0.03)[()], -W / 2 + t, z1)),
                _box((x_of(L)[()], -W / 2 + t + 0.01, z0), (x_of(L - t)[()], W / 2 - t - 0.01, z1 - 0.02)),
            ]
        else:  # van
            hood = 0.40 + 0.08 * f[1]
            belt = max(0.45 * H, arch_top + 0.12)
            top = [(0, max(nose, 0.35 * H)), (0.04 * L, hood * H), ((0.11 + 0.04 * f[2]) * L, (hood + 0.05) * H),
                   ((0.24 + 0.04 * f[3]) * L, 0.97 * H), ((0.30 + 0.04 * f[3]) * L, H), (L - 0.05, H), (L, 0.97 * H)]  # fmt: skip
            roof = W * (0.90 + 0.05 * f[3])
            car_tyre = 0.21 + 0.04 * f[4]
        parts.append(_body(p, 0.0, L, top, belt, floor, [sf, sr], roof, x_of))
        parts += _wheel_pair(sf, p, car_tyre, x_of) + _wheel_pair(sr, p, car_tyre, x_of)
        return parts
    if p.body == "bus":
        belt = max((0.36 + 0.06 * f[1]) * H, arch_top + 0.15)
        top = [(0, H - 0.35), (0.25, H - 0.05), (0.6, H), (L - 0.3, H), (L, H - 0.25)]
        floor = [(0, cl + 0.15), (0.3, cl), (L - 0.5, cl), (L, cl + 0.25)]
        # windscreen: the front rounds off over the top 0.35 m, the greenhouse is almost full width
        parts.append(_body(p, 0.0, L, top, belt, floor, [sf, sr], W - 0.12, x_of, chamfer=0.06))
        parts += _wheel_pair(sf, p, 0.3, x_of) + _wheel_pair(sr, p, 0.6, x_of)
        return parts
    if p.body in ("box_truck", "semi_tractor"):
        semi = p.body == "semi_tractor"
        cab_h = H if semi else min(H - 0.15, 2.6 + 0.4 * f[1])
        hooded = p.variant == 1
        cab_len = _cab_length(p)
        belt = max(cab_h * (0.50 if semi else 0.55), arch_top + 0.25)
        if hooded:
            hood_h = max(arch_top + 0.3, 0.42 * cab_h)
            top = [(0, hood_h - 0.25), (0.2, hood_h), (cab_len - 1.9, hood_h + 0.05), (cab_len - 1.5, cab_h - 0.1),
                   (cab_len - 1.2, cab_h), (cab_len, cab_h)]  # fmt: skip
        else:
            top = [(0, belt - 0.1), (0.12, belt + 0.15), (0.35, cab_h - 0.2), (0.6, cab_h), (cab_len, cab_h)]
        floor = [(0, cl + 0.1), (0.3, cl), (cab_len, cl)]
        parts.append(_body(p, 0.0, cab_len, top, belt, floor, [sf], W - 0.16, x_of, chamfer=0.05))
        frame_z = (2 * r + 0.03, 2 * r + 0.28)
        frame_from = cab_len + 0.05
        if semi:
            parts.append(_box((x_of(L)[()], -0.45, frame_z[0]), (x_of(frame_from)[()], 0.45, frame_z[1])))
            rear = _rear_axles(p)
            fw = _fifth_wheel(p)
            parts.append(
                _box((x_of(fw + 0.45)[()], -0.6, frame_z[1] + 0.01), (x_of(fw - 0.45)[()], 0.6, frame_z[1] + 0.18))
            )
            for a in rear:
                parts += _wheel_pair(a, p, 0.6, x_of)
        else:
            floor_z = frame_z[1] + 0.01
            parts.append(_box((x_of(L)[()], -0.45, frame_z[0]), (x_of(frame_from)[()], 0.45, frame_z[1])))
            parts.append(_box((x_of(L)[()], -W / 2, floor_z), (x_of(cab_len + 0.12)[()], W / 2, H)))
            for a in _rear_axles(p):
                parts += _wheel_pair(a, p, 0.6, x_of)
        parts += _wheel_pair(sf, p, 0.32, x_of)
        return parts
    if p.body == "articulated_truck":
        return _articulated(p)
    return _trailer(p, semi=L >= DRAWBAR_MAX_LENGTH)


def _rear_axles(p: VehicleParams) -> list:
    """Distances from the front of a box truck's or semi-tractor's rear axles (a tandem on 6x4
    tractors and on box trucks from :data:`BOX_TANDEM_MIN_LENGTH`)."""
    sr = p.front_overhang + p.wheelbase
    tandem = p.variant if p.body == "semi_tractor" else p.length >= BOX_TANDEM_MIN_LENGTH
    return [sr, sr + TANDEM_SPACING] if tandem else [sr]


def _fifth_wheel(p: VehicleParams) -> float:
    """Distance from the front of a semi-tractor's fifth wheel (the kingpin): 0.3 m ahead of the
    middle of the rear axle(s); its plate is 0.9 m long, its top 2 r + 0.46 m above the ground."""
    return float(np.mean(_rear_axles(p))) - 0.3


def _cab_length(p: VehicleParams) -> float:
    """Length (m) of a box truck's or semi-tractor's cab (cab-over, or hooded for ``variant`` 1)."""
    sf, sr, ra = p.front_overhang, p.front_overhang + p.wheelbase, p.wheel_radius + ARCH_GAP
    f = p.shape
    cab_len = max(2.0 + 0.4 * f[2], sf + ra + 0.3) if p.variant != 1 else sf + ra + 1.7 + 0.3 * f[2]
    return min(cab_len, sr - ra - 0.1)


def _trailer(p: VehicleParams, semi: bool, legs_from: float = 0.0) -> list:
    """The components of a trailer (front at s = 0, x = L - s). ``semi``: a semi-trailer (two axles,
    three from 11 m, near the rear; landing legs 1.6-2.4 m from the front, or ``legs_from`` + 0-0.8 m
    when that is further back); else a drawbar trailer: an A-frame drawbar (a solid trapezoid, 1.0-1.6 m
    long, 0.12 m thick, its top 0.85-1.0 m above the ground) ahead of the body, one axle (two 1.1 m
    apart from 6.5 m) 50-60% of the body's length behind its front, no landing legs."""
    L, W, H, r, cl, f = p.length, p.width, p.height, p.wheel_radius, p.clearance, p.shape
    x_of = lambda s: L - np.asarray(s, dtype=np.float64)  # noqa: E731
    arch_top = 2 * r + ARCH_GAP
    parts = []
    if semi:
        front = 0.0
        n_axles = 3 if L > 11.0 else 2
        last = L - 1.0 - 0.6 * f[1]
        axles = [last - 1.31 * k for k in range(n_axles)]
    else:
        front = 1.0 + 0.6 * f[4]  # the drawbar's length: the body starts behind it
        centre = front + (0.5 + 0.1 * f[1]) * (L - front)
        half = DRAWBAR_AXLE_SPACING / 2 if L >= DRAWBAR_TANDEM_MIN_LENGTH else 0.0
        axles = sorted({centre - half, centre + half})
    if p.body == "trailer_box":
        floor_z = max(cl, arch_top + 0.05)
        parts.append(_box((x_of(L)[()], -W / 2, floor_z), (x_of(front)[()], W / 2, H)))
        under = floor_z - 0.01
    else:
        deck = cl
        parts.append(_box((x_of(L)[()], -W / 2, H - deck), (x_of(front)[()], W / 2, H)))
        beam_top = H - deck - 0.01
        beam_bottom = max(arch_top + 0.02, beam_top - 0.35)
        parts.append(_box((x_of(L - 0.2)[()], -0.45, beam_bottom), (x_of(front + 0.2)[()], 0.45, beam_top)))
        under = beam_bottom - 0.01
    if semi:
        legs_s = max(1.6, legs_from) + 0.8 * f[2]
        for y in (0.9, -0.9):
            parts.append(_box((x_of(legs_s + 0.1)[()], y - 0.06, 0.0), (x_of(legs_s - 0.1)[()], y + 0.06, under)))
    else:
        top = 0.85 + 0.15 * f[3]
        base = min(0.6, W / 2 - 0.1)
        xs = x_of([0.0, front - 0.02])
        secs = np.array(
            [[[y0, z0] for y0, z0 in ((-h, top - 0.12), (h, top - 0.12), (h, top), (-h, top))] for h in (0.1, base)]
        )
        parts.append(_loft(xs, secs))
    for a in axles:
        parts += _wheel_pair(a, p, 0.6, x_of)
    return parts


def _articulated(p: VehicleParams) -> list:
    """An articulated truck: a semi-tractor (``p``'s wheelbase, front overhang, wheel radius and
    variant; length :func:`_tractor_length`, height 3.2 m up to the trailer's by ``shape[8]``) and a
    box semi-trailer (the rest of the length, full height) whose floor rests 2 cm above the fifth
    wheel's plate, its front 0.9-1.7 m ahead of the kingpin (``shape[7]``; less where the cab leaves
    less room: the gap behind the cab is 0.5-2.5 m, half the room if under 1 m), its landing legs behind the tractor."""
    f = p.shape
    lt = _tractor_length(p.length, f[6])
    h_lo, h_hi = DIMENSIONS["semi_tractor"]["height"]
    ht = h_lo + (min(h_hi, p.height) - h_lo) * f[8]
    tractor = VehicleParams(
        "semi_tractor", lt, p.width, ht, p.wheelbase, p.clearance, p.wheel_radius, p.front_overhang, p.variant, f[:6]
    )
    kingpin = _fifth_wheel(tractor)
    room = kingpin - _cab_length(tractor)
    front = kingpin - min(0.9 + 0.8 * f[7], room - min(0.5, room / 2))
    floor = 2 * p.wheel_radius + 0.48  # the fifth wheel's top + 0.02
    trailer = VehicleParams(
        "trailer_box", p.length - front, p.width, p.height, 0.0, floor, p.wheel_radius, 0.0, 0, f[:6]
    )
    shift = np.array([p.length - lt, 0.0, 0.0])
    parts = [(v + shift, fc) for v, fc in _components(tractor)]
    return parts + _trailer(trailer, semi=True, legs_from=lt - front + 0.4)


def vehicle_arrays(params: VehicleParams) -> tuple[np.ndarray, np.ndarray]:
    """The mesh of ``params``: vertices (V, 3) float64 in the object frame (x forward, y left,
    z up, metres, origin at the centre of the axis-aligned box) and faces (F, 3) int64, closed
    and outward-facing (module docstring)."""
    vs, fs, n = [], [], 0
    for v, f in _components(params):
        vs.append(v)
        fs.append(f + n)
        n += len(v)
    v = np.concatenate(vs)
    c = (v.min(axis=0) + v.max(axis=0)) / 2.0
    return np.ascontiguousarray(v - c), np.ascontiguousarray(np.concatenate(fs))


def generate_vehicle(body: str, seed) -> tuple[np.ndarray, np.ndarray, VehicleParams]:
    """Draw and build one vehicle: ``(vertices (V, 3) float64 metres, faces (F, 3) int64, params)``.

    body : one of :data:`BODY_TYPES`. seed : int, SeedSequence or Generator (same seed, same bytes).
    """
    p = draw_params(body, seed)
    v, f = vehicle_arrays(p)
    return v, f, p


def generate_trimesh(body: str, seed):
    """:func:`generate_vehicle` as a :class:`trimesh.Trimesh` (unprocessed: indices as built)."""
    import trimesh

    v, f, _ = generate_vehicle(body, seed)
    return trimesh.Trimesh(v, f, process=False, validate=False)


def mesh_digest(vertices: np.ndarray, faces: np.ndarray) -> str:
    """SHA-256 of a generated mesh's bytes (float64 vertices, then int64 faces): its identity."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return h.hexdigest()
