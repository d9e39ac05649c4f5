"""``spotlights view``: meshes, encodings, point clouds, completions and scenes in one interactive HTML page."""

from __future__ import annotations

from ..files import ViewSettings, view_files
from ..options import settings_from_namespace
from ..viz import html
from ._util import add_command, port_number, positive_int, unit_interval


def register(sub) -> None:
    p = add_command(
        sub,
        "view",
        "interactive 3-D view of meshes, encodings, point clouds, completions and scenes: "
        "one self-contained HTML page that opens offline in any browser (rotate, zoom, toggle layers)",
        "spotlights view scan.pcd completed.ply box.json --out view.html    # then open view.html",
        _view,
    )
    p.add_argument(
        "files",
        nargs="+",
        metavar="FILE",
        help="meshes (OBJ PLY OFF STL GLB GLTF), point clouds (PLY PCD NPY XYZ TXT), encodings (.npz), "
        "scenes (PLY with 'source'/'object' fields, from 'complete --boxes'), boxes (.json), "
        "observations (.h5 from 'real extract': its busiest frame)",
    )
    p.add_argument(
        "--out",
        "-o",
        default=None,
        metavar="HTML",
        help="output page (default ./view.html; with --serve the page is written only when --out is given)",
    )
    p.add_argument(
        "--rays",
        type=int,
        default=None,
        metavar="I",
        help="encodings: also draw viewpoint I's ray bundle (hits green, misses orange)",
    )
    p.add_argument(
        "--clip", type=unit_interval, default=None, metavar="T", help="encodings: depths below T count as misses"
    )
    p.add_argument(
        "--side-by-side",
        action="store_true",
        help="one 3-D panel per file (default: all files overlaid in one scene, e.g. a scan and its completion)",
    )
    p.add_argument("--title", default=None, help="page title (default: the file names)")
    p.add_argument(
        "--max-points",
        type=positive_int,
        default=400_000,
        metavar="K",
        help="points drawn at most per cloud (an even subsample beyond; default 400000)",
    )
    p.add_argument(
        "--up", default="z", help="meshes: the file's up axis (x, y, z, -x, ...); glTF files are usually y (default z)"
    )
    p.add_argument("--forward", default="x", help="meshes: the file's forward axis (default x)")
    p.add_argument(
        "--serve",
        action="store_true",
        help="serve the page with Python's http.server (loopback only by default) until Ctrl-C, "
        "and print the URL and the 'ssh -L' line that forwards it to a laptop",
    )
    p.add_argument(
        "--port",
        type=port_number,
        default=None,
        metavar="N",
        help="--serve: the port (default 8000; 0 picks a free one)",
    )
    p.add_argument(
        "--host",
        default=None,
        metavar="ADDR",
        help="--serve: the address to bind (default 127.0.0.1, loopback: reach it through 'ssh -L'); "
        "another address, e.g. 0.0.0.0, only when given here, with a warning (no authentication)",
    )
    p.add_argument("--quiet", "-q", action="store_true", help="no summary lines")


def _view(args) -> int:
    return view_files(settings_from_namespace(ViewSettings, args), say=print)


def add_html_argument(p) -> None:
    """The ``--html PATH`` option of the commands that draw (show, real show, dataset show, complete)."""
    p.add_argument(
        "--html",
        default=None,
        metavar="HTML",
        help="also write an interactive 3-D view: one self-contained HTML page (opens offline; needs plotly)",
    )


def write_page(path, panels, title: str, quiet: bool = False) -> None:
    """Write ``panels`` ((title, traces) pairs) as one overlaid page and say where."""

    out = html.write_html(path, html.page(panels, title))
    if not quiet:
        print(f"page -> {out}")
