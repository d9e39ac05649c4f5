"""Detector classes of the synthetic models: which procedural bodies make each class, and the class of a
mesh category.

The class names are those the real-data readers give boxes (:data:`spotlights.data.real.base.CLASSES`:
``caravan`` is the van class, KITTI ``Van``, Argoverse 2 ``LARGE_VEHICLE``), so a model trained on these
classes can be matched with a detector's boxes. ``van`` is accepted as another name of ``caravan``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

#: detector class -> procedural body types drawn for it, in round-robin order. Pickups are in both car
#: and truck: nuScenes labels pickups ``vehicle.truck``, Argoverse 2 ``REGULAR_VEHICLE`` and KITTI ``Car``.
#: Vehicle ``i`` of a class is body ``i % len(bodies)``: a body appended to a class changes which body (and
#: name, hence seed) the indices from ``len(bodies)`` on draw (``articulated_truck`` was appended to truck;
#: coupe, estate, minibus, articulated_bus and trailer_tanker to their classes).
CLASS_BODIES: dict[str, tuple[str, ...]] = {
    "car": ("sedan", "hatchback", "suv", "pickup", "coupe", "estate"),
    "caravan": ("van", "minibus"),
    "truck": ("box_truck", "semi_tractor", "pickup", "articulated_truck"),
    "bus": ("bus", "articulated_bus"),
    "trailer": ("trailer_box", "trailer_flatbed", "trailer_tanker"),
}
#: the classes the procedural generator makes: the one class vocabulary of the models (a class-conditioned
#: SA-Net's ``classes``); every reader's labels map onto these (``data.real.boxfiles.CLASS_MAP`` merges the
#: readers' tables) or onto a class no model learns (``construction``, ``emergency``: gated, not completed)
VEHICLE_CLASSES: tuple[str, ...] = tuple(CLASS_BODIES)
#: other names accepted for a class (``--classes van``)
CLASS_ALIASES: dict[str, str] = {"van": "caravan"}

#: mesh category (sub-folder or manifest category; procedural body type) -> detector class; categories not
#: listed are ``"other"`` (e.g. the Kenney farm tractors)
CATEGORY_CLASS: dict[str, str] = {
    "sedan": "car",
    "hatchback": "car",
    "suv": "car",
    "coupe": "car",
    "wagon": "car",
    "estate": "car",
    "pickup": "car",
    "race": "car",
    "car": "car",
    "van": "caravan",
    "caravan": "caravan",
    "minibus": "caravan",
    "truck": "truck",
    "box_truck": "truck",
    "semi_tractor": "truck",
    "articulated_truck": "truck",
    "bus": "bus",
    "articulated_bus": "bus",
    "trailer": "trailer",
    "trailer_box": "trailer",
    "trailer_flatbed": "trailer",
    "trailer_tanker": "trailer",
}


def class_of_category(category: str) -> str:
    """The detector class of a mesh category (:data:`CATEGORY_CLASS`; ``"other"`` when unknown)."""
    return CATEGORY_CLASS.get(str(category).lower(), "other")


def canonical_class(name: str) -> str:
    """A class name as stored: lower case, aliases resolved (``van`` -> ``caravan``)."""
    n = str(name).strip().lower()
    return CLASS_ALIASES.get(n, n)


def class_rows(names: Iterable[str | None], vocabulary: Sequence[str]) -> np.ndarray:
    """(B,) int64 row of each class name in a class-conditioned model's ``vocabulary`` (its embedding rows, in
    order); names are compared as :func:`canonical_class` gives them (``van`` is ``caravan``), and ``None`` or a
    class the vocabulary lacks is -1 (no class input: the model's code as its encoder gives it)."""
    table = {canonical_class(c): i for i, c in enumerate(vocabulary)}
    return np.array([-1 if n is None else table.get(canonical_class(n), -1) for n in names], dtype=np.int64)
