"""Body types, their published dimension ranges and the draw of one vehicle's parameters.

Dimension ranges (metres; :data:`DIMENSIONS`), drawn uniformly
----------------------------------------------------------------
Legal limits: EU Directive (EU) 2015/719 amending Council Directive 96/53/EC, Annex I: width
<= 2.55 m, height 4.00 m, motor vehicle (rigid truck) 12.00 m, trailer 12.00 m, articulated
vehicle 16.50 m, road train 18.75 m, articulated bus 18.75 m, a two-axle bus 13.50 m, a
three-axle bus 15.00 m (Annex I 1.1); US: 23 CFR 658.15 width 102 in (2.59 m), 53 ft (16.15 m)
semi-trailers in most states, no federal overall limit for tractor-semi-trailers (23 CFR
658.13; 19-22 m with a conventional tractor), heights set by states, mostly 13 ft 6 in (4.11 m).
Here widths stay <= 2.55 m, heights <= 4.1 m, lengths <= 20.0 m. Typical published dimensions
(manufacturers' data sheets; length x width without mirrors x height, wheelbase in brackets):

================= ========== =========== =========== =========== ========== ==========================================
body              length     width       height      wheelbase   clearance  from
================= ========== =========== =========== =========== ========== ==========================================
sedan             4.2-5.2    1.70-1.95   1.38-1.55   2.6-3.1     0.12-0.17  Corolla 4.63 x 1.78 x 1.44 (2.70), BMW 5
                                                                            4.96 x 1.87 x 1.48 (2.98), S-Class 5.18 x
                                                                            1.95 x 1.50 (3.11)
hatchback         3.6-4.45   1.63-1.82   1.42-1.56   2.35-2.7    0.12-0.16  Panda 3.65 x 1.64 x 1.55 (2.30), Polo 4.05
                                                                            x 1.75 x 1.46 (2.55), Golf 4.28 x 1.79 x
                                                                            1.46 (2.64)
coupe             4.2-4.8    1.78-1.95   1.28-1.42   2.45-2.85   0.11-0.15  Audi TT 4.19 x 1.83 x 1.37 (2.51), 911
                                                                            4.52 x 1.85 x 1.30 (2.45), BMW 4 coupe 4.77
                                                                            x 1.85 x 1.38 (2.85), Mustang 4.79 x 1.92 x
                                                                            1.38 (2.72)
estate            4.5-5.0    1.78-1.90   1.42-1.55   2.65-2.98   0.13-0.17  Octavia Combi 4.69 x 1.83 x 1.47 (2.69),
                                                                            Passat Variant 4.77 x 1.83 x 1.52 (2.79),
                                                                            E-Class estate 4.93 x 1.85 x 1.48 (2.94)
suv               4.2-5.4    1.78-2.06   1.60-1.95   2.55-3.1    0.18-0.25  RAV4 4.60 x 1.86 x 1.69 (2.69), Touareg
                                                                            4.88 x 1.98 x 1.72 (2.90), Tahoe 5.35 x
                                                                            2.06 x 1.93 (3.07)
pickup            5.0-6.2    1.80-2.10   1.75-2.00   3.0-3.9     0.21-0.28  Hilux 5.33 x 1.86 x 1.82 (3.09), F-150
                                                                            SuperCrew 5.89 x 2.03 x 1.96 (3.68)
van               4.8-7.0    1.90-2.05   1.90-2.80   3.0-4.3     0.15-0.20  Transporter 4.90 x 1.90 x 1.99 (3.00),
                                                                            Transit 5.53-6.70 x 2.06 x 2.06-2.78,
                                                                            Sprinter 5.27-7.37 x 2.02 x 2.36-2.83
minibus           5.9-7.4    1.99-2.05   2.35-2.85   3.6-4.33    0.15-0.20  Sprinter 9-20 seat 5.93-7.37 x 2.02 x
                                                                            2.36-2.84 (3.66-4.33), Transit minibus
                                                                            6.70 x 2.06 x 2.70 (3.75)
box_truck         6.5-12.0   2.30-2.55   3.00-4.00   3.4-6.8     0.25-0.35  7.5-26 t rigids (MAN TGL/TGM, Isuzu N/F):
                                                                            3-axle from 10 m (rear tandem 1.35 m), EU
                                                                            rigid maximum 12.00 m
semi_tractor      5.8-7.5    2.45-2.55   3.20-4.00   3.6-5.0     0.25-0.35  EU cab-over 4x2 (Volvo FH, MAN TGX ~6.0 x
                                                                            2.50 x 3.5-4.0, wb 3.6-3.9), US
                                                                            conventional 6x4 (~7 m, wb 4.5-5.8)
articulated_truck 13.5-20.0  2.45-2.55   3.60-4.10   3.6-5.0     0.25-0.35  EU articulated vehicle 16.50 m; US tractor
                                                  (tractor)   (tractor)             + 48-53 ft semi-trailer 19-22 m (capped
                                                                            at 20.0 m); the semi-trailer is the rest
trailer_box       5.0-16.2   2.45-2.55   3.60-4.10   (axles)     floor      EU 13.6 m semi-trailer, US 48-53 ft; below 9
                                                                 1.1-1.3    m drawbar trailers (EU centre-axle 7-8.5
                                                                            m, US enclosed cargo 16-28 ft)
trailer_flatbed   5.0-19.0   2.45-2.55   1.40-1.70   (axles)     deck       US flatbed deck ~60 in (1.52 m); beyond
                                                                            16.2 m: extendable ("stretch") flatbed
                                                                            semi-trailers for long loads, which extend
                                                                            past 20 m (capped at 19.0 m)
trailer_tanker    9.0-13.6   2.45-2.55   3.30-4.00   (axles)     0.9-1.2    ADR fuel/chemical tank semi-trailers,
                                                                 (tank      3 axles: 10.5-13.6 x 2.50-2.55 x 3.5-3.9
                                                                 bottom)    (Kässbohrer, Feldbinder data sheets)
bus               9.0-15.0   2.45-2.55   2.90-3.60   4.5-7.0     0.25-0.35  city buses 12.0 x 2.55 x 3.0-3.3 (Citaro wb
                                                                            5.85), coaches 12-13.7 x 2.55 x 3.5-3.9;
                                                                            3-axle from 13.5 m (EU 15.00 m)
articulated_bus   17.5-18.75 2.50-2.55   2.90-3.40   5.0-5.9     0.25-0.35  Citaro G 18.13 x 2.55 x 3.12 (5.90 + 5.99),
                                                  (front)                   Urbino 18 18.0 x 2.55 x 2.85-3.35, Volvo
                                                                            7900 A 18.0 x 2.55 x 3.3
================= ========== =========== =========== =========== ========== ==========================================
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ....errors import ParameterError

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
    "coupe",
    "estate",
    "minibus",
    "articulated_bus",
    "trailer_tanker",
)
PASSENGER = ("sedan", "hatchback", "coupe", "estate", "suv", "pickup", "van", "minibus")
TRAILERS = ("trailer_box", "trailer_flatbed", "trailer_tanker")

#: per body type: (min, max) of length, width, height, wheelbase, ground clearance (metres);
#: trailers: wheelbase unused, clearance = floor height (box), deck thickness (flatbed) or tank bottom
DIMENSIONS = {
    "sedan": {"length": (4.2, 5.2), "width": (1.70, 1.95), "height": (1.38, 1.55), "wheelbase": (2.6, 3.1), "clearance": (0.12, 0.17)},
    "hatchback": {"length": (3.6, 4.45), "width": (1.63, 1.82), "height": (1.42, 1.56), "wheelbase": (2.35, 2.7), "clearance": (0.12, 0.16)},
    "suv": {"length": (4.2, 5.4), "width": (1.78, 2.06), "height": (1.60, 1.95), "wheelbase": (2.55, 3.1), "clearance": (0.18, 0.25)},
    "pickup": {"length": (5.0, 6.2), "width": (1.80, 2.10), "height": (1.75, 2.00), "wheelbase": (3.0, 3.9), "clearance": (0.21, 0.28)},
    "van": {"length": (4.8, 7.0), "width": (1.90, 2.05), "height": (1.90, 2.80), "wheelbase": (3.0, 4.3), "clearance": (0.15, 0.20)},
    "box_truck": {"length": (6.5, 12.0), "width": (2.30, 2.55), "height": (3.00, 4.00), "wheelbase": (3.4, 6.8), "clearance": (0.25, 0.35)},
    "semi_tractor": {"length": (5.8, 7.5), "width": (2.45, 2.55), "height": (3.20, 4.00), "wheelbase": (3.6, 5.0), "clearance": (0.25, 0.35)},
    "trailer_box": {"length": (5.0, 16.2), "width": (2.45, 2.55), "height": (3.60, 4.10), "wheelbase": (0.0, 0.0), "clearance": (1.10, 1.30)},
    "trailer_flatbed": {"length": (5.0, 19.0), "width": (2.45, 2.55), "height": (1.40, 1.70), "wheelbase": (0.0, 0.0), "clearance": (0.15, 0.22)},
    "bus": {"length": (9.0, 15.0), "width": (2.45, 2.55), "height": (2.90, 3.60), "wheelbase": (4.5, 7.0), "clearance": (0.25, 0.35)},
    "articulated_truck": {"length": (13.5, 20.0), "width": (2.45, 2.55), "height": (3.60, 4.10), "wheelbase": (3.6, 5.0), "clearance": (0.25, 0.35)},
    "coupe": {"length": (4.2, 4.8), "width": (1.78, 1.95), "height": (1.28, 1.42), "wheelbase": (2.45, 2.85), "clearance": (0.11, 0.15)},
    "estate": {"length": (4.5, 5.0), "width": (1.78, 1.90), "height": (1.42, 1.55), "wheelbase": (2.65, 2.98), "clearance": (0.13, 0.17)},
    "minibus": {"length": (5.9, 7.4), "width": (1.99, 2.05), "height": (2.35, 2.85), "wheelbase": (3.6, 4.33), "clearance": (0.15, 0.20)},
    "articulated_bus": {"length": (17.5, 18.75), "width": (2.50, 2.55), "height": (2.90, 3.40), "wheelbase": (5.0, 5.9), "clearance": (0.25, 0.35)},
    "trailer_tanker": {"length": (9.0, 13.6), "width": (2.45, 2.55), "height": (3.30, 4.00), "wheelbase": (0.0, 0.0), "clearance": (0.90, 1.20)},
}  # fmt: skip

#: wheel radius range per body type (m): passenger tyres 0.29-0.42, truck and bus 22.5 in rims 0.45-0.53
WHEEL_RADIUS = {
    "sedan": (0.30, 0.34),
    "hatchback": (0.29, 0.32),
    "coupe": (0.31, 0.35),
    "estate": (0.31, 0.34),
    "suv": (0.34, 0.40),
    "pickup": (0.37, 0.42),
    "van": (0.33, 0.37),
    "minibus": (0.34, 0.37),
    "box_truck": (0.45, 0.52),
    "semi_tractor": (0.49, 0.53),
    "trailer_box": (0.45, 0.52),
    "trailer_flatbed": (0.45, 0.52),
    "trailer_tanker": (0.45, 0.52),
    "bus": (0.49, 0.53),
    "articulated_bus": (0.49, 0.53),
    "articulated_truck": (0.49, 0.53),
}
#: wheelbase / length range per body type (cars 0.55-0.66: Golf 0.62, BMW 5 0.60; buses ~0.49)
WHEELBASE_RATIO = {
    "sedan": (0.56, 0.63),
    "hatchback": (0.59, 0.67),
    "coupe": (0.56, 0.62),
    "estate": (0.56, 0.62),
    "suv": (0.56, 0.63),
    "pickup": (0.55, 0.65),
    "van": (0.55, 0.63),
    "minibus": (0.56, 0.63),
    "box_truck": (0.48, 0.62),
    "semi_tractor": (0.55, 0.68),
    "bus": (0.45, 0.56),
    "articulated_bus": (0.27, 0.34),
}
#: smallest front and rear overhang per body type (m): room for the wheel arch and a bumper
OVERHANG_MIN = {
    "sedan": (0.75, 0.75),
    "hatchback": (0.65, 0.55),
    "coupe": (0.75, 0.70),
    "estate": (0.75, 0.80),
    "suv": (0.75, 0.70),
    "pickup": (0.80, 0.90),
    "van": (0.70, 0.60),
    "minibus": (0.75, 0.75),
    "box_truck": (1.10, 1.00),
    "semi_tractor": (1.20, 0.80),
    "bus": (2.30, 2.20),
    "articulated_bus": (2.40, 10.0),
}
#: the share of the length left over that goes to the front overhang
FRONT_SHARE = {"sedan": 0.45, "hatchback": 0.5, "coupe": 0.45, "estate": 0.4, "suv": 0.45, "pickup": 0.4, "van": 0.4,
               "minibus": 0.4, "box_truck": 0.1, "semi_tractor": 0.1, "bus": 0.25, "articulated_bus": 0.1}  # fmt: skip
TANDEM_MIN_LENGTH = 6.8  # semi-tractors at least this long get a tandem rear axle (6x4)
TANDEM_SPACING = 1.35  # m between the two rear axles of a tandem
BOX_TANDEM_MIN_LENGTH = 10.0  # box trucks at least this long are 3-axle rigids (6x2/6x4: a rear tandem)
BUS_TRIAXLE_MIN_LENGTH = 13.5  # rigid buses at least this long have a rear tandem (EU 3-axle buses to 15 m)
DRAWBAR_MAX_LENGTH = 9.0  # trailers shorter than this are drawbar / centre-axle trailers (A-frame drawbar)
DRAWBAR_TANDEM_MIN_LENGTH = 6.5  # drawbar trailers at least this long have two axles (else one)
DRAWBAR_AXLE_SPACING = 1.1  # m between the two axles of a drawbar trailer
MIRROR = 0.10  # m a door mirror reaches beyond a passenger body's side (published widths exclude them)
MIRROR_SHARE = 0.8  # the share of passenger bodies with door mirrors (variant 1)
N_SHAPE = 12  # shape fractions drawn per vehicle (articulated bodies use the last three for their parts)


@dataclass(frozen=True)
class VehicleParams:
    """The drawn parameters of one procedural vehicle (metres; ``variant`` picks a sub-shape:
    semi-tractor 0 cab-over / 1 conventional; box truck 0 cab-over / 1 short hood; passenger
    bodies 0 without / 1 with door mirrors). An articulated truck's wheelbase, front overhang,
    clearance, wheel radius and variant are its tractor's; an articulated bus's wheelbase is its
    front section's. ``shape``: :data:`N_SHAPE` fractions in [0, 1), drawn uniformly, that the
    body's builder turns into its profile (roof line, bonnet, pillars, ...)."""

    body: str
    length: float
    width: float
    height: float
    wheelbase: float
    clearance: float
    wheel_radius: float
    front_overhang: float
    variant: int
    shape: tuple

    def to_dict(self) -> dict:
        """JSON-serialisable dict of the parameters."""
        return asdict(self)


def box_range(body: str, key: str) -> tuple[float, float]:
    """The stated range (m) of a vehicle's box along ``key`` (length, width, height): the
    :data:`DIMENSIONS` range, its width + 2 :data:`MIRROR` at most for passenger bodies (mirrors)."""
    lo, hi = DIMENSIONS[check_body(body)][key]
    return (lo, hi + 2 * MIRROR) if key == "width" and body in PASSENGER else (lo, hi)


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
    the body's share (:data:`FRONT_SHARE`). Passenger bodies have door mirrors (``variant`` 1) with
    probability :data:`MIRROR_SHARE`, which widen the box by 2 :data:`MIRROR`. Deterministic in ``seed``."""
    d = DIMENSIONS[check_body(body)]
    rng = _rng(seed)
    u = lambda key: float(rng.uniform(*d[key]))  # noqa: E731
    length, width, height = u("length"), u("width"), u("height")
    clearance = u("clearance")
    r = float(rng.uniform(*WHEEL_RADIUS[body]))
    shape = tuple(float(x) for x in rng.uniform(0.0, 1.0, size=N_SHAPE))
    variant = int(rng.integers(0, 2))
    x = float(rng.uniform())
    if body in PASSENGER:  # door mirrors widen the box beyond the published (body) width
        variant = int(x < MIRROR_SHARE)
        x = x / MIRROR_SHARE if variant else (x - MIRROR_SHARE) / (1 - MIRROR_SHARE)
        width += 2 * MIRROR * variant
    if body in TRAILERS:
        return VehicleParams(body, length, width, height, 0.0, clearance, r, 0.0, variant, shape)
    if body == "articulated_truck":
        lt = tractor_length(length, shape[9])
        variant = int(lt >= TANDEM_MIN_LENGTH)
        wheelbase, front = _wheelbase_front("semi_tractor", lt, r, variant, x, shape[5])
        return VehicleParams(body, length, width, height, wheelbase, clearance, r, front, variant, shape)
    if body == "semi_tractor":
        variant = int(length >= TANDEM_MIN_LENGTH)  # long tractors: US conventional 6x4, else EU cab-over 4x2
    wheelbase, front = _wheelbase_front(body, length, r, variant, x, shape[5])
    return VehicleParams(body, length, width, height, wheelbase, clearance, r, front, variant, shape)


def rear_overhang_min(body: str, length: float, r: float, variant: int) -> float:
    """The smallest rear overhang (m): :data:`OVERHANG_MIN`, or room for a rear tandem."""
    rm = OVERHANG_MIN[body][1]
    if (
        (body == "semi_tractor" and variant)
        or (body == "box_truck" and length >= BOX_TANDEM_MIN_LENGTH)
        or (body == "bus" and length >= BUS_TRIAXLE_MIN_LENGTH)
    ):
        rm = max(rm, TANDEM_SPACING + r + 0.1 + (1.2 if body == "bus" else 0.0))
    return rm


def _wheelbase_front(body: str, length: float, r: float, variant: int, x: float, f5: float) -> tuple[float, float]:
    """(wheelbase, front overhang) of a body of ``length`` with wheel radius ``r``: the wheelbase at
    fraction ``x`` of its allowed range (:func:`draw_params`), the front overhang from ``f5``."""
    d = DIMENSIONS[body]
    fm = OVERHANG_MIN[body][0]
    rm = rear_overhang_min(body, length, r, variant)
    a, b = WHEELBASE_RATIO[body]
    lo = max(d["wheelbase"][0], a * length)
    hi = min(d["wheelbase"][1], b * length, length - fm - rm)
    if lo > hi:
        lo = hi = min(max(d["wheelbase"][0], (a + b) / 2 * length), d["wheelbase"][1], length - fm - rm)
    wheelbase = lo + (hi - lo) * x
    front = fm + (length - wheelbase - fm - rm) * FRONT_SHARE[body] * (0.8 + 0.4 * f5)
    return wheelbase, front


def tractor_length(length: float, f: float) -> float:
    """The tractor length of an articulated truck ``length`` long, at fraction ``f`` of its range:
    the semi-tractor range, capped at 5.8 + (length - 13.5) m so that the semi-trailer keeps >= 7.7 m
    behind the tractor, and at least length - 12.5 m (a 20 m truck is a US conventional tractor with
    a 53 ft semi-trailer)."""
    lo, hi = DIMENSIONS["semi_tractor"]["length"]
    hi = min(hi, lo + length - DIMENSIONS["articulated_truck"]["length"][0])
    lo = min(hi, max(lo, length - 12.5))
    return lo + (hi - lo) * f
