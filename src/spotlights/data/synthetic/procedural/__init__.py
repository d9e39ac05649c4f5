"""Procedural vehicle meshes: parametric bodies for every vehicle class a real frame holds.

A source of *variety* for the completion dataset (docs/dataset.md, "Procedural vehicles";
docs/studies/procedural.md measures how realistic): sedans, hatchbacks, coupes, estates, SUVs,
pickups (with an open cargo bed), vans and minibuses (:mod:`.cars`); box trucks, semi-tractors
alone and coupled to a box or tank semi-trailer (articulated trucks, up to 20 m), box, flatbed and
tanker trailers (semi-trailers, and drawbar trailers below 9 m), rigid and articulated buses
(:mod:`.heavy`). Dimension ranges and their published sources: :mod:`.params`.

Construction
------------
Every vehicle is a few disjoint closed components, concatenated (no boolean operations, so no
interior faces): **lofted shells** through smooth cross-sections (superellipses below the
beltline; above it the sides lean in to the roof's width, rounded at the roof's edges) along a
smooth side profile (monotone cubic through the nose, bonnet, windscreen, roof, rear window and
boot, hatch or bed), plan-view corners rounded, side glass recessed between the pillars (1.5 cm
on cabs and buses; 0.20-0.35 m on passenger bodies: the cabin as rays see it through the open
windows of the ApolloScape meshes), the floor rising over every wheel into a **wheel arch** (a
circular tunnel of radius ``wheel radius + 4 cm``, closed between the wheels of a passenger body
by a wheel house); boxes (cargo boxes, trailer bodies, frames, bed walls, landing legs,
fifth wheels, door mirrors), tanks and **wheels** (20-sided cylinders along y, tyre bottoms on the
ground, inside the body's width). Components are 1-10 cm apart, so the concatenation is watertight
(every edge in exactly two faces: every ray that enters leaves), wound outward, of positive volume.

Frame: the object frame of the project (x forward, y left, z up, metres), origin at the centre
of the mesh's axis-aligned box, like the ApolloScape meshes. The box is exactly
(length, width, height) of the drawn parameters (door mirrors included in the width).

Detector classes (:data:`~spotlights.data.vehicle_classes.CLASS_BODIES`, the real readers' names):
``car`` = sedan, hatchback, SUV, pickup, coupe, estate; ``caravan`` (``van`` is accepted) = van,
minibus; ``truck`` = box truck, semi-tractor, pickup, articulated truck; ``bus`` = bus, articulated
bus; ``trailer`` = box, flatbed and tanker trailers. Pickups are in both car and truck: datasets
disagree (nuScenes labels pickups ``vehicle.truck``; Argoverse 2 ``REGULAR_VEHICLE``, KITTI ``Car``).
"""

from __future__ import annotations

import hashlib

import numpy as np

from ...vehicle_classes import CATEGORY_CLASS, CLASS_BODIES, VEHICLE_CLASSES, class_of_category
from . import cars, heavy
from .params import BODY_TYPES, DIMENSIONS, PASSENGER, TRAILERS, VehicleParams, box_range, draw_params

__all__ = [
    "BODY_TYPES",
    "CATEGORY_CLASS",
    "CLASS_BODIES",
    "DIMENSIONS",
    "VEHICLE_CLASSES",
    "VehicleParams",
    "box_range",
    "class_of_category",
    "draw_params",
    "generate_vehicle",
    "generate_trimesh",
    "mesh_digest",
    "vehicle_arrays",
]


def _components(p: VehicleParams) -> list:
    """The closed components ``[(vertices, faces), ...]`` of a vehicle (x = L - s from its front)."""
    if p.body in PASSENGER:
        return cars.passenger(p)
    if p.body in ("box_truck", "semi_tractor"):
        return heavy.truck(p)
    if p.body == "bus":
        return heavy.bus(p)
    if p.body == "articulated_bus":
        return heavy.articulated_bus(p)
    if p.body == "articulated_truck":
        return heavy.articulated_truck(p, _components)
    if p.body in TRAILERS:
        return heavy.trailer(p, semi=heavy.is_semi_trailer(p))
    raise AssertionError(p.body)  # draw_params checked the body


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
