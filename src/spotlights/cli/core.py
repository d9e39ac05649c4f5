"""Core commands: ``encode``, ``decode``, ``show``."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

from ..files import (
    DecodeSettings,
    EncodeSettings,
    ShowSettings,
    decode_file,
    encode_meshes,
    show_file,
)
from ..options import option, settings_from_namespace
from ..outputs import check_distinct_paths
from ._util import add_command, add_options, add_quiet, unit_interval
from .view import add_html_argument

RIG_GROUP = "rig (paper defaults: 32 x 64 rays, 60 degrees)"


@dataclass(kw_only=True)
class RigArguments:
    """The rig options shared by every command that builds a rig (read as the rig fields of
    :class:`~spotlights.files.EncodeSettings`)."""

    primary: int = option(
        "--primary", "-N", default=32, type=int, metavar="N", group=RIG_GROUP,
        help="viewpoints on the Fibonacci sphere (default 32)",
    )  # fmt: skip
    secondary: int = option(
        "--secondary", "-M", default=64, type=int, metavar="M", group=RIG_GROUP, help="rays per viewpoint (default 64)"
    )
    angle: float = option(
        default=60.0,
        type=float,
        metavar="DEG",
        group=RIG_GROUP,
        help="cap polar half-angle omega in degrees, (0, 90] (default 60)",
    )
    radius: float | None = option(
        default=None,
        type=float,
        metavar="R",
        group=RIG_GROUP,
        help="alternatively the paper's small-sphere radius r/R: omega = arccos(r/2R); 0.25 gives 82.8 degrees",
    )
    rig_kind: str = option(
        default="cap",
        choices=("cap", "box"),
        group=RIG_GROUP,
        help="cap: the paper's rig (default); box: aim each viewpoint's rays at the object's box "
        "(beyond the paper; on the 79 cars at 2048-8192 rays: hit ratio 0.94 instead of 0.35 and 22-24%% better "
        "completeness than the 60-degree cap; docs/box-rig.md)",
    )
    box_targets: str | None = option(
        default=None,
        choices=("ellipsoid", "volume", "surface", "visible"),
        group=RIG_GROUP,
        help="box rigs: target set (default ellipsoid: the tangent cone of the box's inscribed ellipsoid)",
    )
    box_scale: float | None = option(
        default=None,
        type=float,
        metavar="S",
        group=RIG_GROUP,
        help="box rigs: targets within the box scaled by S, (0, 1] (default 1)",
    )
    box_cap_share: float | None = option(
        default=None,
        type=float,
        metavar="C",
        group=RIG_GROUP,
        help="box rigs: share of each viewpoint's rays kept on the paper's cap of --angle, [0, 1) (default 0)",
    )


@dataclass(kw_only=True)
class MeshAxesArguments:
    """The axes of a mesh file (``encode``, ``show``)."""

    up: str = option(
        default="z", help="the mesh file's up axis (x, y, z, -x, ...); glTF files are usually y (default z)"
    )
    forward: str = option(default="x", help="the mesh file's forward axis (default x)")


@dataclass(kw_only=True)
class EncodeOptions:
    """The own options of ``spotlights encode`` (then :class:`RigArguments`, :class:`MeshAxesArguments`, ``-q``)."""

    meshes: list[str] = option("meshes", nargs="+", metavar="MESH", help="mesh files (OBJ, PLY, OFF, STL, GLB, GLTF)")
    out: str = option(
        "--out",
        "-o",
        metavar="PATH",
        help="output .npz for one mesh, or a folder for several (one MESH_STEM.npz each)",
    )


@dataclass(kw_only=True)
class DecodeOptions:
    """The options of ``spotlights decode``."""

    encoding: str = option("encoding", metavar="FILE.npz", help="an encoding written by 'spotlights encode'")
    out: str = option("--out", "-o", metavar="CLOUD", help="output .ply, .pcd, .npy, .xyz or .txt")
    frame: str = option(
        default="original",
        choices=("original", "unit"),
        help="original: the mesh's own frame (default); unit: the normalised unit sphere",
    )
    clip: float | None = option(
        default=None,
        type=unit_interval,
        metavar="T",
        help="treat depths below T as misses (the paper uses 0.2 on predictions)",
    )


@dataclass(kw_only=True)
class ShowOptions:
    """The own options of ``spotlights show`` (then ``--html`` and :class:`MeshAxesArguments`)."""

    file: str = option(
        "file",
        metavar="FILE",
        help="mesh, point cloud (.ply .pcd .npy .xyz) or encoding (.npz); a picture draws at most 200000 points "
        "(an even subsample beyond; --html: 400000 per cloud)",
    )
    out: str | None = option(
        "--out",
        "-o",
        default=None,
        metavar="PNG",
        help="output picture (default: ./FILE_STEM.png; with --html alone, no picture)",
    )
    clip: float | None = option(
        default=None, type=unit_interval, metavar="T", help="for encodings: depths below T count as misses"
    )


def add_rig_arguments(p: argparse.ArgumentParser) -> None:
    """Add :class:`RigArguments`, the rig options shared by every command that builds a rig."""
    add_options(p, RigArguments)


def add_axes_arguments(p: argparse.ArgumentParser) -> None:
    """Add :class:`MeshAxesArguments` (``--up``, ``--forward`` of a mesh file)."""
    add_options(p, MeshAxesArguments)


def register(sub) -> None:
    p = add_command(
        sub,
        "encode",
        "cast a Spotlights rig at meshes and write their depth arrays (.npz)",
        "spotlights encode car.glb --up y --forward z --out car.npz",
        _encode,
    )
    add_options(p, EncodeOptions)
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
    add_options(p, DecodeOptions)

    p = add_command(
        sub,
        "show",
        "render a mesh, a point cloud or an encoding to a PNG",
        "spotlights show car.npz --out car.png",
        _show,
    )
    add_options(p, ShowOptions)
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
