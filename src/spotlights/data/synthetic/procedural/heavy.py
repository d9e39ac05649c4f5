"""Heavy bodies: box trucks, semi-tractors, articulated trucks, trailers and buses.

Cabs and buses are lofted shells (:func:`~.mesh.loft_body`, boxy superellipse sections with
rounded edges, recessed side glass); cargo boxes, trailer bodies, frames, decks, landing legs and
fifth wheels are boxes; a tanker's tank is a superellipse loft with dished heads; a drawbar
trailer's A-frame drawbar is one solid trapezoidal slab (0.2 m wide at the eye). An articulated
bus is two lofted sections joined by a bellows (a rounded box 8 cm inside the sections).
"""

from __future__ import annotations

import numpy as np

from .mesh import ARCH_GAP, box, loft, loft_body, rounded_box, tank, wheel_pair
from .params import (
    BOX_TANDEM_MIN_LENGTH,
    BUS_TRIAXLE_MIN_LENGTH,
    DIMENSIONS,
    DRAWBAR_AXLE_SPACING,
    DRAWBAR_MAX_LENGTH,
    DRAWBAR_TANDEM_MIN_LENGTH,
    TANDEM_SPACING,
    VehicleParams,
    tractor_length,
)


def _x_of(L: float):
    return lambda s: L - np.asarray(s, dtype=np.float64)


def rear_axles(p: VehicleParams) -> list:
    """Distances from the front of a box truck's, semi-tractor's or rigid bus's rear axles (a tandem
    on 6x4 tractors, on box trucks from :data:`BOX_TANDEM_MIN_LENGTH` and buses from
    :data:`BUS_TRIAXLE_MIN_LENGTH`)."""
    sr = p.front_overhang + p.wheelbase
    if p.body == "semi_tractor":
        tandem = p.variant
    elif p.body == "bus":
        tandem = p.length >= BUS_TRIAXLE_MIN_LENGTH
    else:
        tandem = p.length >= BOX_TANDEM_MIN_LENGTH
    return [sr, sr + TANDEM_SPACING] if tandem else [sr]


def fifth_wheel(p: VehicleParams) -> float:
    """Distance from the front of a semi-tractor's fifth wheel (the kingpin): 0.3 m ahead of the
    middle of the rear axle(s); its plate is 0.9 m long, its top 2 r + 0.46 m above the ground."""
    return float(np.mean(rear_axles(p))) - 0.3


def cab_length(p: VehicleParams) -> float:
    """Length (m) of a box truck's or semi-tractor's cab (cab-over, or hooded for ``variant`` 1)."""
    sf, sr, ra = p.front_overhang, p.front_overhang + p.wheelbase, p.wheel_radius + ARCH_GAP
    f = p.shape
    cab_len = max(2.0 + 0.4 * f[2], sf + ra + 0.3) if p.variant != 1 else sf + ra + 1.7 + 0.3 * f[2]
    return min(cab_len, sr - ra - 0.1)


def truck(p: VehicleParams) -> list:
    """A box truck or a semi-tractor (front at s = 0): a lofted cab (cab-over or hooded), a frame,
    and a cargo box (box truck) or a fifth wheel (semi-tractor), front wheels and the rear axles."""
    L, W, H, r, cl, f = p.length, p.width, p.height, p.wheel_radius, p.clearance, p.shape
    x_of = _x_of(L)
    semi = p.body == "semi_tractor"
    sf = p.front_overhang
    arch_top = 2 * r + ARCH_GAP
    cab_h = H if semi else min(H - 0.15, 2.6 + 0.4 * f[1])
    cab_len = cab_length(p)
    belt = max(cab_h * (0.50 if semi else 0.55), arch_top + 0.25)
    if p.variant == 1:
        hood_h = max(arch_top + 0.3, 0.42 * cab_h)
        top = [(0, hood_h - 0.25), (0.2, hood_h), (cab_len - 1.9, hood_h + 0.05), (cab_len - 1.5, cab_h - 0.1),
               (cab_len - 1.2, cab_h), (cab_len, cab_h)]  # fmt: skip
        windows = [(cab_len - 1.1, cab_len - 0.25)]
    else:
        top = [(0, belt - 0.1), (0.12, belt + 0.15), (0.35, cab_h - 0.2), (0.6, cab_h), (cab_len, cab_h)]
        windows = [(0.25, min(1.2, cab_len - 0.3))]
    floor = [(0, cl + 0.1), (0.3, cl), (cab_len, cl)]
    parts = [
        loft_body(0.0, cab_len, top, floor, belt, W / 2, W / 2 - 0.1, [sf], r + ARCH_GAP, x_of,
                  corners=(0.12 + 0.1 * f[11], 0.04), n_low=8.0, n_up=6.0, windows=windows)
    ]  # fmt: skip
    frame_z = (2 * r + 0.03, 2 * r + 0.28)
    parts.append(box((x_of(L)[()], -0.45, frame_z[0]), (x_of(cab_len + 0.05)[()], 0.45, frame_z[1])))
    if semi:
        fw = fifth_wheel(p)
        parts.append(box((x_of(fw + 0.45)[()], -0.6, frame_z[1] + 0.01), (x_of(fw - 0.45)[()], 0.6, frame_z[1] + 0.18)))
    else:
        parts.append(box((x_of(L)[()], -W / 2, frame_z[1] + 0.01), (x_of(cab_len + 0.12)[()], W / 2, H)))
    for a in rear_axles(p):
        parts += wheel_pair(x_of(a)[()], W / 2, 0.6, r)
    parts += wheel_pair(x_of(sf)[()], W / 2, 0.32, r)
    return parts


def bus(p: VehicleParams) -> list:
    """A rigid bus (front at s = 0): one lofted shell, near-vertical windscreen, a low beltline,
    a window band with pillars every 1.1-1.6 m, a front axle and one or two rear axles."""
    L, W, r = p.length, p.width, p.wheel_radius
    x_of = _x_of(L)
    rear = rear_axles(p)
    parts = [_bus_section(p, 0.0, L, [p.front_overhang] + rear, True, True)]
    parts += wheel_pair(x_of(p.front_overhang)[()], W / 2, 0.3, r)
    for k, a in enumerate(rear):
        parts += wheel_pair(x_of(a)[()], W / 2, 0.6 if k == 0 else 0.3, r)
    return parts


def _bus_section(p: VehicleParams, s0: float, s1: float, axles: list, front: bool, rear: bool):
    """One lofted bus section from ``s0`` to ``s1``; ``front``/``rear``: it carries the bus's
    rounded windscreen / rear end (else a flat face toward the bellows)."""
    L, W, H, r, cl, f = p.length, p.width, p.height, p.wheel_radius, p.clearance, p.shape
    belt = max((0.36 + 0.06 * f[1]) * H, 2 * r + ARCH_GAP + 0.15)
    top = [(s0, H - 0.35 if front else H - 0.02), (s0 + 0.3, H - 0.04), (s0 + 0.6, H), (s1 - 0.3, H),
           (s1, H - 0.22 if rear else H - 0.02)]  # fmt: skip
    floor = [(s0, cl + (0.15 if front else 0.0)), (s0 + 0.3, cl), (s1 - 0.5, cl), (s1, cl + (0.25 if rear else 0.0))]
    pitch = 1.1 + 0.5 * f[9]
    start = s0 + (1.2 if front else 0.3)
    n = max(1, int((s1 - 0.4 - start) / pitch))
    edges = np.linspace(start, s1 - 0.4, n + 1)
    windows = [(a + 0.06, b - 0.06) for a, b in zip(edges[:-1], edges[1:])]
    corners = (0.15 + 0.15 * f[11] if front else 0.03, 0.12 if rear else 0.03)
    return loft_body(s0, s1, top, floor, belt, W / 2, W / 2 - 0.05, axles, r + ARCH_GAP, _x_of(L),
                     corners=corners, n_low=8.0, n_up=8.0, windows=windows, step=0.2)  # fmt: skip


def articulated_bus(p: VehicleParams) -> list:
    """An articulated bus: a front section (front axle and middle axle ``wheelbase`` behind it), a
    0.7 m bellows 1.3-1.7 m behind the middle axle, a rear section on the rear axle 2.6-3.4 m ahead
    of the rear (``shape[10]``)."""
    L, W, H, r, cl, f = p.length, p.width, p.height, p.wheel_radius, p.clearance, p.shape
    x_of = _x_of(L)
    sf, sm = p.front_overhang, p.front_overhang + p.wheelbase
    joint = sm + 1.3 + 0.4 * f[6]
    sr = L - (2.6 + 0.8 * f[10])
    parts = [
        _bus_section(p, 0.0, joint - 0.37, [sf, sm], True, False),
        _bus_section(p, joint + 0.37, L, [sr], False, True),
        rounded_box(x_of(joint + 0.35)[()], x_of(joint - 0.35)[()], W / 2 - 0.08, cl + 0.12, H - 0.1, n=8.0),
    ]
    parts += wheel_pair(x_of(sf)[()], W / 2, 0.3, r) + wheel_pair(x_of(sm)[()], W / 2, 0.6, r)
    parts += wheel_pair(x_of(sr)[()], W / 2, 0.6, r)
    return parts


def trailer(p: VehicleParams, semi: bool, legs_from: float = 0.0) -> list:
    """The components of a trailer (front at s = 0, x = L - s). ``semi``: a semi-trailer (two axles,
    three from 11 m, near the rear; landing legs 1.6-2.4 m from the front, or ``legs_from`` + 0-0.8 m
    when that is further back); else a drawbar trailer: an A-frame drawbar (a solid trapezoid, 1.0-1.6 m
    long, 0.12 m thick, its top 0.85-1.0 m above the ground) ahead of the body, one axle (two 1.1 m
    apart from 6.5 m) 50-60% of the body's length behind its front, no landing legs. Box: a box
    body on the floor; flatbed: a deck on a centre beam; tanker: a tank (bottom at the clearance,
    top 0.1 m below the height) with a catwalk on top."""
    L, W, H, r, cl, f = p.length, p.width, p.height, p.wheel_radius, p.clearance, p.shape
    x_of = _x_of(L)
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
        parts.append(box((x_of(L)[()], -W / 2, floor_z), (x_of(front)[()], W / 2, H)))
        under = floor_z - 0.01
    elif p.body == "trailer_tanker":
        bottom = max(cl, arch_top + 0.06)
        parts.append(tank(x_of(L)[()], x_of(front)[()], W / 2, bottom, H - 0.1, 0.25 + 0.15 * f[3]))
        parts.append(box((x_of(0.75 * L)[()], -0.3, H - 0.09), (x_of(0.25 * L)[()], 0.3, H)))
        under = bottom - 0.01
    else:
        deck = cl
        parts.append(box((x_of(L)[()], -W / 2, H - deck), (x_of(front)[()], W / 2, H)))
        beam_top = H - deck - 0.01
        beam_bottom = max(arch_top + 0.02, beam_top - 0.35)
        parts.append(box((x_of(L - 0.2)[()], -0.45, beam_bottom), (x_of(front + 0.2)[()], 0.45, beam_top)))
        under = beam_bottom - 0.01
    if semi:
        legs_s = max(1.6, legs_from) + 0.8 * f[2]
        for y in (0.9, -0.9):
            parts.append(box((x_of(legs_s + 0.1)[()], y - 0.06, 0.0), (x_of(legs_s - 0.1)[()], y + 0.06, under)))
    else:
        top = 0.85 + 0.15 * f[3]
        base = min(0.6, W / 2 - 0.1)
        xs = x_of([0.0, front - 0.02])
        secs = np.array(
            [[[y0, z0] for y0, z0 in ((-h, top - 0.12), (h, top - 0.12), (h, top), (-h, top))] for h in (0.1, base)]
        )
        parts.append(loft(xs, secs))
    for a in axles:
        parts += wheel_pair(x_of(a)[()], W / 2, 0.6, r)
    return parts


def articulated_truck(p: VehicleParams, components) -> list:
    """An articulated truck: a semi-tractor (``p``'s wheelbase, front overhang, wheel radius and
    variant; length :func:`~.params.tractor_length` at ``shape[9]``, height 3.2 m up to the
    trailer's by ``shape[8]``) and a box semi-trailer (a tanker when ``shape[10]`` < 0.3; the rest
    of the length, full height) whose floor rests 2 cm above the fifth wheel's plate, its front
    0.9-1.7 m ahead of the kingpin (``shape[7]``; less where the cab leaves less room: the gap behind
    the cab is 0.5-2.5 m, half the room if under 1 m), its landing legs behind the tractor.
    ``components``: the builder of the tractor's components."""
    f = p.shape
    lt = tractor_length(p.length, f[9])
    h_lo, h_hi = DIMENSIONS["semi_tractor"]["height"]
    ht = h_lo + (min(h_hi, p.height) - h_lo) * f[8]
    tractor = VehicleParams(
        "semi_tractor", lt, p.width, ht, p.wheelbase, p.clearance, p.wheel_radius, p.front_overhang, p.variant, f
    )
    kingpin = fifth_wheel(tractor)
    room = kingpin - cab_length(tractor)
    front = kingpin - min(0.9 + 0.8 * f[7], room - min(0.5, room / 2))
    floor = 2 * p.wheel_radius + 0.48  # the fifth wheel's top + 0.02
    kind = "trailer_tanker" if f[10] < 0.3 else "trailer_box"
    trailer_p = VehicleParams(kind, p.length - front, p.width, p.height, 0.0, floor, p.wheel_radius, 0.0, 0, f)
    shift = np.array([p.length - lt, 0.0, 0.0])
    parts = [(v + shift, fc) for v, fc in components(tractor)]
    return parts + trailer(trailer_p, semi=True, legs_from=lt - front + 0.4)


def is_semi_trailer(p: VehicleParams) -> bool:
    """Whether a trailer body is a semi-trailer (else a drawbar trailer)."""
    return p.length >= DRAWBAR_MAX_LENGTH
