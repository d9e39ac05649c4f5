"""Passenger bodies: sedan, hatchback, coupe, estate, SUV, pickup, van and minibus.

Each body is one lofted shell (:func:`~.mesh.loft_body`) whose side profile is a smooth curve
through control points - nose, bonnet, cowl (windscreen base), windscreen top, roof, the rear
window's or hatch's base, boot lid and tail - drawn as fractions of the length and height from
the vehicle's shape fractions; the cross-sections are superellipses below the beltline and lean
in above it (tumblehome) to the roof's width, with rounded edges; the side windows are open onto a
cabin surface :data:`CABIN` m inside the pillars (the ApolloScape meshes have no side glass: rays
through their windows meet the cabin). Four wheels stand in wheel arches, a wheel house between the
two wheels of an axle (a well at each side, no tunnel across; the floor :data:`FLOOR_ABOVE_CLEARANCE`
above the published ground clearance, which is the lowest point); door mirrors (variant 1) stand 1 cm off the body
and reach the box's width (the body is then 0.2 m narrower). A pickup's bed is open: a floor
in the shell, two side walls and a tailgate as separate boxes.
"""

from __future__ import annotations

import numpy as np

from .mesh import ARCH_GAP, box, loft_body, wheel_house, wheel_pair
from .params import MIRROR, VehicleParams

FLOOR_ABOVE_CLEARANCE = 0.08  # m: the body's floor above the published ground clearance (its lowest point)
CABIN = (0.20, 0.35)  # m: how far inside the pillars a side window's surface lies (the cabin through open glass)


def _car_top(p: VehicleParams, nose: float) -> tuple[list, float, float]:
    """Roof-line control points of a sedan, coupe, estate or hatchback: ``(top, cowl s, side-glass
    end s)``. Nose, bonnet front, cowl (windscreen base), windscreen top, roof apex, then the
    body's rear: sedan and coupe a rear window down to a boot lid, estate a long roof and a
    near-vertical tailgate, hatchback a roof sloping to a steep hatch."""
    L, H, f, b = p.length, p.height, p.shape, p.body
    cowl = {"sedan": 0.28, "estate": 0.28, "coupe": 0.32, "hatchback": 0.25}[b] + 0.04 * f[2]
    hood = (0.68 if b != "coupe" else 0.64) + 0.04 * f[1]
    front = (hood - 0.09) * H
    screen = cowl + (0.17 if b != "coupe" else 0.19) + 0.04 * f[3]
    apex = screen + 0.07
    top = [(0, nose), (0.025 * L, nose + 0.7 * (front - nose)), (0.07 * L, front), (cowl * L, hood * H),
           (screen * L, 0.955 * H), (apex * L, H)]  # fmt: skip
    if b in ("sedan", "coupe"):
        rw = (0.82 if b == "sedan" else 0.86) + 0.03 * f[5]
        deck = (0.73 + 0.04 * f[6]) * H
        back = (0.68 + 0.04 * f[4]) * L if b == "sedan" else (apex + 0.12) * L
        top += [(back, 0.96 * H if b == "sedan" else 0.90 * H), (rw * L, deck), (0.975 * L, deck - 0.015 * H),
                (L, deck - 0.1 * H)]  # fmt: skip
        return top, cowl * L, min(rw * L - 0.15, back + 0.1)
    if b == "estate":
        re = 0.89 + 0.03 * f[4]
        tail = (0.64 + 0.05 * f[6]) * H
        top += [(re * L, (0.945 - 0.02 * f[5]) * H), (0.978 * L, tail + 0.16 * H), (L, tail)]
        return top, cowl * L, re * L - 0.1
    re = 0.80 + 0.05 * f[4]
    tail = (0.60 + 0.08 * f[6]) * H
    top += [(re * L, (0.93 + 0.02 * f[5]) * H), ((re + 0.975) / 2 * L, (0.93 * H + tail) / 2 + 0.08 * H),
            (0.975 * L, tail + 0.03 * H), (L, tail)]  # fmt: skip
    return top, cowl * L, re * L - 0.1


def _profile(p: VehicleParams) -> dict:
    """The side profile of a passenger body: ``top``, ``floor`` and ``belt`` control points, roof
    half-width fraction ``roof``, cowl s ``cowl``, side-glass end ``glass_end``."""
    L, H, cl, f = p.length, p.height, p.clearance, p.shape
    arch_top = 2 * p.wheel_radius + ARCH_GAP
    nose = cl + 0.30 + 0.08 * f[0]
    b = p.body
    rise = 0.04 * H
    if b in ("sedan", "estate", "coupe", "hatchback"):
        top, cowl, glass_end = _car_top(p, nose)
        belt = max((0.60 + 0.03 * f[7]) * H, arch_top + 0.1)
        roof = 0.70 + 0.08 * f[8]
    elif b in ("suv", "pickup"):
        pick = b == "pickup"
        cowl = (0.25 if pick else 0.27) + 0.03 * f[2]
        hood = (0.71 if pick else 0.68) + 0.04 * f[1]
        front = (hood - 0.10) * H
        screen = cowl + (0.10 if pick else 0.14) + 0.03 * f[3]
        nose = max(nose, 0.45 * H)
        top = [(0, nose), (0.02 * L, nose + 0.7 * (front - nose)), (0.05 * L, front), (cowl * L, hood * H),
               (screen * L, 0.965 * H), ((screen + 0.05) * L, H)]  # fmt: skip
        if not pick:
            re = 0.84 + 0.06 * f[4]
            tail = (0.64 + 0.08 * f[6]) * H
            top += [(re * L, (0.96 - 0.02 * f[5]) * H), (0.97 * L, tail + 0.12 * H), (L, tail)]
            glass_end = re * L - 0.15
        else:
            cab = (0.53 + 0.07 * f[4]) * L  # extended cab ... crew cab
            top += [(cab - 0.12, 0.985 * H), (cab, 0.95 * H)]
            glass_end = cab - 0.15
        belt = max(((0.62 if pick else 0.58) + 0.03 * f[7]) * H, arch_top + 0.15)
        roof = (0.80 if pick else 0.76) + 0.08 * f[8]
        cowl *= L
    else:  # van, minibus
        cowl = (0.10 + 0.04 * f[2]) * L
        hood = 0.40 + 0.08 * f[1]
        screen = cowl + (0.13 + 0.04 * f[3]) * L
        nose = max(nose, 0.30 * H)
        top = [(0, nose), (0.015 * L, nose + 0.7 * (hood * H - nose)), (0.04 * L, hood * H), (cowl, (hood + 0.06) * H),
               (screen, 0.97 * H), (screen + 0.05 * L, H), (L - 0.1, H), (L, 0.96 * H)]  # fmt: skip
        belt = max((0.42 + 0.06 * f[7]) * H, arch_top + 0.12)
        roof = 0.88 + 0.06 * f[8]
        glass_end = L - 0.25 if b == "minibus" else screen + 0.12 * L
        rise = 0.0
    fl = cl + FLOOR_ABOVE_CLEARANCE
    floor = [(0, fl + 0.2), (0.12, fl + 0.1), (0.35, fl + 0.02), (0.6, fl), (L - 0.7, fl), (L - 0.3, fl + 0.06),
             (L - 0.1, fl + 0.12), (L, fl + 0.2)]  # fmt: skip
    belt_pts = [(0, belt - 0.01 * H), (cowl, belt), (L, belt + rise)]
    return {"top": top, "floor": floor, "belt": belt_pts, "roof": roof, "cowl": cowl, "glass_end": glass_end}


def _windows(p: VehicleParams, start: float, end: float) -> list:
    """Side-glass spans between ``start`` and ``end`` (s, m), split by pillars 0.08-0.14 m wide:
    cars two or three windows, a minibus one per 0.9-1.2 m."""
    f = p.shape
    if end <= start + 0.2:
        return []
    if p.body == "minibus":
        n = max(2, int((end - start) / (0.9 + 0.3 * f[9])))
    elif p.body in ("coupe", "van"):
        n = 1
    else:
        n = 3 if p.body in ("estate", "suv") and f[9] > 0.4 else 2
    edges = np.linspace(start, end, n + 1)
    pillar = 0.04 + 0.03 * f[10]
    return [(a + pillar * (i > 0), b - pillar * (i < n - 1)) for i, (a, b) in enumerate(zip(edges[:-1], edges[1:]))]


def passenger(p: VehicleParams) -> list:
    """The closed components of a passenger body (front at s = 0, x = L - s)."""
    L, W, r, f = p.length, p.width, p.wheel_radius, p.shape
    x_of = lambda s: L - np.asarray(s, dtype=np.float64)  # noqa: E731
    pr = _profile(p)
    half = W / 2 - (MIRROR if p.variant else 0.0)  # mirrors reach the box's width
    sf, sr = p.front_overhang, p.front_overhang + p.wheelbase
    arch = r + ARCH_GAP
    corners = (0.35 + 0.2 * f[11], 0.25 + 0.15 * f[11])
    if p.body in ("van", "minibus"):
        corners = (0.25 + 0.15 * f[11], 0.08)
    windows = _windows(p, pr["cowl"] + 0.25, pr["glass_end"])
    parts = _bed(p, half, pr, x_of) if p.body == "pickup" else []
    boxy = {"van": (6.0, 3.0), "minibus": (6.0, 3.0), "pickup": (5.0, 5.0)}.get(p.body, (4.0, 3.0))
    parts += [
        loft_body(0.0, L, pr["top"], pr["floor"], pr["belt"], half, half * pr["roof"], [sf, sr], arch, x_of,
                  corners=corners, n_low=boxy[0], n_up=boxy[1], windows=windows,
                  recess=CABIN[0] + (CABIN[1] - CABIN[0]) * f[9])
    ]  # fmt: skip
    if p.variant:
        s_m = pr["cowl"] + 0.22
        z = pr["belt"][1][1] + 0.04
        for sgn in (1.0, -1.0):
            y = sorted((sgn * (half + 0.01), sgn * W / 2))
            parts.append(box((x_of(s_m + 0.14)[()], y[0], z), (x_of(s_m)[()], y[1], z + 0.14)))
    tyre = (0.21 + 0.04 * f[4]) if p.body in ("van", "minibus") else 0.19 + 0.07 * f[4]
    for s in (sf, sr):
        parts += wheel_pair(x_of(s)[()], half, tyre, r)
        parts.append(wheel_house(x_of(s)[()], r, arch, p.clearance + FLOOR_ABOVE_CLEARANCE, half - tyre - 0.05))
    return parts


def _bed(p: VehicleParams, half: float, pr: dict, x_of) -> list:
    """A pickup's open bed behind the cab: the shell's top drops to the bed floor there (set in
    ``pr["top"]``), and two side walls and a tailgate (boxes, 6 cm thick) stand 1 cm above it."""
    L = p.length
    cab = pr["top"][-1][0]
    bed_floor = max(0.46 * p.height, 2 * p.wheel_radius + ARCH_GAP + 0.06)
    pr["top"] += [(cab + 0.04, bed_floor + 0.04), (L, bed_floor)]
    t, z0, z1 = 0.06, bed_floor + 0.05, min(pr["belt"][1][1] + 0.05, p.height - 0.3)
    s0, s1 = cab + 0.1, L - 0.02
    return [
        box((x_of(s1)[()], half - t, z0), (x_of(s0)[()], half - 0.01, z1)),
        box((x_of(s1)[()], -half + 0.01, z0), (x_of(s0)[()], -half + t, z1)),
        box((x_of(L)[()], -half + t + 0.02, z0), (x_of(L - t)[()], half - t - 0.02, z1 - 0.03)),
    ]
