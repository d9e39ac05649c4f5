"""A completed frame drawn: the bird's-eye raster (the default), matplotlib's close-ups where asked, the
interactive HTML page."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..viz import SceneObject, html, scene_png, write_png
from ..viz.bev import bev_png, xy_of
from .results import ObjectResult, SceneResult

#: The legend's line on the boxes' labels.
ID_NOTE = "boxes: object id, as in the PLY"


def scene_objects(result: SceneResult) -> list:
    """The completed objects of a scene as :class:`spotlights.viz.SceneObject` (scan frame): box, partial
    input, completion, labelled with their ``object`` ids (as in the PLY); then the objects left as their
    observed points because the model did not learn them (status ``not_learned``: box and points, no
    completion), so a picture shows what was not completed too."""
    objs = []
    for o in result.completed:
        objs.append(
            SceneObject(
                label=str(o.object_id),
                box=o.used_box if o.used_box is not None else o.box,
                partial=result.points[o.input_indices],
                completion=o.completion,
                caption=_caption(o),
            )
        )
    for o in result.objects:
        if o.status == "not_learned":
            objs.append(
                SceneObject(
                    label=str(o.object_id),
                    box=o.box,
                    partial=result.points[o.input_indices],
                    completion=None,
                    caption=f"{o.box.cls or o.box.label or 'box'}: {len(o.input_indices)} pts in box, not learned: "
                    "left as observed",
                )
            )
    return objs


def bev_scene(result: SceneResult) -> tuple[np.ndarray, list]:
    """What the bird's-eye picture of ``result`` draws, and no more: the scan's (N, 2) float32 x, y and
    :func:`scene_objects` with (K, 2) float32 x, y inputs and completions (scan frame, metres); a tenth of the
    result's bytes, for a picture process (each frame's result is pickled to it)."""
    objects = [
        dataclasses.replace(
            o,
            partial=_xy32(o.partial),
            completion=None if o.completion is None else _xy32(o.completion),
        )
        for o in scene_objects(result)
    ]
    return _xy32(result.points), objects


def _xy32(points) -> np.ndarray:
    """:func:`~spotlights.viz.bev.xy_of` as a contiguous float32 copy (the bytes a picture process is sent)."""
    return np.ascontiguousarray(xy_of(points), dtype=np.float32)


def bev_scene_png(scan_xy: np.ndarray, objects: list, title: str | None = None) -> bytes:
    """The PNG bytes of the bird's-eye picture of :func:`bev_scene`'s ``(scan_xy, objects)``."""
    return bev_png(scan_xy, objects, title=title, id_note=ID_NOTE)


def render_result(result: SceneResult, path: str | Path, title: str | None = None, closeups: bool = False) -> Path:
    """Draw a completed scene into a PNG (atomic write): a bird's-eye view (grey scan, purple inputs, green
    completions, box outlines labelled with their ``object`` ids, a scale bar, the objects' captions), and with
    ``closeups`` a 3-D close-up of every completed object seen from the sensor (box wireframe, 1 m ruler): the
    bytes of :func:`result_png`."""
    return write_png(result_png(result, title, closeups), path)


def result_png(result: SceneResult, title: str | None = None, closeups: bool = False) -> bytes:
    """The PNG bytes :func:`render_result` writes: the bird's-eye raster (:func:`spotlights.viz.bev.bev_png`, a few
    hundredths of a second), or with ``closeups`` matplotlib's figure with a close-up per object
    (:func:`spotlights.viz.scene_png`, most of a second); a picklable function of a picklable :class:`SceneResult`,
    so another process can draw them (``real complete``'s picture processes)."""
    if closeups:
        return scene_png(result.points, scene_objects(result), title=title, id_note=ID_NOTE)
    return bev_scene_png(*bev_scene(result), title=title)


def render_result_html(
    result: SceneResult, path: str | Path, title: str | None = None, plotlyjs: str | None = None
) -> Path:
    """The same scene as one interactive HTML page (:mod:`spotlights.viz.html`): self-contained, or with
    ``plotlyjs`` a relative path to a shared local copy of plotly.js (:func:`spotlights.viz.html.write_plotlyjs`)."""
    fig = html.page([("scene", html.scene_traces(result.points, scene_objects(result)))], title or "")
    return html.write_html(path, fig, plotlyjs=plotlyjs)


def _caption(o: ObjectResult) -> str:
    return (
        f"{o.box.cls or o.box.label or 'box'}: {len(o.input_indices)} pts in box, {len(o.completion)} completed"
        + (f" by {o.completed_by}" if o.completed_by else "")
        + (", heading flipped" if o.flipped else "")
        + (" [outside learned domain]" if o.warnings else "")
    )
