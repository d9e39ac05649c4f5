"""Core commands: ``encode``, ``decode``, ``show``."""

from __future__ import annotations

import argparse

from ..files import (
    DecodeSettings,
    EncodeSettings,
    ShowSettings,
    decode_file,
    encode_meshes,
    show_file,
)
from ..options import settings_from_namespace
from ..outputs import check_distinct_paths
from ._util import add_command, add_quiet, unit_interval
from .view import add_html_argument


def add_rig_arguments(p: argparse.ArgumentParser) -> None:
    """The rig options shared by every command that builds a rig."""
    g = p.add_argument_group("rig (paper defaults: 32 x 64 rays, 60 degrees)")
    g.add_argument(
        "--primary", "-N", type=int, default=32, metavar="N", help="viewpoints on the Fibonacci sphere (default 32)"
    )
    g.add_argument("--secondary", "-M", type=int, default=64, metavar="M", help="rays per viewpoint (default 64)")
    g.add_argument(
        "--angle",
        type=float,
        default=60.0,
        metavar="DEG",
        help="cap polar half-angle omega in degrees, (0, 90] (default 60)",
    )
    g.add_argument(
        "--radius",
        type=float,
        default=None,
        metavar="R",
        help="alternatively the paper's small-sphere radius r/R: omega = arccos(r/2R); 0.25 gives 82.8 degrees",
    )
    g.add_argument(
        "--rig-kind",
        choices=("cap", "box"),
        default="cap",
        help="cap: the paper's rig (default); box: aim each viewpoint's rays at the object's box "
        "(beyond the paper; on the 79 cars at 2048-8192 rays: hit ratio 0.94 instead of 0.35 and 22-24%% better "
        "completeness than the 60-degree cap; docs/box-rig.md)",
    )
    g.add_argument(
        "--box-targets",
        choices=("ellipsoid", "volume", "surface", "visible"),
        default=None,
        help="box rigs: target set (default ellipsoid: the tangent cone of the box's inscribed ellipsoid)",
    )
    g.add_argument(
        "--box-scale",
        type=float,
        default=None,
        metavar="S",
        help="box rigs: targets within the box scaled by S, (0, 1] (default 1)",
    )
    g.add_argument(
        "--box-cap-share",
        type=float,
        default=None,
        metavar="C",
        help="box rigs: share of each viewpoint's rays kept on the paper's cap of --angle, [0, 1) (default 0)",
    )


def add_axes_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--up", default="z", help="the mesh file's up axis (x, y, z, -x, ...); glTF files are usually y (default z)"
    )
    p.add_argument("--forward", default="x", help="the mesh file's forward axis (default x)")


def register(sub) -> None:
    p = add_command(
        sub,
        "encode",
        "cast a Spotlights rig at meshes and write their depth arrays (.npz)",
        "spotlights encode car.glb --up y --forward z --out car.npz",
        _encode,
    )
    p.add_argument("meshes", nargs="+", metavar="MESH", help="mesh files (OBJ, PLY, OFF, STL, GLB, GLTF)")
    p.add_argument(
        "--out",
        "-o",
        required=True,
        metavar="PATH",
        help="output .npz for one mesh, or a folder for several (one MESH_STEM.npz each)",
    )
    add_rig_arguments(p)
    add_axes_arguments(p)
    add_quiet(p, "no progress bar (several meshes)")

    p = add_command(
        sub,
        "decode",
        "turn an encoding back into its ordered point cloud",
        "spotlights decode car.npz --out car_points.ply --frame original",
        _decode,
    )
    p.add_argument("encoding", metavar="FILE.npz", help="an encoding written by 'spotlights encode'")
    p.add_argument("--out", "-o", required=True, metavar="CLOUD", help="output .ply, .pcd, .npy, .xyz or .txt")
    p.add_argument(
        "--frame",
        choices=("original", "unit"),
        default="original",
        help="original: the mesh's own frame (default); unit: the normalised unit sphere",
    )
    p.add_argument(
        "--clip",
        type=unit_interval,
        default=None,
        metavar="T",
        help="treat depths below T as misses (the paper uses 0.2 on predictions)",
    )

    p = add_command(
        sub,
        "show",
        "render a mesh, a point cloud or an encoding to a PNG",
        "spotlights show car.npz --out car.png",
        _show,
    )
    p.add_argument(
        "file",
        metavar="FILE",
        help="mesh, point cloud (.ply .pcd .npy .xyz) or encoding (.npz); a picture draws at most 200000 points "
        "(an even subsample beyond; --html: 400000 per cloud)",
    )
    p.add_argument(
        "--out",
        "-o",
        default=None,
        metavar="PNG",
        help="output picture (default: ./FILE_STEM.png; with --html alone, no picture)",
    )
    p.add_argument(
        "--clip", type=unit_interval, default=None, metavar="T", help="for encodings: depths below T count as misses"
    )
    add_html_argument(p)
    add_axes_arguments(p)


def _encode(args) -> int:
    s = settings_from_namespace(EncodeSettings, args)
    check_distinct_paths([("MESH", m) for m in s.meshes], [("--out", t) for t in s.targets()])
    encode_meshes(s, say=print)
    return 0


def _decode(args) -> int:
    s = settings_from_namespace(DecodeSettings, args)
    check_distinct_paths([("FILE.npz", s.encoding)], [("--out", s.out)])
    decode_file(s, say=print)
    return 0


def _show(args) -> int:
    s = settings_from_namespace(ShowSettings, args)
    check_distinct_paths([("FILE", s.file)], [("--out", s.out), ("--html", s.html)])
    show_file(s, say=print)
    return 0
