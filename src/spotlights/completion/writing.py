"""A completed frame's files and lines: the scene PLY (``source``, ``object``), per-object PLYs, the one-line
description and the refusal of a frame with nothing completed."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..data.real.base import CLASSES
from ..errors import InputFileError
from ..geometry.io import save_ply, save_points
from ..outputs import atomic_output
from .scene_config import SOURCE_COMPLETION, SOURCE_PARTIAL

if TYPE_CHECKING:  # the results import this module (SceneResult.save)
    from .results import SceneResult


def check_completed(result: SceneResult, source) -> None:
    """Raise a one-line :class:`InputFileError` (naming ``source``) when no box of the scene was completed."""
    if result.completed:
        return
    sk = result.skipped()
    if not result.objects:
        raise InputFileError(source, "holds no box")
    what = ", ".join(f"{k} {v}" for k, v in sorted(sk.items()))
    labels = sorted({o.box.label for o in result.objects if o.status == "class_excluded" and o.box.label})
    hint = f" (labels: {', '.join(labels[:6])})" if labels else ""
    if sk.get("not_learned"):
        hint += " (not_learned: a class or size the model did not learn; --complete-unknown completes them)"
    raise InputFileError(
        source,
        f"no vehicle box to complete: {len(result.objects)} box(es), {what}{hint}; "
        f"classes completed: {', '.join(result.config.classes or CLASSES)}",
    )


def scene_comments(result: SceneResult, scan_name: str = "") -> list[str]:
    """PLY header comments describing a scene: fields, model, every object, warnings."""
    lines = [
        f"spotlights scene{(' of ' + scan_name) if scan_name else ''}: scan frame, metres",
        "source: 0 raw point, 1 partial input of an object, 2 completion; object: box index or track id, -1 none",
        f"model {result.model}" + (f" ({result.checkpoint})" if result.checkpoint else ""),
    ]
    for o in result.objects:
        tid = f" track {o.box.track_id}" if o.box.track_id and str(o.object_id) != o.box.track_id else ""
        lines.append(
            f"object {o.object_id}: box {o.index}{tid} {o.box.label or '-'} ({o.box.cls or '-'}) {o.status}, "
            f"{len(o.input_indices)} points in box, {len(o.completion)} completed"
            + (", heading flipped" if o.flipped else "")
        )
    lines += [f"warning: {w}" for w in result.warnings()]
    return lines


def write_scene(
    result: SceneResult, out: str | Path, per_object: str | Path | None = None, scan_name: str = ""
) -> list[Path]:
    """Write the scene: ``out`` ``.ply`` with x y z, ``source``, ``object`` (any other suffix: the completion
    points only, as ``save_points`` writes them); ``per_object`` folder: ``object_<id>.ply`` per completed
    object (its input and completion, with ``source``). Atomic writes, all or nothing: when one
    fails, those already written are removed again; returns the paths written."""
    out = Path(out)
    written: list[Path] = []
    try:
        _write_scene_files(result, out, per_object, scan_name, written)
    except BaseException:
        for p in written:
            p.unlink(missing_ok=True)
        raise
    return written


def _write_scene_files(result: SceneResult, out: Path, per_object, scan_name: str, written: list) -> None:
    if out.suffix.lower() == ".ply":
        xyz, src, obj = result.fields()
        written.append(save_ply(out, xyz, {"source": src, "object": obj}, comments=scene_comments(result, scan_name)))
    else:
        pts = np.concatenate([o.completion for o in result.completed]) if result.completed else np.zeros((0, 3))
        written.append(save_points(out, pts))
    if per_object is not None:
        folder = Path(per_object)
        for o in result.completed:
            xyz = np.concatenate([result.points[o.input_indices], o.completion])
            src = np.r_[
                np.full(len(o.input_indices), SOURCE_PARTIAL, np.uint8),
                np.full(len(o.completion), SOURCE_COMPLETION, np.uint8),
            ]
            com = [
                f"object {o.object_id}: box {o.index} {o.box.label or '-'} ({o.box.cls or '-'}), model {result.model}"
            ]
            com += [f"warning: {w}" for w in o.warnings]
            written.append(save_ply(folder / f"object_{o.object_id}.ply", xyz, {"source": src}, comments=com))


def describe(result: SceneResult) -> str:
    """One line: boxes, completed objects, skips, points, time."""
    sk = result.skipped()
    flips = sum(o.flipped for o in result.completed)
    by = fallback_counts(Counter(o.completed_by for o in result.completed if o.completed_by))
    return (
        f"{len(result.objects)} box(es): {len(result.completed)} completed"
        + (f" ({by})" if by else "")
        + (f" ({flips} heading flip{'s' if flips != 1 else ''})" if result.config.heading_check else "")
        + (", skipped " + ", ".join(f"{k} {v}" for k, v in sorted(sk.items())) if sk else "")
        + (
            " (not_learned: left as observed points, "
            + ", ".join(f"{k} {v}" for k, v in sorted(result.not_completed().items()))
            + "; --complete-unknown completes them)"
            if sk.get("not_learned")
            else ""
        )
        + f"; {sum(len(o.completion) for o in result.completed)} completion points; "
        f"{1000 * result.timings.get('total_s', 0):.0f} ms"
    )


def write_json(path: str | Path, data: dict) -> None:
    """``data`` as indented JSON (numpy scalars as floats), written atomically to ``path``."""
    with atomic_output(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=float) + "\n", encoding="utf-8")


def fallback_counts(by: dict) -> str:
    """``{fallback name: boxes it completed}`` as the summary lines say it ("4 by the fallback classes"; "" for none)."""
    return ", ".join(f"{v} by the fallback {k}" for k, v in sorted(by.items()))
