"""``spotlights view``: meshes, encodings, point clouds, completions and scenes in one interactive HTML page."""

from __future__ import annotations

from dataclasses import dataclass

from ..files import ViewSettings, view_files
from ..options import option, settings_from_namespace
from ..viz import html
from ._util import add_command, add_options, port_number, positive_int, unit_interval


@dataclass(kw_only=True)
class ViewOptions:
    """The options of ``spotlights view`` (read as :class:`~spotlights.files.ViewSettings`)."""

    files: list[str] = option(
        "files",
        nargs="+",
        metavar="FILE",
        help="meshes (OBJ PLY OFF STL GLB GLTF), point clouds (PLY PCD NPY XYZ TXT), encodings (.npz), "
        "scenes (PLY with 'source'/'object' fields, from 'complete --boxes'), boxes (.json), "
        "observations (.h5 from 'real extract': its busiest frame)",
    )
    out: str | None = option(
        "--out",
        "-o",
        default=None,
        metavar="HTML",
        help="output page (default ./view.html; with --serve the page is written only when --out is given)",
    )
    rays: int | None = option(
        default=None,
        type=int,
        metavar="I",
        help="encodings: also draw viewpoint I's ray bundle (hits green, misses orange)",
    )
    clip: float | None = option(
        default=None, type=unit_interval, metavar="T", help="encodings: depths below T count as misses"
    )
    side_by_side: bool = option(
        default=False,
        action="store_true",
        help="one 3-D panel per file (default: all files overlaid in one scene, e.g. a scan and its completion)",
    )
    title: str | None = option(default=None, help="page title (default: the file names)")
    max_points: int = option(
        default=400_000,
        type=positive_int,
        metavar="K",
        help="points drawn at most per cloud (an even subsample beyond; default 400000)",
    )
    up: str = option(
        default="z", help="meshes: the file's up axis (x, y, z, -x, ...); glTF files are usually y (default z)"
    )
    forward: str = option(default="x", help="meshes: the file's forward axis (default x)")
    serve: bool = option(
        default=False,
        action="store_true",
        help="serve the page with Python's http.server (loopback only by default) until Ctrl-C, "
        "and print the URL and the 'ssh -L' line that forwards it to a laptop",
    )
    port: int | None = option(
        default=None,
        type=port_number,
        metavar="N",
        help="--serve: the port (default 8000; 0 picks a free one)",
    )
    host: str | None = option(
        default=None,
        metavar="ADDR",
        help="--serve: the address to bind (default 127.0.0.1, loopback: reach it through 'ssh -L'); "
        "another address, e.g. 0.0.0.0, only when given here, with a warning (no authentication)",
    )
    quiet: bool = option("--quiet", "-q", default=False, action="store_true", help="no summary lines")


def register(sub) -> None:
    p = add_command(
        sub,
        "view",
        "interactive 3-D view of meshes, encodings, point clouds, completions and scenes: "
        "one self-contained HTML page that opens offline in any browser (rotate, zoom, toggle layers)",
        "spotlights view scan.pcd completed.ply box.json --out view.html    # then open view.html",
        _view,
    )
    add_options(p, ViewOptions)


def _view(args) -> int:
    return view_files(settings_from_namespace(ViewSettings, args), say=print)


@dataclass(kw_only=True)
class HtmlArgument:
    """The ``--html PATH`` option of the commands that draw (show, real show, dataset show, complete)."""

    html: str | None = option(
        default=None,
        metavar="HTML",
        help="also write an interactive 3-D view: one self-contained HTML page (opens offline; needs plotly)",
    )


def add_html_argument(p) -> None:
    """Add :class:`HtmlArgument` (``--html PATH``) to the parser ``p``."""
    add_options(p, HtmlArgument)


def write_page(path, panels, title: str, quiet: bool = False) -> None:
    """Write ``panels`` ((title, traces) pairs) as one overlaid page and say where."""

    out = html.write_html(path, html.page(panels, title))
    if not quiet:
        print(f"page -> {out}")
