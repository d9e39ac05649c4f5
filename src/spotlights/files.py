"""The representation's file commands as settings and one function each: what ``spotlights encode``,
``decode``, ``show`` and ``view`` do.

- :func:`encode_meshes` (:class:`EncodeSettings`): mesh files -> depth arrays (``.npz``), one rig
  (:class:`RigOptions`: the paper's cap rig or a box rig) cast at each mesh in its object frame.
- :func:`decode_file` (:class:`DecodeSettings`): an encoding -> its ordered point cloud (original or unit frame).
- :func:`show_file` (:class:`ShowSettings`): a mesh, point cloud, scene or encoding -> a PNG (and/or HTML page).
- :func:`view_files` (:class:`ViewSettings`): any of those -> one interactive HTML page (and/or served).

Each takes a ``say`` callback for its summary lines and prints nothing otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import logs, viz
from .completion.scan import Say, silent
from .errors import InputFileError, ParameterError, SpotlightsError
from .geometry.encode import MeshProbe, hit_ratio, load_encoding, save_encoding
from .geometry.io import (
    MESH_SUFFIXES,
    POINT_SUFFIXES,
    load_mesh,
    load_ply_fields,
    load_points,
    ply_has_faces,
    save_points,
)
from .geometry.rig import RigSpec, make_rig_spec
from .outputs import check_suffix, check_writable
from .viz import html, serve
from .viz.html import SOURCES


@dataclass(kw_only=True)
class RigOptions:
    """A rig as the command-line options give it (paper defaults: 32 x 64 rays, a 60-degree cap).

    primary, secondary : viewpoints N and rays per viewpoint M; angle : the cap's polar half-angle, degrees;
    radius : alternatively the paper's r/R; rig_kind : ``cap`` or ``box``; box_targets, box_scale,
    box_cap_share : box rigs only (None: their defaults).
    """

    primary: int = 32
    secondary: int = 64
    angle: float = 60.0
    radius: float | None = None
    rig_kind: str = "cap"
    box_targets: str | None = None
    box_scale: float | None = None
    box_cap_share: float | None = None

    def spec(self) -> RigSpec:
        """The :class:`~spotlights.geometry.rig.RigSpec` (box rigs become rigs with an object's box)."""
        kind = self.rig_kind or "cap"
        box = {"targets": self.box_targets, "scale": self.box_scale, "cap_share": self.box_cap_share}
        given = [f"box_{k}" for k, v in box.items() if v is not None]
        if kind == "cap" and given:
            raise ParameterError(
                f"{', '.join(f'`{g}`' for g in given)} only apply with `rig_kind` box", *given, "rig_kind"
            )
        return make_rig_spec(
            self.primary,
            self.secondary,
            angle=self.angle,
            radius=self.radius,
            kind=kind,
            targets=self.box_targets,
            scale=self.box_scale,
            cap_share=self.box_cap_share,
        )


@dataclass(kw_only=True)
class EncodeSettings(RigOptions):
    """What ``spotlights encode`` does: ``meshes`` (files) encoded into ``out`` (a ``.npz`` for one mesh, a
    folder for several: ``MESH_STEM.npz`` each), with the :class:`RigOptions`; ``up``/``forward``: the mesh
    files' axes; ``quiet``: no progress bar."""

    meshes: list
    out: str
    up: str = "z"
    forward: str = "x"
    quiet: bool = False

    def targets(self) -> list[Path]:
        """The ``.npz`` file of each mesh (one-line errors for an ``out`` that does not fit)."""
        out = Path(self.out)
        several = len(self.meshes) > 1
        if several and out.suffix.lower() == ".npz":
            raise SpotlightsError(f"{out}: several meshes need a folder for --out, not a .npz file")
        into_folder = several or out.is_dir()  # an existing folder receives MESH_STEM.npz
        if not into_folder and out.suffix and out.suffix.lower() != ".npz":
            raise SpotlightsError(
                f"--out {out}: an encoding is written as an .npz archive; name it {out.stem}.npz (or give a folder)"
            )
        if not into_folder:
            return [out if out.suffix else out.with_suffix(".npz")]
        targets = [out / (Path(m).stem + ".npz") for m in self.meshes]
        if several and len(set(targets)) != len(targets):
            raise SpotlightsError("several meshes share a file name; encode them into different folders")
        return targets


def encode_meshes(s: EncodeSettings, say: Say = logs.info) -> list[Path]:
    """Encode every mesh of ``s.meshes`` (each in its object frame, normalised to the unit sphere) with the rig
    of ``s`` (box rigs: aimed at each mesh's own box) and write its depths ((N, M) float32, unit frame) and
    normalisation as ``.npz``; every mesh is read before any file is written. ``say`` gets one line per mesh
    (rig, hit ratio). Returns the files written."""
    from tqdm import tqdm

    spec = s.spec()
    targets = s.targets()
    several = len(s.meshes) > 1
    check_writable(*targets)
    meshes = [load_mesh(m, up=s.up, forward=s.forward) for m in s.meshes]  # validate all first
    for path, mesh, target in tqdm(
        list(zip(s.meshes, meshes, targets)), desc="encode", unit="mesh", disable=not several or s.quiet
    ):
        probe = MeshProbe(mesh)
        rig = probe.rig_for(spec)  # box rigs: aimed at this mesh's own box
        depths = probe.encode(rig)
        save_encoding(target, depths, rig, probe.normalization)
        msg = f"{path}: {rig.name}, hit ratio {hit_ratio(depths):.3f} ({int((depths > 0).sum())}/{rig.n_rays} rays) -> {target}"
        with tqdm.external_write_mode():  # the line above the progress bar (several meshes)
            say(msg)
    return targets


@dataclass(kw_only=True)
class DecodeSettings:
    """What ``spotlights decode`` does: ``encoding`` (``.npz``) -> ``out`` (point cloud file) in ``frame``
    (``original``: the mesh's own frame; ``unit``: the unit sphere), depths below ``clip`` counted as misses."""

    encoding: str
    out: str
    frame: str = "original"
    clip: float | None = None


def decode_file(s: DecodeSettings, say: Say = logs.info) -> np.ndarray:
    """Decode ``s.encoding`` into its ordered points ((K, 3) float64, ``s.frame``) and write them to ``s.out``;
    a one-line :class:`InputFileError` when no ray hit (nothing written). Returns the points."""
    check_writable(s.out)
    enc = load_encoding(s.encoding)
    pts = enc.points(frame=s.frame, clip=s.clip)
    if len(pts) == 0:
        why = f" at or above the clip {s.clip}" if s.clip is not None else ""
        raise InputFileError(s.encoding, f"no ray hit{why}: the point cloud would be empty (nothing written)")
    save_points(s.out, pts)
    say(f"{s.encoding}: {len(pts)} points ({s.frame} frame) -> {s.out}")
    return pts


@dataclass(kw_only=True)
class ShowSettings:
    """What ``spotlights show`` does: ``file`` (mesh, point cloud, scene PLY or encoding) drawn into ``out``
    (PNG; None: ``./FILE_STEM.png``, or no picture with ``html`` alone); ``clip``: encodings' depth clip;
    ``html``: an interactive page; ``up``/``forward``: a mesh file's axes."""

    file: str
    out: str | None = None
    clip: float | None = None
    html: str | None = None
    up: str = "z"
    forward: str = "x"


def _is_encoding(src: Path) -> bool:
    """Whether the ``.npz`` file ``src`` holds an encoding (a ``depths`` array)."""
    try:
        with np.load(src, allow_pickle=False) as z:
            return "depths" in z.files
    except Exception as exc:
        raise InputFileError(src, f"not a readable .npz file ({type(exc).__name__})") from None


def _render_scene_ply(src: Path, out: Path, fields: dict) -> None:
    """A scene PLY (from ``complete --boxes``): raw points grey, partial inputs purple, completions green."""
    xyz = np.stack([fields["x"], fields["y"], fields["z"]], axis=1).astype(np.float64)
    layers = [
        viz.Layer(
            xyz[fields["source"] == code],
            color,
            f"{label} ({int((fields['source'] == code).sum())})",
            0.5 if code == 0 else 2.0,
        )
        for code, (label, color, _) in SOURCES.items()
    ]
    viz.render_layers(out, layers, title=f"{src.name}: scene of {len(xyz)} points")


def render_file(src: Path, out: Path, clip: float | None = None, up: str = "z", forward: str = "x") -> str:
    """Draw ``src`` into the PNG ``out`` by its kind (encoding, mesh, scene PLY, point cloud); returns the kind
    as a phrase (``"mesh"``, ``"encoding (cap 32x64)"``). A one-line :class:`InputFileError` for other files."""
    suffix = src.suffix.lower()
    if suffix == ".npz" and _is_encoding(src):
        enc = load_encoding(src)
        viz.render_encoding(out, enc, clip=clip)
        box = "" if enc.rig.box is None else ", box half-extents " + " x ".join(f"{x:.3f}" for x in enc.rig.box)
        return f"encoding ({enc.rig.name}{box})"
    if suffix in MESH_SUFFIXES and suffix != ".ply" or (suffix == ".ply" and ply_has_faces(src)):
        mesh = load_mesh(src, up=up, forward=forward)
        viz.render_mesh(out, mesh, title=f"{src.name}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces")
        return "mesh"
    if suffix == ".ply":
        fields = load_ply_fields(src)
        if "source" in fields:
            _render_scene_ply(src, out, fields)
            return "scene"
    if suffix in POINT_SUFFIXES:
        pts = load_points(src)
        viz.render_layers(out, [viz.Layer(pts, "tab:blue", None, 2.0)], title=f"{src.name}: {len(pts)} points")
        return "point cloud"
    raise InputFileError(src, f"unknown file type {suffix!r} (a mesh, a point cloud or an encoding .npz)")


def show_file(s: ShowSettings, say: Say = logs.info) -> Path | None:
    """Draw ``s.file`` as a PNG (:func:`render_file`) and/or an HTML page; returns the PNG (None: page only)."""
    check_suffix(s.out, (".png",), "the picture")
    src = Path(s.file)
    out = Path(s.out) if s.out else Path.cwd() / (src.stem + ".png")
    if not src.exists():
        raise InputFileError(src, "no such file")
    if src.is_dir():
        raise InputFileError(src, f"is a folder: {html.FOLDER_HINT}")
    check_suffix(s.html, (".html", ".htm"), "the page (HTML)", "html")
    check_writable(s.out or (None if s.html else out), s.html)
    if s.html:
        traces, what = html.file_traces(src, clip=s.clip, up=s.up, forward=s.forward)
        html.write_html(s.html, html.page([(src.name, traces)], f"{src.name}: {what}"))
        say(f"{src}: {what} -> {s.html}")
        if not s.out:
            return None
    say(f"{src}: {render_file(src, out, s.clip, s.up, s.forward)} -> {out}")
    return out


@dataclass(kw_only=True)
class ViewSettings:
    """What ``spotlights view`` does: ``files`` drawn in one interactive page ``out`` (None: ``view.html``, or
    no file with ``serve``); ``rays``: an encoding viewpoint's ray bundle; ``clip``: encodings' depth clip;
    ``side_by_side``: one panel per file; ``title``; ``max_points``: points drawn per cloud; ``up``/``forward``:
    mesh axes; ``serve``, ``port``, ``host``: serve the page over HTTP; ``quiet``: no summary lines."""

    files: list
    out: str | None = None
    rays: int | None = None
    clip: float | None = None
    side_by_side: bool = False
    title: str | None = None
    max_points: int = 400_000
    up: str = "z"
    forward: str = "x"
    serve: bool = False
    port: int | None = None
    host: str | None = None
    quiet: bool = False


def view_files(s: ViewSettings, say: Say = logs.info) -> int:
    """Write ``s.files`` as one self-contained HTML page (:mod:`spotlights.viz.html`) and, with ``s.serve``,
    serve it until Ctrl-C (:func:`spotlights.viz.serve.serve`). Returns the exit code (0)."""
    if not s.serve and (s.port is not None or s.host is not None):
        raise SpotlightsError("--port and --host go with --serve")
    out = s.out if s.out is not None or s.serve else "view.html"
    if out is not None:
        check_suffix(out, (".html", ".htm"), "the page (HTML)")
        check_writable(out)
    html.require_plotly()
    panels, lines = [], []
    for f in s.files:
        traces, what = html.file_traces(
            f, rays=s.rays, clip=s.clip, up=s.up, forward=s.forward, max_points=s.max_points
        )
        panels.append((Path(f).name, traces))
        lines.append(f"{f}: {what}")
    title = s.title if s.title is not None else ", ".join(Path(f).name for f in s.files)
    fig = html.page(panels, title, side_by_side=s.side_by_side)
    say = silent if s.quiet else say
    for line in lines:
        say(line)
    if out is not None:
        page = html.write_html(out, fig)
        say(f"page -> {page} ({page.stat().st_size / 1e6:.1f} MB, opens offline in a browser)")
    if s.serve:
        host = s.host if s.host is not None else serve.DEFAULT_HOST
        port = s.port if s.port is not None else serve.DEFAULT_PORT
        return serve.serve(html.page_text(fig).encode("utf-8"), host, port, quiet=s.quiet)
    return 0


__all__ = [
    "DecodeSettings",
    "EncodeSettings",
    "RigOptions",
    "ShowSettings",
    "ViewSettings",
    "decode_file",
    "encode_meshes",
    "render_file",
    "show_file",
    "view_files",
]
