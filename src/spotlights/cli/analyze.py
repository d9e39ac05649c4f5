"""``spotlights analyze``: theory behind the representation (paper Section 3.3).

Sub-command ``density``: the ray density of a surfel inside the sphere, by quadrature,
checked with real rigs and real ray casting, written as CSV, figures and a summary.
"""

from __future__ import annotations

from ..experiments.density_report import DensityConfig, run_density_analysis
from ..utils import output_folder
from ._util import add_command, add_group, add_quiet, non_negative_int


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
    d.add_argument(
        "--out",
        "-o",
        required=True,
        metavar="DIR",
        help="output folder: density.csv (r, alpha [radians], rho_per_nm[, angle]), density_heatmap.png, "
        "density_directional.png, density_montecarlo.png, density_mc.csv, density_caps.png "
        "(several angles), summary.json",
    )
    d.add_argument(
        "--angle",
        type=float,
        nargs="+",
        default=[90.0],
        metavar="DEG",
        help="cap half-angles omega in degrees, (0, 90]; 90 is the paper's 2 pi analysis (default 90). "
        "Several give a column 'angle' and the cap comparison figure",
    )
    d.add_argument(
        "--r-step", type=float, default=0.01, metavar="DR", help="grid step in r, grid 0..0.99 (default 0.01)"
    )
    d.add_argument(
        "--alpha-step",
        type=float,
        default=1.0,
        metavar="DEG",
        help="grid step in alpha in degrees, grid 0..180 (default 1)",
    )
    d.add_argument("--no-mc", action="store_true", help="skip the Monte-Carlo check with real rays")
    d.add_argument(
        "--mc-rays",
        type=int,
        nargs=2,
        default=[1024, 1024],
        metavar=("N", "M"),
        help="viewpoints and rays per viewpoint of the Monte-Carlo rigs (default 1024 1024)",
    )
    d.add_argument(
        "--rotations",
        type=int,
        default=24,
        metavar="K",
        help="random rotations per disc placement; the error is their spread (default 24)",
    )
    d.add_argument(
        "--disc-radius", type=float, default=0.08, metavar="A", help="Monte-Carlo disc radius (default 0.08)"
    )
    d.add_argument("--seed", type=non_negative_int, default=0, help="seed of the random rotations (default 0)")
    add_quiet(d)


def _density(args) -> int:
    import numpy as np

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
        summary, timings = run_density_analysis(args.out, cfg, progress=not args.quiet)
    print(f"ray density per unit N*M (paper Section 3.3); outputs in {args.out}/")
    lim = f"{cfg.r_limit:g}"
    for key, s in summary["angles"].items():
        ext = s[f"range_r_le_{lim}"]

        def where(k):
            r = ext[f"{k}_r"]
            return f"r={r:.2f}, " + ("any alpha" if r < 1e-9 else f"alpha={np.degrees(ext[f'{k}_alpha']):.0f} deg")

        print(
            f"omega = {key:>4} deg: r <= {lim}: min {ext['min']:.5f} ({where('min')}), "
            f"max {ext['max']:.5f} ({where('max')}), max/min {s['uniformity_max_over_min']:.2f} "
            f"({s['uniformity_max_over_min_r_le_0.95']:.2f} over r <= 0.95); "
            f"r=0: {s['rho_r0']:.5f} (closed form {s['rho_r0_closed_form']:.5f}); "
            f"quadrature error < {s['quadrature_max_abs_error']:.1e}"
        )
        print(
            f"                 real rig {s['rig']}: {s['hit_ratio_05']:.1%} of rays enter the ball r <= 0.5, "
            f"{s['hit_ratio_08']:.1%} the ball r <= 0.8"
        )
        if "montecarlo" in s:
            m = s["montecarlo"]
            print(
                f"                 Monte-Carlo: {m['comparisons']} disc faces, max |z| {m['max_abs_z']:.2f}, "
                f"rms z {m['rms_z']:.2f}, {m['within_2_sigma']:.0%} within 2 sigma, "
                f"median |deviation| {m['median_abs_rel_deviation']:.2%} (median 1-sigma {m['median_rel_se']:.2%})"
            )
            if m["min_shells"] < 3.0:
                print(
                    f"                 note: some discs span only {m['min_shells']:.1f} cap steps (< 3): the finite-M "
                    "term is unreliable there; use more rays per viewpoint (M) or a larger disc"
                )
    print(
        f"done in {timings['total']:.1f} s (quadrature {timings['quadrature_grid']:.1f} s, "
        f"Monte-Carlo {timings['montecarlo']:.1f} s)"
    )
    return 0
