"""What a frame's completion returns: one :class:`ObjectResult` per box and the :class:`SceneResult` of the frame
(scan frame, metres), with :meth:`SceneResult.save` writing the files ``spotlights complete`` writes."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..geometry.boxes import Box
from .scene_config import SOURCE_COMPLETION, SOURCE_PARTIAL, SceneConfig
from .writing import write_json, write_scene


@dataclass
class ObjectResult:
    """One box of the scene and what happened to it.

    ``status``: ``"completed"`` or the reason it was not (``class_excluded``, ``invalid_box``,
    ``too_few_points``, ``not_learned``: a class or size the model did not learn, left as observed points,
    ``empty_completion``). Arrays (scan frame, float64, metres):
    ``completion`` (K, 3); ``input_indices`` (k,) int64 rows of the scan used as the input.
    ``partial_unit`` (256, 3) and ``completion_unit`` (K, 3) float32: the box's unit frame; ``sensor_unit`` (3,)
    float64 the LiDAR in that frame; ``seen_unit`` (K', 3) float32, with other frames fused in and ``snap``, the
    scan's own points in that frame (the occlusion rule's free space). ``box`` as given; ``used_box`` the box
    completed (turned around when ``flipped``).
    """

    index: int
    object_id: int
    box: Box
    status: str
    used_box: Box | None = None
    input_indices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    partial_unit: np.ndarray | None = None
    completion_unit: np.ndarray | None = None
    sensor_unit: np.ndarray | None = None
    completion: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    flipped: bool = False
    fidelity: float | None = None
    fidelity_flipped: float | None = None
    warnings: list = field(default_factory=list)
    n_fused: int | None = None  # input points with other frames' fused in (``extra_points``), else None
    # with other frames fused in: this scan's own points, unit frame (float32), the free space --snap's occlusion
    # rule carves from this scan's sensor (the other frames' points were seen from elsewhere); else None
    seen_unit: np.ndarray | None = None
    # share of the points inside the box grown by 0.15 m before the clamp (the network's; with --snap, snapped)
    inside_box: float | None = None
    completed_by: str | None = None  # the fallback model's name when it, not the main model, completed the box
    # with fit: True when the evidence fit was kept (it lowered the fidelity), False when the gate kept the
    # unfitted completion; None without fit (or a model that cannot be fitted)
    fitted: bool | None = None
    # with fit: the gate's choice for the given heading and, with the heading check, the turned one (internal)
    fitted_headings: tuple | None = field(default=None, repr=False)

    def summary(self) -> dict:
        """JSON-ready description (no point arrays)."""
        return (
            dict(
                index=self.index,
                object=self.object_id,
                status=self.status,
                label=self.box.label,
                cls=self.box.cls,
                track_id=self.box.track_id,
                n_points=int(len(self.input_indices)),
                n_completion=int(len(self.completion)),
                flipped=self.flipped,
                fidelity=self.fidelity,
                fidelity_flipped=self.fidelity_flipped,
                warnings=list(self.warnings),
                box=(self.used_box or self.box).to_dict(),
            )
            | ({} if self.n_fused is None else {"n_fused": self.n_fused})
            | ({} if self.inside_box is None else {"inside_box": round(float(self.inside_box), 4)})
            | ({} if self.completed_by is None else {"completed_by": self.completed_by})
            | ({} if self.fitted is None else {"fitted": self.fitted})
        )


@dataclass
class SceneResult:
    """A completed scene: the scan, every box's :class:`ObjectResult`, the model and timings (seconds)."""

    points: np.ndarray
    objects: list[ObjectResult]
    model: str
    checkpoint: str | None
    config: SceneConfig
    timings: dict = field(default_factory=dict)
    member: np.ndarray | None = None  # (N,) int64 box index of each scan point (-1: none)

    @property
    def completed(self) -> list[ObjectResult]:
        return [o for o in self.objects if o.status == "completed"]

    @property
    def xyz(self) -> np.ndarray:
        """(M, 3) float64 scan frame, metres: every scan point, then every completion (see :meth:`fields`)."""
        return self.fields()[0]

    @property
    def source(self) -> np.ndarray:
        """(M,) uint8 per point of :attr:`xyz`: 0 raw point, 1 partial input of an object, 2 completion."""
        return self.fields()[1]

    @property
    def object(self) -> np.ndarray:
        """(M,) int32 per point of :attr:`xyz`: its object's id (:func:`object_ids`), -1 outside every box."""
        return self.fields()[2]

    def skipped(self) -> dict:
        """{reason: count} of the boxes not completed."""
        out: dict = {}
        for o in self.objects:
            if o.status != "completed":
                out[o.status] = out.get(o.status, 0) + 1
        return out

    def not_completed(self) -> dict:
        """{class: count} of the boxes left as observed points because the model did not learn them (status
        ``not_learned``; a box without a class counts as ``"unknown"``)."""
        out: dict = {}
        for o in self.objects:
            if o.status == "not_learned":
                key = o.box.cls or "unknown"
                out[key] = out.get(key, 0) + 1
        return out

    def warnings(self) -> list[str]:
        """One line per warned box: ``object ID (label): reason; reason``."""
        return [
            f"object {o.object_id} ({o.box.label or o.box.cls or 'box'}): " + "; ".join(o.warnings)
            for o in self.objects
            if o.warnings
        ]

    def fields(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The scene as arrays: xyz (M, 3) float64 scan frame, ``source`` (M,) uint8, ``object`` (M,) int32.

        Raw points first (every scan point once: source 1 where it is an object's input, else 0),
        then every completion (source 2).
        """
        n = len(self.points)
        source = np.zeros(n, np.uint8)
        obj = np.full(n, -1, np.int32)
        ids = {o.index: o.object_id for o in self.objects}
        if self.member is not None:
            inside = self.member >= 0
            obj[inside] = [ids[i] for i in self.member[inside]]
        for o in self.completed:
            source[o.input_indices] = SOURCE_PARTIAL
        xyz = [self.points] + [o.completion for o in self.completed]
        src = [source] + [np.full(len(o.completion), SOURCE_COMPLETION, np.uint8) for o in self.completed]
        ob = [obj] + [np.full(len(o.completion), o.object_id, np.int32) for o in self.completed]
        return np.concatenate(xyz), np.concatenate(src), np.concatenate(ob)

    def save(
        self,
        path: str | Path,
        summary: str | Path | bool = True,
        per_object: str | Path | None = None,
        scan_name: str = "",
    ) -> list[Path]:
        """Write the files ``spotlights complete`` writes: ``path`` (``.ply``: every scan point and completion with
        ``source`` and ``object``, scan frame, metres; another point suffix: the completion points only), the JSON
        summary (:meth:`summary`, plus ``"out"``) at ``summary`` (True: ``path`` with the suffix ``.json``; False:
        none) and, with ``per_object``, ``object_<id>.ply`` per completed object in that folder. All or nothing
        (atomic writes; when one fails, those already written are removed). Returns the paths written."""
        path = Path(path)
        summary_path = path.with_suffix(".json") if summary is True else (Path(summary) if summary else None)
        if summary_path is not None and summary_path.resolve() == path.resolve():
            raise ParameterError(f"summary: {summary_path} is the points' file (path); give another name")
        written = write_scene(self, path, per_object=per_object, scan_name=scan_name)
        if summary_path is not None:
            try:
                write_json(summary_path, {"out": str(path), **self.summary()})
            except BaseException:
                for p in written:
                    p.unlink(missing_ok=True)
                raise
            written.append(summary_path)
        return written

    def summary(self) -> dict:
        """JSON-ready summary: counts, model, config, timings, warnings and every object."""
        from dataclasses import asdict

        cfg = asdict(self.config)
        cfg["clip"] = (
            str(cfg["clip"]) if cfg["clip"] is not None and not isinstance(cfg["clip"], float) else cfg["clip"]
        )
        return dict(
            n_points=int(len(self.points)),
            n_boxes=len(self.objects),
            n_completed=len(self.completed),
            n_flipped=sum(o.flipped for o in self.completed),
            skipped=self.skipped(),
            not_completed=self.not_completed(),
            model=self.model,
            checkpoint=self.checkpoint,
            config=cfg,
            timings=self.timings,
            warnings=self.warnings(),
            objects=[o.summary() for o in self.objects],
        )


def object_ids(boxes: Sequence[Box]) -> list[int]:
    """The ``object`` value of each box: its track id where it has an integer one (``"track_id": 7``), its
    index in the box list where it has none. When a track id is not an integer (nuScenes tokens, AV2 UUIDs),
    or two boxes would share a value, every box gets its index (the track ids are then in the summary and
    the PLY header)."""
    ids = []
    for i, b in enumerate(boxes):
        t = str(b.track_id).strip()
        if not t:
            ids.append(i)
        elif t.lstrip("-").isdigit() and -(2**31) < int(t) < 2**31 and int(t) != -1:
            ids.append(int(t))
        else:
            return list(range(len(boxes)))
    return ids if len(set(ids)) == len(ids) else list(range(len(boxes)))
