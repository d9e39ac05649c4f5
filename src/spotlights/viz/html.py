"""The interactive viewer: one self-contained HTML page (plotly), rotatable, equal axes, opens offline.

The page embeds plotly's JavaScript (no script is fetched from the network), so it opens
from a file on a laptop after ``scp``, with no server and no display on the machine that
wrote it: the remedy for 3-D windows that cannot open over SSH. Colours follow the static
pictures: raw scan grey, partial input purple, completion green, boxes black wireframes
labelled with their ids.

Functions return lists of plotly traces (``*_traces``); :func:`page` lays them out and
:func:`write_html` writes the page atomically. plotly is an optional extra
(``pip install 'spotlights[viewer]'``).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..data.real.boxfiles import read_json_boxes
from ..data.real.extract import read_observations
from ..data.real.frames import frame_rows
from ..errors import InputFileError, SpotlightsError
from ..geometry.box_json import box_from_dict
from ..geometry.boxes import BOX_EDGES, Box
from ..geometry.encode import decode, load_encoding
from ..geometry.io import MESH_SUFFIXES, POINT_SUFFIXES, load_mesh, load_ply_fields, load_points, ply_has_faces
from ..inputs import read_json
from ..outputs import atomic_output
from .encoding import encoding_layers, viewpoint_rays
from .scene import bev_window, frame_objects, read_frame_scan

GREY, PURPLE, GREEN, BLUE = "#9a9a9a", "#8e44ad", "#27ae60", "#4a78c2"
HIT, MISS = "#2a9d3f", "#f4a261"
#: marker size (px) per role
SIZES = {"raw": 1.5, "partial": 3.0, "completion": 2.0, "points": 2.0}
#: what a ``source`` value of a scene PLY means (written by ``complete --boxes``)
SOURCES = {
    0: ("raw scan", GREY, "raw"),
    1: ("partial input", PURPLE, "partial"),
    2: ("completion", GREEN, "completion"),
}
#: What to give instead of a folder, where one file is expected (``view``, ``show``).
FOLDER_HINT = (
    "give its files (meshes, point clouds, encodings .npz, boxes .json, observations .h5); a dataset folder is "
    "read by 'spotlights real extract' or 'spotlights real complete'"
)

MAX_POINTS = 400_000  # per trace, beyond which a cloud is subsampled (evenly, deterministic)


def require_plotly():
    """Import plotly, or raise a one-line error saying how to install it."""
    try:
        import plotly.graph_objects as go
    except ImportError:
        raise SpotlightsError(
            "the HTML viewer needs plotly: pip install 'spotlights[viewer]' (or: pip install plotly)"
        ) from None
    return go


def _thin(points: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """(points[idx], idx): at most ``max_points`` rows, evenly spaced (deterministic)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    idx = np.arange(len(p)) if len(p) <= max_points else np.linspace(0, len(p) - 1, max_points).astype(np.int64)
    return p[idx], idx


def points_trace(
    points: np.ndarray,
    name: str,
    color="#1f77b4",
    size: float = 2.0,
    group: str | None = None,
    colorbar: str | None = None,
    cmap: str = "Turbo",
    cmin=None,
    cmax=None,
    hover: str | None = None,
    max_points: int = MAX_POINTS,
):
    """A Scatter3d of (K, 3) points: one colour, or (K,) values with a colour bar titled ``colorbar``."""
    go = require_plotly()
    p, idx = _thin(points, max_points)
    label = (
        name
        if len(p) == len(np.asarray(points).reshape(-1, 3))
        else f"{name} (every {len(points) / len(p):.1f}th point)"
    )
    marker = dict(size=size, opacity=1.0)
    if isinstance(color, np.ndarray):
        marker.update(
            color=np.asarray(color)[idx],
            colorscale=cmap,
            cmin=cmin,
            cmax=cmax,
            colorbar=dict(title=dict(text=colorbar or "", side="right"), thickness=14, len=0.7) if colorbar else None,
            showscale=bool(colorbar),
        )
    else:
        marker["color"] = color
    return go.Scatter3d(
        x=p[:, 0],
        y=p[:, 1],
        z=p[:, 2],
        mode="markers",
        name=label,
        legendgroup=group or name,
        marker=marker,
        hovertemplate=(hover or name) + "<br>x %{x:.3f}<br>y %{y:.3f}<br>z %{z:.3f}<extra></extra>",
    )


def segments_trace(
    starts: np.ndarray,
    ends: np.ndarray,
    name: str,
    color: str,
    width: float = 2.0,
    dash: str = "solid",
    group: str | None = None,
    showlegend: bool = True,
):
    """A Scatter3d of line segments ``starts[i] -> ends[i]`` ((S, 3) each), in one trace."""
    go = require_plotly()
    s, e = np.asarray(starts, dtype=np.float64).reshape(-1, 3), np.asarray(ends, dtype=np.float64).reshape(-1, 3)
    xyz = np.full((3 * len(s), 3), np.nan)
    xyz[0::3], xyz[1::3] = s, e
    return go.Scatter3d(
        x=xyz[:, 0],
        y=xyz[:, 1],
        z=xyz[:, 2],
        mode="lines",
        name=name,
        legendgroup=group or name,
        showlegend=showlegend,
        connectgaps=False,
        line=dict(color=color, width=width, dash=dash),
        hoverinfo="skip",
    )


def mesh_traces(mesh, name: str, color: str = BLUE) -> list:
    """A shaded Mesh3d of a triangle mesh (anything with ``vertices`` (V, 3) and ``faces`` (F, 3))."""
    go = require_plotly()
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    return [
        go.Mesh3d(
            x=v[:, 0],
            y=v[:, 1],
            z=v[:, 2],
            i=f[:, 0],
            j=f[:, 1],
            k=f[:, 2],
            name=f"{name} ({len(f)} faces)",
            color=color,
            flatshading=True,
            showlegend=True,
            legendgroup=name,
            lighting=dict(ambient=0.35, diffuse=0.8, specular=0.1, roughness=0.9, facenormalsepsilon=0),
            lightposition=dict(x=5e4, y=-5e4, z=1e5),
            hoverinfo="name",
        )
    ]


def box_traces(boxes: Sequence[Box], name: str = "boxes", color: str = "black") -> list:
    """Wireframes of oriented boxes (:class:`~spotlights.geometry.boxes.Box`) with their ``label`` as text."""
    go = require_plotly()
    if not boxes:
        return []
    starts, ends, tops, labels = [], [], [], []
    for b in boxes:
        k = b.corners()
        for a, c in BOX_EDGES:
            starts.append(k[a])
            ends.append(k[c])
        tops.append(k[0::2].mean(axis=0) + np.array([0.0, 0.0, 0.15 * float(np.max(b.size))]))  # top face: even
        labels.append(b.label)
    out = [segments_trace(np.array(starts), np.array(ends), name, color, 2.0, group=name)]
    t = np.array(tops)
    out.append(
        go.Scatter3d(
            x=t[:, 0],
            y=t[:, 1],
            z=t[:, 2],
            mode="text",
            text=labels,
            name=f"{name}: ids",
            legendgroup=name,
            showlegend=False,
            textfont=dict(size=12, color=color),
            hoverinfo="text",
        )
    )
    return out


def scene_traces(scan: np.ndarray | None, objects: Sequence, name: str = "", margin: float | None = 15.0) -> list:
    """A whole scene: raw scan (grey), each object's partial input (purple) and completion (green),
    boxes as wireframes labelled with their ids. ``objects``: :class:`~spotlights.viz.scene.SceneObject`.

    ``margin``: the raw scan is cut to the boxes' bird's-eye window grown by this many metres
    (and the sensor), so that the page opens on the objects; None keeps the whole scan.
    """

    pre = f"{name}: " if name else ""
    out = []
    if scan is not None and len(scan):
        scan = np.asarray(scan, dtype=np.float64).reshape(-1, 3)
        n_all, label = len(scan), "raw scan"
        if margin is not None and len(objects):
            lo, hi = bev_window(objects, margin)
            scan = scan[np.all((scan[:, :2] >= lo) & (scan[:, :2] <= hi), axis=1)]
            if len(scan) < n_all:
                label = f"raw scan within {margin:g} m of the boxes"
        out.append(
            points_trace(scan, f"{pre}{label} ({len(scan)} of {n_all} pts)", GREY, SIZES["raw"], group=f"{pre}raw")
        )
    partial = [np.asarray(o.partial, dtype=np.float64).reshape(-1, 3) for o in objects]
    comps = [np.asarray(o.completion, dtype=np.float64).reshape(-1, 3) for o in objects if o.completion is not None]
    if comps:
        c = np.concatenate(comps)
        out.append(
            points_trace(c, f"{pre}completion ({len(c)} pts)", GREEN, SIZES["completion"], group=f"{pre}completion")
        )
    if partial:
        p = np.concatenate(partial)
        out.append(
            points_trace(p, f"{pre}partial input ({len(p)} pts)", PURPLE, SIZES["partial"], group=f"{pre}partial")
        )
    out += box_traces([o.box.replace(label=str(o.label)) for o in objects], f"{pre}boxes")
    return out


def encoding_traces(encoding, name: str, clip: float | None = None, rays: int | None = None) -> list:
    """An encoding's decoded hits (unit frame) coloured by viewpoint (colour bar), the unit sphere's
    equator and meridians, and on request one viewpoint's ray bundle (hits green, misses orange)."""

    layers, mask = encoding_layers(encoding, clip)
    rig = encoding.rig
    lay = layers[0]
    out = [
        points_trace(
            lay.points,
            f"{name}: {int(mask.sum())}/{rig.n_rays} hits",
            np.asarray(lay.color),
            2.5,
            group=name,
            colorbar="viewpoint",
            cmin=0,
            cmax=max(rig.n_primary - 1, 1),
        )
    ]
    t = np.linspace(0, 2 * np.pi, 97)
    circles = [
        np.c_[np.cos(t), np.sin(t), 0 * t],
        np.c_[np.cos(t), 0 * t, np.sin(t)],
        np.c_[0 * t, np.cos(t), np.sin(t)],
    ]
    ring = np.concatenate([c[:-1] for c in circles])
    ring_end = np.concatenate([c[1:] for c in circles])
    out.append(segments_trace(ring, ring_end, "unit sphere", "#c8c8c8", 1.0, group="unit sphere"))
    if rays is not None:
        b = viewpoint_rays(encoding, int(rays), clip)
        out.append(
            segments_trace(
                b["hit_start"], b["hit_end"], f"viewpoint {rays}: {len(b['hit_end'])} hits", HIT, 2.0, group="rays"
            )
        )
        out.append(
            segments_trace(
                b["miss_start"],
                b["miss_end"],
                f"viewpoint {rays}: {len(b['miss_end'])} misses",
                MISS,
                1.5,
                dash="dash",
                group="rays",
            )
        )
        go = require_plotly()
        o = b["origin"]
        out.append(
            go.Scatter3d(
                x=[o[0]],
                y=[o[1]],
                z=[o[2]],
                mode="markers",
                name=f"viewpoint {rays}",
                marker=dict(size=6, color="red"),
                legendgroup="rays",
            )
        )
    return out


def sample_traces(sample: dict, rig, clip: float | None = None) -> list:
    """A dataset sample in its unit frame: ground truth (grey), Spotlights points decoded from the
    ground-truth depths with ``rig`` (green), partial scan (purple), and a line toward the sensor.
    ``sample``: a dict of :meth:`~spotlights.data.store.CompletionDataset.sample`."""

    gt = np.asarray(sample["gt_points"], dtype=np.float64)
    spot, mask = decode(sample["gt_depths"], rig, clip)
    partial = np.asarray(sample["partial"], dtype=np.float64)
    sensor = np.asarray(sample["sensor_to_unit"], dtype=np.float64)[:3, 3]
    toward = sensor / max(float(np.linalg.norm(sensor)), 1e-12)
    return [
        points_trace(gt, f"uniform ground truth ({len(gt)} pts)", GREY, 2.0),
        points_trace(spot[mask], f"Spotlights {rig.name} ({int(mask.sum())}/{rig.n_rays} hits)", GREEN, 2.5),
        points_trace(partial, f"partial scan ({len(partial)} pts)", PURPLE, 3.5),
        segments_trace(np.zeros((1, 3)), 0.95 * toward[None], "toward the sensor", "black", 5.0),
    ]


def page(panels: Sequence[tuple[str, list]], title: str = "", side_by_side: bool = False):
    """A plotly Figure: every panel's traces in one 3-D scene (overlay), or one scene per panel.

    ``panels``: ``(panel title, traces)``. Scenes have equal axes (aspectmode "data") and are rotatable.
    """
    go = require_plotly()
    scene = dict(
        aspectmode="data",
        xaxis=dict(title="x"),
        yaxis=dict(title="y"),
        zaxis=dict(title="z"),
        camera=dict(eye=dict(x=-1.5, y=-1.5, z=1.1), up=dict(x=0, y=0, z=1)),
    )
    if side_by_side and len(panels) > 1:
        from plotly.subplots import make_subplots

        fig = make_subplots(
            rows=1,
            cols=len(panels),
            specs=[[{"type": "scene"}] * len(panels)],
            subplot_titles=[t for t, _ in panels],
            horizontal_spacing=0.02,
        )
        for j, (_, traces) in enumerate(panels):
            for tr in traces:
                fig.add_trace(tr, row=1, col=j + 1)
        fig.update_scenes(**scene)
    else:
        fig = go.Figure()
        for _, traces in panels:
            for tr in traces:
                fig.add_trace(tr)
        fig.update_layout(scene=scene)
    fig.update_layout(
        title=dict(text=title, x=0.01, font=dict(size=14)),
        template="plotly_white",
        legend=dict(
            itemsizing="constant", bgcolor="rgba(255,255,255,0.8)", x=0.01, y=0.98, xanchor="left", yanchor="top"
        ),
        margin=dict(l=0, r=0, t=40 if title else 10, b=0),
        uirevision="keep",
    )
    return fig


def write_html(path: str | os.PathLike, fig, plotlyjs: str | None = None) -> Path:
    """Write a plotly Figure as one page, atomically.

    ``plotlyjs`` None (default): plotly.js embedded, the page is self-contained (no network).
    Otherwise a *relative* path from the page to a shared copy written by :func:`write_plotlyjs`
    (for folders of many pages: one copy of the 4.7 MB script; the folder stays offline).
    """
    text = page_text(fig, plotlyjs)
    with atomic_output(path, suffix=".html") as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return Path(path)


def page_text(fig, plotlyjs: str | None = None) -> str:
    """The page :func:`write_html` writes, as a string (``view --serve`` answers it from memory)."""
    import html as _html

    if plotlyjs is not None and ("://" in plotlyjs or plotlyjs.startswith("/")):
        raise ValueError(f"plotlyjs must be a relative path to a local copy, got {plotlyjs!r}")
    text = fig.to_html(
        include_plotlyjs=True if plotlyjs is None else plotlyjs,
        full_html=True,
        include_mathjax=False,
        config={"displaylogo": False, "responsive": True, "scrollZoom": True},
        default_width="100%",
        default_height="100vh",
    )
    name = _html.escape(fig.layout.title.text or "spotlights view")
    text = text.replace(
        "<head>",
        f'<head><meta charset="utf-8"><title>{name}</title>'
        "<style>html, body {margin: 0; height: 100%; overflow: hidden}</style>",
        1,
    )
    return text


def write_plotlyjs(folder: str | os.PathLike) -> Path:
    """Write plotly.js (the version plotly.py embeds) as ``FOLDER/plotly.min.js`` once; returns its path."""
    require_plotly()
    from plotly.offline import get_plotlyjs

    path = Path(folder) / "plotly.min.js"
    if not path.exists():
        with atomic_output(path, suffix=".js") as tmp:
            Path(tmp).write_text(get_plotlyjs(), encoding="utf-8")
    return path


# --- files -> traces (``spotlights view``) -------------------------------------------------------
def scene_ply_traces(fields: dict[str, np.ndarray], name: str) -> list:
    """Traces of a scene PLY with a ``source`` field (0 raw grey, 1 partial purple, 2 completion green);
    an ``object`` field names each object's points in the hover text."""
    pts = np.stack([fields["x"], fields["y"], fields["z"]], axis=1).astype(np.float64)
    src = np.asarray(fields["source"]).astype(np.int64)
    obj = np.asarray(fields["object"]).astype(np.int64) if "object" in fields else None
    out = []
    for code in (0, 2, 1):  # raw first, partial input last (drawn on top)
        sel = src == code
        if not sel.any():
            continue
        label, color, role = SOURCES[code]
        out.append(
            points_trace(
                pts[sel], f"{name}: {label} ({int(sel.sum())} pts)", color, SIZES[role], group=f"{name}:{role}"
            )
        )
        if obj is not None and code != 0:
            n_obj = len(np.unique(obj[sel][obj[sel] >= 0]))
            out[-1].name += f", {n_obj} object{'s' if n_obj != 1 else ''}"
            out[-1].customdata = obj[sel][_thin(pts[sel])[1]]
            out[
                -1
            ].hovertemplate = (
                f"{label}, object %{{customdata}}<br>x %{{x:.3f}}<br>y %{{y:.3f}}<br>z %{{z:.3f}}<extra></extra>"
            )
    unknown = ~np.isin(src, list(SOURCES))
    if unknown.any():
        out.append(
            points_trace(pts[unknown], f"{name}: source {sorted(set(src[unknown].tolist()))[:5]}", "#1f77b4", 2.0)
        )
    return out


def read_boxes_json(path: str | os.PathLike) -> list[Box]:
    """Boxes from JSON, read by the project's one box parser (:func:`spotlights.geometry.box_json.box_from_dict`): a
    generic box file (one box, a list, or ``{"boxes": [...]}``) or a completion summary (``{"objects": [{"box":
    ...}]}``, its boxes as :meth:`Box.to_dict` writes them). Each box's ``label`` here is its id in the picture:
    its track id, else its label, else its index."""
    data = read_json(path)
    if isinstance(data, dict) and isinstance(data.get("objects"), list):  # a summary: rotation given, yaw derived
        items = [o.get("box", o) if isinstance(o, dict) else o for o in data["objects"]]
        items = [
            {k: v for k, v in d.items() if not ("rotation" in d and k == "yaw")} if isinstance(d, dict) else d
            for d in items
        ]
        boxes = [box_from_dict(d, path, f"object {i} box") for i, d in enumerate(items)]
    else:
        boxes = list(read_json_boxes(path, require_label=False).boxes)
    if not boxes:
        raise InputFileError(path, "no box in the file (expected a box, a list of boxes, or {'boxes': [...]})")
    return [b.replace(label=str(b.track_id or b.label or i)) for i, b in enumerate(boxes)]


def file_traces(
    path: str | os.PathLike,
    rays: int | None = None,
    clip: float | None = None,
    up: str = "z",
    forward: str = "x",
    max_points: int = MAX_POINTS,
) -> tuple[list, str]:
    """Traces of one file, by kind: mesh, encoding (.npz with ``depths``), point cloud, scene PLY
    (``source``/``object`` fields), boxes (.json), observations (.h5 from ``real extract``: its
    busiest frame). Returns (traces, a one-line description)."""

    src = Path(path)
    name = src.name
    suffix = src.suffix.lower()
    if not src.exists():
        raise InputFileError(src, "no such file")
    if src.is_dir():
        raise InputFileError(src, f"is a folder: {FOLDER_HINT}")
    if suffix == ".json":
        boxes = read_boxes_json(src)
        return box_traces(boxes, f"{name}: boxes"), f"{len(boxes)} box{'es' if len(boxes) != 1 else ''}"
    if suffix == ".npz":
        try:
            with np.load(src, allow_pickle=False) as z:
                is_encoding = "depths" in z.files
        except Exception as exc:
            raise InputFileError(src, f"not a readable .npz file ({type(exc).__name__})") from None
        if is_encoding:
            enc = load_encoding(src)
            return encoding_traces(enc, name, clip, rays), f"encoding ({enc.rig.name})"
    if rays is not None:
        raise InputFileError(src, "--rays needs an encoding (.npz from 'spotlights encode')")
    if suffix in (".h5", ".hdf5"):
        return _observation_traces(src)
    if suffix in MESH_SUFFIXES and (suffix != ".ply" or ply_has_faces(src)):
        mesh = load_mesh(src, up=up, forward=forward)
        return mesh_traces(mesh, name), f"mesh ({len(mesh.vertices)} vertices, {len(mesh.faces)} faces)"
    if suffix == ".ply":
        fields = load_ply_fields(src)
        if "source" in fields:
            return scene_ply_traces(fields, name), f"scene ({len(fields['x'])} points with sources)"
    if suffix in POINT_SUFFIXES:
        pts = load_points(src)
        return [
            points_trace(pts, f"{name} ({len(pts)} pts)", "#1f77b4", SIZES["points"], max_points=max_points)
        ], f"point cloud ({len(pts)} points)"
    raise InputFileError(
        src, f"unknown file type {suffix!r} (a mesh, a point cloud, an encoding .npz, boxes .json or observations .h5)"
    )


def _observation_traces(path: Path) -> tuple[list, str]:

    obs = read_observations(path)
    rows = frame_rows(obs)
    scan = read_frame_scan(obs, rows[0])
    return scene_traces(
        scan, frame_objects(obs, rows), path.name
    ), f"frame {obs.frame_id[rows[0]]} ({len(rows)} objects)"
