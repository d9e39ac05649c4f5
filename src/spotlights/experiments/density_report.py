"""The ``spotlights analyze density`` pipeline: grids, Monte-Carlo check, CSVs, figures, summary.

:func:`run_density_analysis` is the library entry point the CLI calls. Everything it
writes goes through a temporary name and a rename; the same arguments give the same
bytes (the Monte-Carlo rotations come from ``seed``; timings are returned, not written).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import logs
from ..analysis import density as dens
from ..analysis.montecarlo import DiscPlacement, mc_density
from ..errors import ParameterError
from ..geometry.rig import make_rig
from ..options import check_seed
from ..outputs import atomic_output
from ..timing import StageTimer
from ..viz import density as plots

__all__ = ["DensityConfig", "run_density_analysis", "extrema", "hit_ratios", "MC_RADII", "MC_ALPHAS_DEG"]

#: Monte-Carlo disc placements: every r with every alpha (alpha irrelevant at r = 0)
MC_RADII = (0.0, 0.3, 0.5, 0.7, 0.8, 0.9)
MC_ALPHAS_DEG = (0.0, 45.0, 90.0, 135.0)

# The bounds of DensityConfig (analyze density's options), checked before the output folder is made:
MIN_R_STEP = 0.001
"""Finest grid step in r (``--r-step``): 10 times finer than the default 0.01, 991 radii. With
:data:`MIN_ALPHA_STEP_DEG` a grid of 1.8 million cells per angle (a minute or two of quadrature, a 70 MB CSV);
1e-9 asked for 84 GiB."""
MIN_ALPHA_STEP_DEG = 0.1
"""Finest grid step in alpha, degrees (``--alpha-step``): 10 times finer than the default 1, 1801 orientations;
1e-9 asked for 1.3 TiB."""
MAX_ROTATIONS = 10_000
"""Most random rotations per disc placement (``--rotations``): 400 times the default 24 (the error estimate, their
spread, gains nothing past a few hundred); every rotation casts all the rig's rays, 10^12 asked for 611 TiB."""
MAX_MC_RAYS = 2**24
"""Most rays of a Monte-Carlo rig, N x M (``--mc-rays N M``): 16 times the default 1024 x 1024; the rig's
directions alone are 24 bytes a ray."""


@dataclass
class DensityConfig:
    """Settings of :func:`run_density_analysis` (defaults: the documented run).

    angles: cap half-angles in degrees, (0, 90]; 90 is the paper's analysis.
    r_step: grid step in r (grid 0 .. 0.99). alpha_step_deg: grid step in alpha (0 .. 180 deg).
    r_limit: the paper's range limit for min/max (0.8).
    mc: run the Monte-Carlo check. mc_primary, mc_secondary: N and M of the real rigs.
    mc_rotations: random rotations per placement. disc_radius: test disc radius.
    seed: seeds the rotations.
    """

    angles: Sequence[float] = (90.0,)
    r_step: float = 0.01
    alpha_step_deg: float = 1.0
    r_limit: float = 0.8
    mc: bool = True
    mc_primary: int = 1024
    mc_secondary: int = 1024
    mc_rotations: int = 24
    disc_radius: float = 0.08
    seed: int = 0
    mc_radii: Sequence[float] = field(default_factory=lambda: MC_RADII)
    mc_alphas_deg: Sequence[float] = field(default_factory=lambda: MC_ALPHAS_DEG)

    def validate(self) -> None:
        """Raise :class:`ParameterError` for values outside their ranges."""
        if not self.angles:
            raise ParameterError("give at least one cap angle")
        for a in self.angles:
            if not (0.0 < float(a) <= 90.0):
                raise ParameterError(f"cap angle must be in (0, 90] degrees, got {a:g}")
        if len(set(float(a) for a in self.angles)) != len(self.angles):
            raise ParameterError("cap angles must be distinct")
        if not (MIN_R_STEP <= self.r_step <= 0.5):
            raise ParameterError(f"`r_step` must be in [{MIN_R_STEP:g}, 0.5], got {self.r_step:g}", "r_step")
        if not (MIN_ALPHA_STEP_DEG <= self.alpha_step_deg <= 90.0):
            raise ParameterError(
                f"`alpha_step` must be in [{MIN_ALPHA_STEP_DEG:g}, 90] degrees, got {self.alpha_step_deg:g}",
                "alpha_step",
            )
        n, m = self.mc_primary, self.mc_secondary
        if not (1 <= n and 1 <= m and n * m <= MAX_MC_RAYS):  # the rig is made (hit ratios) even without mc
            raise ParameterError(
                f"`mc_rays` N M: the Monte-Carlo rig needs N, M >= 1 and N x M <= {MAX_MC_RAYS}, got {n} {m}", "mc_rays"
            )
        if not (0.0 < self.r_limit < 1.0):
            raise ParameterError(f"r_limit must be in (0, 1), got {self.r_limit:g}")
        if self.mc:
            if not 2 <= self.mc_rotations <= MAX_ROTATIONS:
                raise ParameterError(
                    f"`rotations` must be in 2..{MAX_ROTATIONS} (at least 2 to estimate the Monte-Carlo error), "
                    f"got {self.mc_rotations}",
                    "rotations",
                )
            check_seed(self.seed)
            if not (0.0 < self.disc_radius < 0.1):
                raise ParameterError("disc radius must be in (0, 0.1) so that a disc at r = 0.9 fits in the sphere")


def extrema(angle: float, r_limit: float, r_values: np.ndarray, alpha_values: np.ndarray, grid: np.ndarray) -> dict:
    """Min and max of ``rho`` over ``0 <= r <= r_limit``, all alpha, per unit N*M.

    Starts from the best grid points and refines with a bounded quasi-Newton search
    (scipy L-BFGS-B) on the quadrature. Returns a dict with ``min``, ``max`` and their
    ``r``/``alpha`` (radians).
    """
    from scipy.optimize import minimize

    inside = r_values <= r_limit + 1e-12
    g = grid[inside]
    out = {}
    for name, sign, idx in (
        ("min", 1.0, np.unravel_index(np.argmin(g), g.shape)),
        ("max", -1.0, np.unravel_index(np.argmax(g), g.shape)),
    ):
        x0 = np.array([r_values[inside][idx[0]], alpha_values[idx[1]]])
        best = (float(g[idx]), float(x0[0]), float(x0[1]))

        def f(x):
            return sign * float(dens.rho(x[0], x[1], angle=angle))

        res = minimize(
            f,
            x0,
            method="L-BFGS-B",
            bounds=[(0.0, r_limit), (0.0, np.pi)],
            options={"ftol": 1e-14, "gtol": 1e-12, "maxiter": 200},
        )
        val = sign * float(res.fun)
        if sign * val < sign * best[0]:
            best = (val, float(res.x[0]), float(res.x[1]))
        out[name] = best[0]
        out[f"{name}_r"] = best[1]
        out[f"{name}_alpha"] = best[2]
    return out


def hit_ratios(rig, radii: Sequence[float] = (0.5, 0.8)) -> dict[str, float]:
    """Fraction of a real rig's rays whose line enters the centred ball of each radius.

    A ray from ``o`` (unit sphere) with direction ``d`` passes at distance
    ``sqrt(1 - (o.d)^2)`` from the centre. Returns ``{"hit_ratio_05": ..., "hit_ratio_08": ...}``
    (keys from the radius digits).
    """
    od = np.einsum("ij,ij->i", rig.origins, rig.directions)
    dist = np.sqrt(np.clip(1.0 - od * od, 0.0, None))
    return {f"hit_ratio_{str(b).replace('.', '')[:2]}": float(np.mean(dist <= b)) for b in radii}


def _symmetric_grid(
    r_values: np.ndarray, alpha_values: np.ndarray, angle: float, nodes: int = dens.DEFAULT_NODES
) -> np.ndarray:
    """``rho_grid`` on a grid symmetric about pi/2, computing only alpha <= pi/2 and mirroring.

    ``rho(r, alpha) = rho(r, pi - alpha)`` exactly (see :mod:`.density`; tested independently).
    ``alpha_values`` must be symmetric (``alpha_j + alpha_{A-1-j} = pi``); otherwise the full grid
    is computed.
    """
    n = len(alpha_values)
    if not np.allclose(alpha_values + alpha_values[::-1], np.pi, atol=1e-12):
        return dens.rho_grid(r_values, alpha_values, angle=angle, nodes=nodes)
    half = (n + 1) // 2
    g = dens.rho_grid(r_values, alpha_values[:half], angle=angle, nodes=nodes)
    return np.concatenate([g, g[:, : n - half][:, ::-1]], axis=1)


def _write_csv(path: Path, header: str, columns: Sequence[np.ndarray], fmts: Sequence[str]) -> None:
    data = np.column_stack([np.asarray(c, dtype=np.float64) for c in columns])
    with atomic_output(path) as tmp:
        np.savetxt(tmp, data, delimiter=",", header=header, comments="", fmt=list(fmts))


def _write_mc_csv(path: Path, results) -> None:
    keys = [
        "angle",
        "r",
        "alpha",
        "side",
        "n_primary",
        "n_secondary",
        "n_rotations",
        "disc_radius",
        "area",
        "hits",
        "rho_mc",
        "se_mc",
        "se_poisson",
        "rho_quad",
        "correction",
        "rho_expected",
        "rho_center",
        "z",
        "shells",
    ]
    lines = [",".join(keys)]
    for x in results:
        d = x.to_dict()
        lines.append(
            ",".join(
                v if isinstance(v, str) else (str(v) if isinstance(v, int) else f"{v:.10g}")
                for v in (d[k] for k in keys)
            )
        )
    with atomic_output(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def _mc_stats(results) -> dict:
    zs = np.array([x.z for x in results])
    rel = np.array([x.rho_mc / x.rho_expected - 1.0 for x in results])
    rel_cont = np.array([x.rho_mc / x.rho_quad - 1.0 for x in results])
    return {
        "comparisons": int(len(results)),
        "max_abs_z": float(np.max(np.abs(zs))),
        "rms_z": float(np.sqrt(np.mean(zs**2))),
        "within_2_sigma": float(np.mean(np.abs(zs) < 2.0)),
        "within_3_sigma": float(np.mean(np.abs(zs) < 3.0)),
        "max_abs_rel_deviation": float(np.max(np.abs(rel))),
        "median_abs_rel_deviation": float(np.median(np.abs(rel))),
        "median_rel_se": float(np.median([x.se_mc / x.rho_expected for x in results])),
        "max_abs_rel_deviation_vs_continuum": float(np.max(np.abs(rel_cont))),
        "min_shells": float(min(x.shells for x in results)),
    }


def run_density_analysis(
    out_dir: str | os.PathLike, config: DensityConfig | None = None, progress: bool = True, log=logs.info
) -> tuple[dict, dict]:
    """Compute, check and draw the ray density of Spotlights rigs; write everything under ``out_dir``.

    Writes ``density.csv`` (columns ``r``, ``alpha`` [radians], ``rho_per_nm`` and, with several
    angles, ``angle`` [degrees]), ``density_heatmap.png``, ``density_directional.png`` (the
    occlusion formula), ``density_mc.csv`` and ``density_montecarlo.png`` (unless ``config.mc`` is
    False), ``density_caps.png`` (with several angles) and ``summary.json``.

    Returns:
        ``(summary, timings)``: the summary written to ``summary.json`` and wall-clock seconds
        per stage (not written, so that outputs stay byte-identical between runs).
    """
    config = config or DensityConfig()
    config.validate()
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ParameterError(f"{out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)

    timer = StageTimer()  # laps, one per stage
    angles = [float(a) for a in config.angles]
    r_values, alpha_values = _grid_axes(config)

    # --- quadrature on the grid -------------------------------------------------------------
    timer.lap("setup")
    grids = {a: _symmetric_grid(r_values, alpha_values, a) for a in angles}
    timer.lap("quadrature_grid")
    summary: dict = {
        "format": "spotlights-density-summary",
        "config": {k: (list(v) if isinstance(v, (list, tuple)) else v) for k, v in config.__dict__.items()},
        "angles": {f"{a:g}": _angle_summary(a, config.r_limit, r_values, alpha_values, grids[a]) for a in angles},
    }
    timer.lap("extrema_and_error")

    # --- CSV + heat maps + occlusion figure ---------------------------------------------------
    _write_grid_outputs(out, config, angles, r_values, alpha_values, grids)
    timer.lap("csv_and_figures")

    # --- real rigs: hit ratios and Monte-Carlo ------------------------------------------------
    all_results = _real_rigs(config, angles, summary, progress)
    timer.lap("montecarlo")
    if config.mc:
        _write_mc_csv(out / "density_mc.csv", all_results)
        curve_r = np.linspace(0.0, 0.95, 96)
        curves = {
            a: (curve_r, {ad: dens.rho(curve_r, np.radians(ad), angle=a) for ad in (0.0, 45.0, 90.0)}) for a in angles
        }
        plots.plot_montecarlo(out / "density_montecarlo.png", all_results, curves)
        summary["montecarlo"] = _mc_stats(all_results)
    if len(angles) > 1:
        _plot_caps(out, angles, summary, r_values, alpha_values, grids)
    with atomic_output(out / "summary.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    timer.lap("mc_figures_and_summary")
    timings = {k: v for k, v in timer.seconds.items() if k != "setup"}
    return summary, {**timings, "total": timer.total}


def _grid_axes(config: DensityConfig) -> tuple[np.ndarray, np.ndarray]:
    """The grid's radii (R,) in [0, 1) and orientations alpha (A,) in [0, pi] radians, float64."""
    n_r = int(round(0.99 / config.r_step)) + 1
    r_values = np.round(np.linspace(0.0, config.r_step * (n_r - 1), n_r), 12)
    r_values = r_values[r_values < 1.0]
    n_a = int(round(180.0 / config.alpha_step_deg)) + 1
    alpha_values = np.radians(np.linspace(0.0, config.alpha_step_deg * (n_a - 1), n_a))
    alpha_values = alpha_values[alpha_values <= np.pi + 1e-12]
    return r_values, alpha_values


def _angle_summary(a: float, r_limit: float, r_values, alpha_values, grid: np.ndarray) -> dict:
    """One cap angle's summary: the density at the centre (and its closed form), the quadrature's
    error against twice the nodes, and the extremes and uniformity over ``r <= r_limit`` and 0.95."""
    ref = _symmetric_grid(r_values, alpha_values, a, nodes=2 * dens.DEFAULT_NODES)
    ext = extrema(a, r_limit, r_values, alpha_values, grid)
    ext_wide = extrema(a, 0.95, r_values, alpha_values, grid)
    return {
        "angle": a,
        "rho_r0": float(grid[0, 0]),
        "rho_r0_closed_form": dens.rho_closed_form_r0(a),
        "quadrature_max_abs_error": float(np.max(np.abs(grid - ref))),
        "quadrature_max_rel_error": float(np.max(np.abs(grid - ref) / ref)),
        f"range_r_le_{r_limit:g}": ext,
        "uniformity_max_over_min": ext["max"] / ext["min"],
        "range_r_le_0.95": ext_wide,
        "uniformity_max_over_min_r_le_0.95": ext_wide["max"] / ext_wide["min"],
    }


def _write_grid_outputs(out: Path, config: DensityConfig, angles: list[float], r_values, alpha_values, grids) -> None:
    """``density.csv``, ``density_heatmap.png`` and ``density_directional.png`` (the occlusion formula)."""
    rr, aa = np.meshgrid(r_values, alpha_values, indexing="ij")
    cols, fmts, header = [], ["%.4f", "%.10f", "%.12e"], "r,alpha,rho_per_nm"
    if len(angles) == 1:
        cols = [rr.ravel(), aa.ravel(), grids[angles[0]].ravel()]
    else:
        cols = [
            np.tile(rr.ravel(), len(angles)),
            np.tile(aa.ravel(), len(angles)),
            np.concatenate([grids[a].ravel() for a in angles]),
            np.repeat(angles, rr.size),
        ]
        fmts.append("%g")
        header += ",angle"
    _write_csv(out / "density.csv", header, cols, fmts)
    plots.plot_heatmaps(out / "density_heatmap.png", r_values, alpha_values, grids, r_limit=config.r_limit)
    dir_angle = 90.0 if 90.0 in angles else angles[0]
    beta = np.linspace(0.0, np.pi / 2, 121)
    gamma = np.linspace(0.0, 2 * np.pi, 2 * 121)
    cases = [
        (r, a, dens.rho_direction_grid(r, a, beta, gamma, angle=dir_angle), float(dens.rho(r, a, angle=dir_angle)))
        for r, a in [(0.0, 0.0), (0.5, np.radians(60.0)), (0.8, 0.0), (0.8, np.pi / 2), (0.8, np.pi)]
    ]
    plots.plot_directional(out / "density_directional.png", cases, beta, gamma, angle=dir_angle)


def _real_rigs(config: DensityConfig, angles: list[float], summary: dict, progress: bool) -> list:
    """Each angle's real rig: its name and hit ratios added to ``summary``, and (with ``config.mc``) its
    Monte-Carlo check; returns every :class:`~spotlights.analysis.montecarlo.MCResult`, angle by angle."""
    all_results = []
    placements = [DiscPlacement(0.0, 0.0)] + [
        DiscPlacement(float(r), float(np.radians(ad))) for r in config.mc_radii if r > 0 for ad in config.mc_alphas_deg
    ]
    for a in angles:
        rig = make_rig(config.mc_primary, config.mc_secondary, angle=a)
        summary["angles"][f"{a:g}"]["rig"] = rig.name
        summary["angles"][f"{a:g}"].update(hit_ratios(rig))
        if config.mc:
            res = mc_density(
                rig,
                placements,
                disc_radius=config.disc_radius,
                n_rotations=config.mc_rotations,
                seed=config.seed + int(round(1000 * a)),
                progress=progress,
            )
            all_results.extend(res)
            summary["angles"][f"{a:g}"]["montecarlo"] = _mc_stats(res)
    return all_results


def _plot_caps(out: Path, angles: list[float], summary: dict, r_values, alpha_values, grids) -> None:
    """``density_caps.png``: the angles' uniformity and hit ratios, and their profiles at alpha 0 and 90 deg."""
    table = [
        {
            "angle": a,
            "uniformity": summary["angles"][f"{a:g}"]["uniformity_max_over_min"],
            "uniformity_095": summary["angles"][f"{a:g}"]["uniformity_max_over_min_r_le_0.95"],
            "hit_ratio_05": summary["angles"][f"{a:g}"]["hit_ratio_05"],
            "hit_ratio_08": summary["angles"][f"{a:g}"]["hit_ratio_08"],
        }
        for a in angles
    ]
    ia0 = 0
    ia90 = int(np.argmin(np.abs(alpha_values - np.pi / 2)))
    profiles = {a: {"alpha0": grids[a][:, ia0], "alpha90": grids[a][:, ia90]} for a in angles}
    plots.plot_caps(out / "density_caps.png", r_values, profiles, table)


def density_summary_lines(summary: dict, timings: dict, cfg: DensityConfig, out: str | os.PathLike) -> list[str]:
    """The lines ``spotlights analyze density`` prints: per cap angle (degrees) the density's
    extremes over ``r <= cfg.r_limit`` (per unit ``N*M``, with where they lie: r, alpha in degrees),
    its uniformity, the value at the centre beside the closed form, the real rig's hit ratios and
    the Monte-Carlo agreement; then the timings (seconds). ``summary``/``timings``: what
    :func:`run_density_analysis` returns; ``out``: its output folder."""
    out_lines = [f"ray density per unit N*M (paper Section 3.3); outputs in {out}/"]
    lim = f"{cfg.r_limit:g}"
    for key, s in summary["angles"].items():
        ext = s[f"range_r_le_{lim}"]

        def where(k):
            r = ext[f"{k}_r"]
            return f"r={r:.2f}, " + ("any alpha" if r < 1e-9 else f"alpha={np.degrees(ext[f'{k}_alpha']):.0f} deg")

        out_lines.append(
            f"omega = {key:>4} deg: r <= {lim}: min {ext['min']:.5f} ({where('min')}), "
            f"max {ext['max']:.5f} ({where('max')}), max/min {s['uniformity_max_over_min']:.2f} "
            f"({s['uniformity_max_over_min_r_le_0.95']:.2f} over r <= 0.95); "
            f"r=0: {s['rho_r0']:.5f} (closed form {s['rho_r0_closed_form']:.5f}); "
            f"quadrature error < {s['quadrature_max_abs_error']:.1e}"
        )
        out_lines.append(
            f"                 real rig {s['rig']}: {s['hit_ratio_05']:.1%} of rays enter the ball r <= 0.5, "
            f"{s['hit_ratio_08']:.1%} the ball r <= 0.8"
        )
        if "montecarlo" in s:
            m = s["montecarlo"]
            out_lines.append(
                f"                 Monte-Carlo: {m['comparisons']} disc faces, max |z| {m['max_abs_z']:.2f}, "
                f"rms z {m['rms_z']:.2f}, {m['within_2_sigma']:.0%} within 2 sigma, "
                f"median |deviation| {m['median_abs_rel_deviation']:.2%} (median 1-sigma {m['median_rel_se']:.2%})"
            )
            if m["min_shells"] < 3.0:
                out_lines.append(
                    f"                 note: some discs span only {m['min_shells']:.1f} cap steps (< 3): the finite-M "
                    "term is unreliable there; use more rays per viewpoint (M) or a larger disc"
                )
    out_lines.append(
        f"done in {timings['total']:.1f} s (quadrature {timings['quadrature_grid']:.1f} s, "
        f"Monte-Carlo {timings['montecarlo']:.1f} s)"
    )
    return out_lines
