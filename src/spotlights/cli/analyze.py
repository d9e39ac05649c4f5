"""``spotlights analyze``: theory behind the representation (paper Section 3.3).

Sub-command ``density``: the ray density of a surfel inside the sphere, by quadrature,
checked with real rigs and real ray casting, written as CSV, figures and a summary.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..experiments.density_report import (
    MAX_MC_RAYS,
    MAX_ROTATIONS,
    MIN_ALPHA_STEP_DEG,
    MIN_R_STEP,
    DensityConfig,
    density_summary_lines,
    run_density_analysis,
)
from ..options import option
from ..outputs import output_folder
from ._util import SEED_HELP, add_command, add_group, add_options, add_quiet, seed_number


@dataclass(kw_only=True)
class DensityOptions:
    """The options of ``spotlights analyze density`` (then ``-q``; read as a :class:`DensityConfig`)."""

    out: str = option(
        "--out",
        "-o",
        metavar="DIR",
        help="output folder: density.csv (r, alpha [radians], rho_per_nm[, angle]), density_heatmap.png, "
        "density_directional.png, density_montecarlo.png, density_mc.csv, density_caps.png "
        "(several angles), summary.json",
    )
    angle: list[float] = option(
        default=[90.0],
        type=float,
        nargs="+",
        metavar="DEG",
        help="cap half-angles omega in degrees, (0, 90]; 90 is the paper's 2 pi analysis (default 90). "
        "Several give a column 'angle' and the cap comparison figure",
    )
    r_step: float = option(
        default=0.01, type=float, metavar="DR", help=f"grid step in r, {MIN_R_STEP:g}..0.5 (default 0.01)"
    )
    alpha_step: float = option(
        default=1.0,
        type=float,
        metavar="DEG",
        help=f"grid step in alpha in degrees, {MIN_ALPHA_STEP_DEG:g}..90, grid 0..180 (default 1)",
    )
    no_mc: bool = option(default=False, action="store_true", help="skip the Monte-Carlo check with real rays")
    mc_rays: list[int] = option(
        default=[1024, 1024],
        type=int,
        nargs=2,
        metavar=("N", "M"),
        help=f"viewpoints and rays per viewpoint of the Monte-Carlo rigs, N x M <= {MAX_MC_RAYS} (default 1024 1024)",
    )
    rotations: int = option(
        default=24,
        type=int,
        metavar="K",
        help=f"random rotations per disc placement, 2..{MAX_ROTATIONS}; the error is their spread (default 24)",
    )
    disc_radius: float = option(default=0.08, type=float, metavar="A", help="Monte-Carlo disc radius (default 0.08)")
    seed: int = option(default=0, type=seed_number, help=f"seed of the random rotations, {SEED_HELP} (default 0)")


def register(sub) -> None:
    inner = add_group(
        sub,
        "analyze",
        "analyses of the Spotlights representation (ray density, paper Section 3.3)",
        "spotlights analyze density --out out/density",
        metavar="ANALYSIS",
    )

    d = add_command(
        inner,
        "density",
        "ray density of a surfel at distance r and orientation alpha inside the sphere: quadrature, "
        "the occlusion formula, and a Monte-Carlo check with real rigs (Embree)",
        "spotlights analyze density --out out/density --angle 90 83 60 30",
        _density,
    )
    add_options(d, DensityOptions)
    add_quiet(d)


def _density(args) -> int:
    cfg = DensityConfig(
        angles=tuple(args.angle),
        mc=not args.no_mc,
        mc_primary=args.mc_rays[0],
        mc_secondary=args.mc_rays[1],
        mc_rotations=args.rotations,
        disc_radius=args.disc_radius,
        seed=args.seed,
        r_step=args.r_step,
        alpha_step_deg=args.alpha_step,
    )

    cfg.validate()  # bad parameters fail before the folder is made
    with output_folder(args.out):  # removed again if the analysis fails before writing anything
        summary, timings = run_density_analysis(args.out, cfg, progress=not args.quiet, log=print)
    print("\n".join(density_summary_lines(summary, timings, cfg, args.out)))
    return 0
