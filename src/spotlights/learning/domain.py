"""What a model learned (:class:`LearnedDomain`: its classes and box sizes) and the gate that leaves other boxes as
observed points."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..data.store import open_dataset
from ..data.vehicle_classes import CATEGORY_CLASS, canonical_class
from ..errors import InputFileError, ParameterError

#: Body types of the synthetic datasets' categories -> the detector class a real box of that vehicle gets: the
#: one mapping, :data:`spotlights.data.vehicle_classes.CATEGORY_CLASS` (a pickup or a race car is a ``car`` for
#: KITTI, nuScenes and Argoverse 2 alike; a van is KITTI's ``Van``, ``caravan``).
BODY_TYPE_CLASS: dict[str, str] = CATEGORY_CLASS

GATE_TOLERANCE = 0.5
"""How far outside its class's learned size range a box may be and still be completed: 0.5 = a length,
width or height 50% beyond the range (a 16.7 m truck against cars' 3.4-5.6 m is far outside; a 6 m pickup is
not). Inside :attr:`LearnedDomain.tolerance` (10%) nothing is said; between the two, a warning."""


@dataclass(frozen=True)
class LearnedDomain:
    """What a model was trained on: the object classes and the box sizes (metres) it has seen.

    ``size_min``/``size_max``: (length, width, height) ranges of all the training boxes;
    ``class_sizes``: ``{class: ((l, w, h) min, (l, w, h) max)}`` per class (empty in older checkpoints: the
    overall range serves every class). A box whose class is not in ``classes`` or whose size leaves its
    class's range widened by ``tolerance`` (a fraction: 0.1 = 10%) gets a warning: the completion is an
    extrapolation (a car stretched over a truck's box). :meth:`gate` says which boxes are not completed at all.
    Checkpoints record it as ``checkpoint["domain"] = {"classes": [...], "size_min": [l, w, h],
    "size_max": [l, w, h], "class_sizes": {class: [[l, w, h], [l, w, h]]}}`` (training writes it from the
    train split, :meth:`from_training_set`); older ones get :data:`CARS_DOMAIN` (car only).
    """

    classes: tuple = ("car",)
    size_min: tuple = (3.449, 1.733, 1.359)
    size_max: tuple = (5.593, 2.412, 1.894)
    tolerance: float = 0.10
    source: str = "the 79 ApolloScape cars (length, width, height ranges)"
    class_sizes: dict = field(default_factory=dict)

    @classmethod
    def from_training_set(cls, categories, sizes, source: str, tolerance: float = 0.10, classes=None) -> LearnedDomain:
        """The domain of a training split: its classes, its box ranges, overall and per class.

        Parameters
        ----------
        categories : (n,) str, each training model's category (body type, e.g. ``sedan``); mapped
            through :data:`BODY_TYPE_CLASS` (a category not in it is kept as its own class name) unless
            ``classes`` is given.
        sizes : (n, 3) float, each training model's box (length, width, height) in metres (the
            dataset's ``/models/size``: after any augmentation, so scaled copies widen the range).
        source : what the domain was read from (e.g. the dataset path and split), kept in the record.
        classes : (n,) str, each training model's detector class (the dataset's ``/models/class``), or None.
        """
        sizes = np.asarray(sizes, dtype=np.float64).reshape(-1, 3)
        if len(sizes) == 0 or len(sizes) != len(categories):
            raise ParameterError(
                f"{source}: need one size per category and at least one model, got "
                f"{len(categories)} categories and {len(sizes)} sizes"
            )
        if classes is None:
            names = [BODY_TYPE_CLASS.get(str(c).lower(), str(c).lower()) for c in categories]
        else:
            names = [canonical_class(c) for c in classes]
        order = list(dict.fromkeys(names))
        per = {}
        for c in order:
            rows = sizes[[n == c for n in names]]
            per[c] = (tuple(float(v) for v in rows.min(axis=0)), tuple(float(v) for v in rows.max(axis=0)))
        return cls(
            tuple(order),
            tuple(float(v) for v in sizes.min(axis=0)),
            tuple(float(v) for v in sizes.max(axis=0)),
            float(tolerance),
            str(source),
            per,
        )

    @classmethod
    def from_dataset(cls, path, split: str = "train") -> LearnedDomain:
        """:meth:`from_training_set` of one split of a completion dataset file (``.h5`` or shard index)."""
        store = open_dataset(path)
        try:
            if store.size is None:
                raise InputFileError(path, "the file has no /models/size (each model's box): no domain to read")
            rows = np.flatnonzero(store.splits == split)
            return cls.from_training_set(
                store.categories[rows],
                store.size[rows],
                source=f"{Path(path).name}, {split} split ({len(rows)} models)",
                classes=None if store.stored_classes is None else store.classes[rows],
            )
        finally:
            store.close()

    def to_dict(self) -> dict:
        """The checkpoint record (``checkpoint["domain"]``) that :meth:`from_checkpoint` reads back."""
        out = {
            "classes": list(self.classes),
            "size_min": [float(v) for v in self.size_min],
            "size_max": [float(v) for v in self.size_max],
            "tolerance": float(self.tolerance),
            "source": self.source,
        }
        if self.class_sizes:
            out["class_sizes"] = {c: [list(lo), list(hi)] for c, (lo, hi) in self.class_sizes.items()}
        return out

    @classmethod
    def from_checkpoint(cls, ckpt: dict) -> LearnedDomain:
        d = ckpt.get("domain") if isinstance(ckpt, dict) else None
        if not isinstance(d, dict):
            return cls()
        try:
            per = {
                str(c): (tuple(float(v) for v in lo), tuple(float(v) for v in hi))
                for c, (lo, hi) in (d.get("class_sizes") or {}).items()
            }
            return cls(
                tuple(str(c) for c in d.get("classes", ("car",))),
                tuple(float(v) for v in d["size_min"]),
                tuple(float(v) for v in d["size_max"]),
                float(d.get("tolerance", 0.10)),
                str(d.get("source", "the checkpoint's training boxes")),
                per,
            )
        except (KeyError, TypeError, ValueError):
            return cls()

    def size_range(self, cls_name: str | None) -> tuple[np.ndarray, np.ndarray]:
        """(3,) float64 min and max (length, width, height) the model learned for class ``cls_name`` (its own
        range where recorded, else the overall one)."""
        lo, hi = self.class_sizes.get(canonical_class(cls_name) if cls_name else "", (self.size_min, self.size_max))
        return np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)

    def _outside(self, cls_name, size, tolerance: float) -> list[str]:
        lo, hi = self.size_range(cls_name)
        lo, hi = lo * (1.0 - tolerance), hi * (1.0 + tolerance)
        sz = np.asarray(size, dtype=np.float64).reshape(3)
        bad = [f"{n} {v:.2f} m" for n, v, a, b in zip(("length", "width", "height"), sz, lo, hi) if not a <= v <= b]
        if not bad:
            return []
        return [
            "size outside the learned range ("
            + ", ".join(bad)
            + "; learned "
            + " x ".join(f"{a:.1f}-{b:.1f}" for a, b in zip(lo, hi))
            + " m)"
        ]

    def learned(self, cls_name: str | None) -> bool:
        """True when the model learned class ``cls_name`` (``None``, no class given: True, the size decides)."""
        return cls_name is None or canonical_class(cls_name) in self.classes

    def warnings(self, cls_name: str | None, size) -> list[str]:
        """Human-readable reasons why a box of class ``cls_name`` (None = unknown) and ``size`` (l, w, h) is
        outside what the model learned; empty when it is inside."""
        out = []
        if not self.learned(cls_name):
            out.append(f"class {cls_name} is not one the model learned ({', '.join(self.classes)})")
        return out + self._outside(cls_name if self.learned(cls_name) else None, size, self.tolerance)

    def gate(self, cls_name: str | None, size, tolerance: float = GATE_TOLERANCE) -> str | None:
        """Why a box must not be completed (it would be an extrapolation), or None when it may be.

        ``"class"``: its class is not one the model learned; ``"size"``: a length, width or height beyond
        its class's learned range widened by ``tolerance`` (:data:`GATE_TOLERANCE`). A box without a class
        (``None``) is judged by the overall size range."""
        if not self.learned(cls_name):
            return "class"
        return "size" if self._outside(cls_name, size, tolerance) else None


CARS_DOMAIN = LearnedDomain()
"""The domain of every checkpoint trained on the shipped car dataset (l 3.45-5.59 m, w 1.73-2.41 m, h 1.36-1.89 m)."""
