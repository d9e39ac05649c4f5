"""Whole scenes: raw scan (grey), partial inputs (purple), completions (green), boxes with their ids.

Everything is drawn in the **sensor frame** of the scan. Left: a bird's-eye view of the
scan around the objects (points subsampled, boxes outlined and labelled with their ids,
a scale bar). Right: a close-up of each object seen from the sensor's side (as the
LiDAR saw it), with its box as a wireframe, a 1 m ruler, and the raw points *around* the
box (within 1 m, outside the box) as context: the raw points inside the box are the
object's own, drawn as the purple partial input, so no grey point hides them.

:func:`render_scene` takes arrays (any reader, ``complete --boxes``);
:func:`render_frame` draws rows of an observation file (``spotlights real show``).
"""

from __future__ import annotations

import math
import os
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..data.real import read_scan
from ..errors import InputFileError, ParameterError
from ..geometry.boxes import BOX_EDGES, Box
from ._figure import add_scale_bar, new_figure, png_bytes, write_png
from .points import Layer, merge_layers
from .raster import splat_points, view_basis

GREY, PURPLE, GREEN = "#9a9a9a", "#8e44ad", "#27ae60"
CLOSEUP_TITLE_WIDTH = 44
"""Characters per line of a close-up's title (wrapped beyond: three close-ups share a row)."""


@dataclass
class SceneObject:
    """One object of a scene, everything in the scan's sensor frame (metres).

    label : the id drawn beside its box (track id, object id).
    box : its :class:`~spotlights.geometry.boxes.Box` (``center``, ``size``, ``rotation`` read through).
    partial : (K, 3) the points the model was given (purple).
    completion : (L, 3) the model's completion (green), or None.
    caption : a line under the close-up's id (class, point counts, ...).
    """

    label: str
    box: Box
    partial: np.ndarray
    completion: np.ndarray | None = None
    caption: str = ""

    @property
    def center(self) -> np.ndarray:
        return self.box.center

    @property
    def size(self) -> np.ndarray:
        return self.box.size

    @property
    def rotation(self) -> np.ndarray:
        return self.box.rotation

    @property
    def reach(self) -> float:
        """Half the box diagonal, metres (:attr:`Box.radius <spotlights.geometry.boxes.Box.radius>`)."""
        return self.box.radius

    def corners(self) -> np.ndarray:
        """(8, 3) box corners (order of :data:`~spotlights.geometry.boxes.CORNER_SIGNS`)."""
        return self.box.corners()

    def inside(self, points: np.ndarray, margin: float = 0.15) -> np.ndarray:
        """(N,) bool: points inside the box grown by ``margin`` metres on every side."""
        return self.box.contains(points, margin)


def to_sensor(points_unit: np.ndarray, unit_to_sensor: np.ndarray) -> np.ndarray:
    """(K, 3) unit-frame points -> (K, 3) float64 sensor frame, with a (4, 4) unit->sensor matrix."""
    p = np.asarray(points_unit, dtype=np.float64).reshape(-1, 3)
    return p @ unit_to_sensor[:3, :3].T + unit_to_sensor[:3, 3]


def short_id(track_id: str, n: int = 8) -> str:
    """A track id short enough to print beside a box (UUIDs: their first ``n`` characters)."""
    t = str(track_id)
    return t[:n] if len(t) > n + 2 else t


def bev_window(objects: Sequence[SceneObject], margin: float = 8.0) -> tuple[np.ndarray, np.ndarray]:
    """(lo (2,), hi (2,)) of the bird's-eye window: every box plus ``margin`` metres, and the sensor."""
    centers = np.array([o.center[:2] for o in objects], dtype=np.float64).reshape(-1, 2)
    reach = np.array([o.reach for o in objects]).reshape(-1, 1)
    lo = np.minimum((centers - reach).min(axis=0) - margin, -3.0)
    hi = np.maximum((centers + reach).max(axis=0) + margin, 3.0)
    return lo, hi


def draw_bev(
    ax,
    scan: np.ndarray,
    objects: Sequence[SceneObject],
    max_scan_points: int = 40000,
    seed: int = 0,
    window: tuple[np.ndarray, np.ndarray] | None = None,
    legend: bool = True,
) -> None:
    """Bird's-eye view on a 2-D axes: grey scan, green completions, purple inputs, boxes with ids, sensor, scale bar."""
    lo, hi = window if window is not None else bev_window(objects)
    scan = np.asarray(scan, dtype=np.float64).reshape(-1, 3)
    bev = scan[np.all((scan[:, :2] >= lo) & (scan[:, :2] <= hi), axis=1)]
    if len(bev) > max_scan_points:
        bev = bev[np.sort(np.random.default_rng(seed).choice(len(bev), max_scan_points, replace=False))]
    ax.scatter(bev[:, 0], bev[:, 1], s=0.3, color=GREY, alpha=0.6, linewidths=0, label="raw scan", rasterized=True)
    # one scatter for every completion, then one for every input (the order each object's used to be drawn in)
    comps = [np.asarray(o.completion)[:, :2] for o in objects if o.completion is not None and len(o.completion)]
    if comps:
        c2 = np.concatenate(comps)
        ax.scatter(c2[:, 0], c2[:, 1], s=1.0, color=GREEN, linewidths=0, label="completion")
    if objects:
        p2 = np.concatenate([np.asarray(o.partial, dtype=np.float64).reshape(-1, 3)[:, :2] for o in objects])
        ax.scatter(p2[:, 0], p2[:, 1], s=2.5, color=PURPLE, linewidths=0, label="partial input")
    outlines = [np.vstack([o.corners()[[1, 3, 7, 5, 1], :2], np.full(2, np.nan)]) for o in objects]  # bottom faces
    if outlines:
        ax.plot(*np.concatenate(outlines).T, color="black", lw=0.7)  # one line for every box
    for o in objects:
        k = o.corners()
        ax.annotate(
            o.label,
            (o.center[0], k[:, 1].max() + 0.4),  # just above the box's northmost corner
            fontsize=7,
            ha="center",
            va="bottom",
            color="black",
            bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.7),
        )
    ax.plot([0], [0], marker="^", color="black", ms=6, ls="none")
    ax.annotate("sensor", (0, 0), xytext=(0, -10), textcoords="offset points", fontsize=7, ha="center", va="top")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, sensor frame)")
    ax.set_ylabel("y (m)")
    add_scale_bar(ax, label="m", loc="lower left")
    if legend:
        ax.legend(loc="upper right", fontsize=7, markerscale=4, framealpha=0.85)


def completion_marker_size(n: int) -> float:
    """Marker area (points^2) of a close-up's completion of ``n`` points: 2.0 up to 2,048 points, then
    shrinking as 1/sqrt(n) (0.75 at 15,000, floor 0.5), so a dense completion shows its surface's shape
    instead of a solid blob and the purple input stays visible among it."""
    return float(max(0.5, 2.0 * min(1.0, math.sqrt(2048.0 / max(int(n), 1)))))


CLOSEUP_ELEVATION = 20.0
"""Degrees above the horizon of a close-up's view."""


def draw_closeup(ax, scan: np.ndarray, obj: SceneObject, context: float = 1.0, dpi: float = 110.0) -> None:
    """Close-up of one object from the sensor's side, on a 2-D axes whose size is final (after the layout):
    context scan (grey, outside the box), completion (green), partial input (purple) splatted into one image
    with a depth test (orthographic view, :data:`CLOSEUP_ELEVATION` degrees up; each point a disc of its
    marker's size at ``dpi``: :func:`~spotlights.viz.raster.splat_points`), the box wireframe and a 1 m ruler."""
    c = np.asarray(obj.center, dtype=np.float64)
    reach = obj.reach
    scan = np.asarray(scan, dtype=np.float64).reshape(-1, 3)
    near = scan[np.sum((scan - c) ** 2, axis=1) <= (reach + context) ** 2]
    near = near[~obj.inside(near)]  # the object's own points are its partial input
    layers = [Layer(near, GREY, None, 0.8, 0.7)]
    if obj.completion is not None:
        layers.append(Layer(obj.completion, GREEN, None, completion_marker_size(len(obj.completion)), 1.0))
    layers.append(Layer(obj.partial, PURPLE, None, 4.0, 1.0))
    p, col, size = merge_layers(layers)
    azim = math.degrees(math.atan2(c[1], c[0])) + 180.0  # look from the sensor's side
    basis = view_basis(CLOSEUP_ELEVATION, azim)
    project = lambda q: (np.asarray(q, dtype=np.float64) - c) @ basis[:2].T  # noqa: E731 - (K, 2): right, up
    # the axes' size in pixels, and limits of equal scale that hold the sphere of radius reach + 0.3
    fig = ax.figure
    w_in, h_in = fig.get_size_inches()
    pos = ax.get_position()
    width, height = max(int(round(pos.width * w_in * dpi)), 1), max(int(round(pos.height * h_in * dpi)), 1)
    half = reach + 0.3
    hu, hv = (half * width / height, half) if width >= height else (half, half * height / width)
    if len(p):
        uv = project(p)
        px = np.stack([(uv[:, 0] + hu) / (2 * hu) * width, (hv - uv[:, 1]) / (2 * hv) * height], axis=1)
        rgb = col[:, :3] * col[:, 3:4] + (1.0 - col[:, 3:4])  # alpha over the white page
        image = splat_points(px, (p - c) @ basis[2], rgb, np.sqrt(size) * dpi / 72.0, width, height)
        ax.imshow(image, extent=(-hu, hu, -hv, hv), origin="upper", interpolation="nearest", zorder=1)
    k = project(obj.corners())
    edges = np.concatenate([np.stack([k[a], k[b], np.full(2, np.nan)]) for a, b in BOX_EDGES])  # one line
    ax.plot(*edges.T, color="black", lw=0.5, alpha=0.6, zorder=2)
    # a 1 m ruler along the box's length, on the ground beside its bottom edge that faces the sensor
    k3 = obj.corners()
    rot = np.asarray(obj.rotation, dtype=np.float64)
    # bottom edges (corners: x- and x+ at z-): +y side 5, 1; -y side 7, 3. Is the +y side nearer the sensor?
    side = 1.0 if np.linalg.norm(k3[5] + k3[1]) < np.linalg.norm(k3[7] + k3[3]) else -1.0
    start = (k3[5] if side > 0 else k3[7]) + side * rot[:, 1] * 0.3
    ruler = project(np.stack([start, start + rot[:, 0]]))
    ax.plot(*ruler.T, color="black", lw=2.0, solid_capstyle="butt", zorder=3)
    label = project(np.stack([start + 0.5 * rot[:, 0] + side * rot[:, 1] * 0.35]))[0]
    ax.text(*label, "1 m", fontsize=7, ha="center", va="top", zorder=3)
    ax.set_xlim(-hu, hu)
    ax.set_ylim(-hv, hv)
    ax.set_aspect("equal", adjustable="box")
    ax.set_axis_off()


def figure_scene(
    scan: np.ndarray,
    objects: Sequence[SceneObject],
    title: str | None = None,
    max_scan_points: int = 40000,
    seed: int = 0,
    closeups: bool = True,
    id_note: str = "boxes: object id",
    dpi: float = 110.0,
):
    """The :class:`~matplotlib.figure.Figure` of :func:`render_scene` (not saved; ``dpi``: the resolution it
    will be saved at, which the close-ups' images are drawn for)."""
    objects = list(objects)
    if not objects:
        raise ParameterError("no object to draw")
    n_obj = len(objects) if closeups else 0
    ncol = min(3, n_obj) if n_obj else 0
    nrow = math.ceil(n_obj / ncol) if n_obj else 1
    fig = new_figure(7.0 + 3.8 * ncol, max(6.5, 3.8 * nrow))
    gs = fig.add_gridspec(nrow, ncol + 2)
    ax = fig.add_subplot(gs[:, :2])
    draw_bev(ax, scan, objects, max_scan_points, seed)
    ax.set_title(f"bird's-eye view ({id_note})", fontsize=10)
    closeups = []
    for k, o in enumerate(objects[:n_obj]):
        a2 = fig.add_subplot(gs[k // ncol, 2 + k % ncol], xticks=[], yticks=[])  # no ticks to lay out
        a2.set_axis_off()
        size = " x ".join(f"{x:.1f}" for x in o.size)
        head = textwrap.fill(f"{o.label}: {o.caption}", CLOSEUP_TITLE_WIDTH) if o.caption else str(o.label)
        a2.set_title(f"{head}\nbox {size} m", fontsize=8, y=1.0)  # placed, not fitted above tick labels
        closeups.append((a2, o))
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    for a2, o in closeups:  # drawn once the layout fixed each axes' size in pixels
        draw_closeup(a2, scan, o, dpi=dpi)
    return fig


def render_scene(
    path: str | os.PathLike,
    scan: np.ndarray,
    objects: Sequence[SceneObject],
    title: str | None = None,
    max_scan_points: int = 40000,
    seed: int = 0,
    closeups: bool = True,
    dpi: int = 110,
    id_note: str = "boxes: object id",
) -> Path:
    """Draw a scene into a PNG (atomic write): bird's-eye view, plus one close-up per object.

    Parameters
    ----------
    scan : (N, 3) raw scan, sensor frame (metres).
    objects : the objects, in the order of their close-ups.
    max_scan_points : grey points drawn at most in the bird's-eye view (random subset, seeded).
    closeups : False draws the bird's-eye view alone.
    id_note : what the labels are, printed in the bird's-eye title.
    """
    return write_png(scene_png(scan, objects, title, max_scan_points, seed, closeups, dpi, id_note), path)


def scene_png(
    scan: np.ndarray,
    objects: Sequence[SceneObject],
    title: str | None = None,
    max_scan_points: int = 40000,
    seed: int = 0,
    closeups: bool = True,
    dpi: int = 110,
    id_note: str = "boxes: object id",
) -> bytes:
    """The PNG bytes :func:`render_scene` writes (same parameters, no path): for drawing in another process."""
    fig = figure_scene(scan, objects, title, max_scan_points, seed, closeups, id_note, dpi)
    return png_bytes(fig, dpi)  # tight_layout placed everything: no second draw to crop the page


def observation_label(obs, i: int) -> str:
    """The id printed for observation row ``i``: its track id (shortened), else ``#ROW`` in the file."""
    t = obs.track_id[i]
    return short_id(t) if t else f"#{i}"


def frame_objects(obs, rows: Sequence[int], completions: Sequence[np.ndarray] | None = None) -> list[SceneObject]:
    """Observation rows as :class:`SceneObject` (sensor frame): partials and completions mapped with
    each row's ``unit_to_sensor``; labels from :func:`observation_label`."""
    out = []
    for k, i in enumerate(rows):
        m = obs.unit_to_sensor[i]
        comp = to_sensor(completions[k], m) if completions is not None else None
        out.append(
            SceneObject(
                label=observation_label(obs, i),
                box=Box(obs.box_center[i], obs.box_size[i], obs.box_rotation[i]),
                partial=to_sensor(obs.partial[i], m),
                completion=comp,
                caption=f"{obs.cls[i]} ({obs.label[i]}), {int(obs.n_points_raw[i])} raw pts, {len(obs.partial[i])} input",
            )
        )
    return out


def render_frame(
    path: str | os.PathLike,
    obs,
    rows: Sequence[int],
    completions: Sequence[np.ndarray] | None = None,
    scan: np.ndarray | None = None,
    title: str | None = None,
    max_scan_points: int = 40000,
    seed: int = 0,
    dpi: int = 110,
) -> Path:
    """Draw one frame's observations into a PNG (atomic write); see :func:`render_scene`.

    Parameters
    ----------
    obs, rows : the :class:`~spotlights.data.real.extract.Observations` and the rows to draw (all of one scan).
    completions : one (K_i, 3) unit-frame array per row, or None (no green).
    scan : (N, 3) raw scan in the sensor frame, or None to read ``obs.scan_path`` of the first row.
    max_scan_points : grey points drawn at most in the bird's-eye view (random subset, seeded).
    """
    rows = list(rows)
    if not rows:
        raise ParameterError("no observation to draw")
    if scan is None:
        scan = read_frame_scan(obs, rows[0])
    tracked = any(obs.track_id[i] for i in rows)
    note = "boxes: track id" if tracked else "boxes: row in the observation file (no track ids)"
    return render_scene(
        path, scan, frame_objects(obs, rows, completions), title, max_scan_points, seed, True, dpi, note
    )


def read_frame_scan(obs, row: int) -> np.ndarray:
    """(N, 3) float64 raw scan of observation ``row`` (sensor frame), read from its ``scan_path``."""
    sp = obs.scan_path[row]
    if not Path(sp).is_file():
        raise InputFileError(sp, "raw scan not found (moved since extraction?)")
    return np.asarray(read_scan(sp), dtype=np.float64)
