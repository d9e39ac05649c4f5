"""Figures of the ray-density analysis (paper Section 3.3; numbers from :mod:`spotlights.analysis`).

Every function writes one PNG atomically (temporary name, then rename) and
returns its path. Densities are per unit ``N*M`` (see :mod:`spotlights.analysis.density`).
The figures take arrays: the analysis computes, this module only draws.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ._figure import colormap, new_figure, save_png

__all__ = ["plot_heatmaps", "plot_montecarlo", "plot_directional", "plot_caps"]

#: line and marker colour per disc orientation alpha (degrees) of :func:`plot_montecarlo`
_MC_COLOURS = {0.0: "tab:blue", 45.0: "tab:orange", 90.0: "tab:green", 135.0: "tab:orange", 180.0: "tab:blue"}


def _save(fig, path, dpi=120) -> Path:
    return save_png(fig, path, dpi, deterministic=True)


def plot_heatmaps(
    path: str | os.PathLike,
    r_values: np.ndarray,
    alpha_values: np.ndarray,
    grids: dict[float, np.ndarray],
    r_limit: float = 0.8,
) -> Path:
    """Heat maps of ``rho(r, alpha)`` per cap angle (the paper's density figure for 90 degrees).

    Args:
        r_values: (R,) radii. alpha_values: (A,) radians. grids: cap angle (degrees) -> (R, A)
            density per unit N*M. r_limit: radius marked by a dashed line (the paper's 0.8).
    """
    angles = list(grids)
    ncol = min(len(angles), 2)
    nrow = (len(angles) + ncol - 1) // ncol
    fig = new_figure(5.6 * ncol, 4.6 * nrow)
    axes = fig.subplots(nrow, ncol, squeeze=False)
    for ax in axes.ravel()[len(angles) :]:
        ax.set_visible(False)
    for ax, ang in zip(axes.ravel(), angles):
        g = grids[ang]
        inside = r_values <= r_limit + 1e-12
        lo, hi = float(g[inside].min()), float(g[inside].max())
        vmax = float(g[r_values <= 0.9 + 1e-12].max())  # keep contrast where the claim is made
        im = ax.pcolormesh(
            r_values, np.degrees(alpha_values), g.T, shading="nearest", cmap="viridis", vmin=float(g.min()), vmax=vmax
        )
        levels = np.unique(np.round(np.linspace(lo, hi, 7), 4))
        if len(levels) > 1:
            cs = ax.contour(r_values, np.degrees(alpha_values), g.T, levels=levels, colors="white", linewidths=0.7)
            ax.clabel(cs, fmt="%.3f", fontsize=7)
        ax.axvline(r_limit, color="red", ls="--", lw=1.0)
        ax.set_xlabel("r  (distance of the surfel from the centre, R = 1)")
        ax.set_ylabel("alpha  (normal vs outward radial, degrees)")
        ax.set_yticks([0, 45, 90, 135, 180])
        title = "paper setting, 2 pi per source" if abs(ang - 90.0) < 1e-9 else "cap"
        ax.set_title(
            f"rho / (N M), omega = {ang:g} deg ({title})\nr <= {r_limit:g}: min {lo:.4f}, max {hi:.4f}", fontsize=10
        )
        cb = fig.colorbar(im, ax=ax, extend="max")
        cb.set_label("rays per unit area / (N M)")
    fig.tight_layout()
    return _save(fig, path)


def plot_montecarlo(
    path: str | os.PathLike, results: Sequence, curves: dict[float, tuple[np.ndarray, dict[float, np.ndarray]]]
) -> Path:
    """Monte-Carlo densities of real rigs against the quadrature, one column per cap angle.

    Args:
        results: :class:`~spotlights.analysis.montecarlo.MCResult` records.
        curves: angle -> (r (R,), {alpha_deg: rho (R,)}) continuum curves to draw.
    Top row: continuum ``rho(r)`` for several alpha (lines), Monte-Carlo disc densities with
    2-sigma error bars (filled markers) and the rig-aware expectation (open markers).
    Bottom row: relative deviation of the Monte-Carlo from the rig-aware expectation
    (filled, 2-sigma bars) and from the bare continuum (grey crosses).
    """
    angles = list(curves)
    ncol = min(len(angles), 2)
    nrow = (len(angles) + ncol - 1) // ncol
    fig = new_figure(6.4 * ncol, 7.6 * nrow)
    axes = fig.subplots(2 * nrow, ncol, squeeze=False, gridspec_kw={"height_ratios": [3, 2] * nrow})
    for j in range(len(angles), nrow * ncol):
        axes[2 * (j // ncol), j % ncol].set_visible(False)
        axes[2 * (j // ncol) + 1, j % ncol].set_visible(False)
    for j, ang in enumerate(angles):
        ax, bx = axes[2 * (j // ncol), j % ncol], axes[2 * (j // ncol) + 1, j % ncol]
        rr, by_alpha = curves[ang]
        for a_deg, vals in by_alpha.items():
            ax.plot(
                rr,
                vals,
                color=_MC_COLOURS.get(a_deg, "k"),
                lw=1.2,
                label=f"quadrature, alpha = {a_deg:g} deg" + (f" (= {180 - a_deg:g})" if a_deg < 90 else ""),
            )
        sel = [x for x in results if abs(x.angle - ang) < 1e-9]
        rel = [x.rho_mc / x.rho_expected - 1.0 for x in sel]
        lim = 100 * max([abs(v) + 2.5 * x.se_mc / x.rho_expected for v, x in zip(rel, sel)] + [0.01])
        lim = float(np.ceil(1.2 * lim * 2) / 2)
        for x, rv in zip(sel, rel):
            _draw_mc_result(ax, bx, x, rv, lim)
        if sel:
            zs = np.array([x.z for x in sel])
            n, m, k = sel[0].n_primary, sel[0].n_secondary, sel[0].n_rotations
            ax.set_title(
                f"omega = {ang:g} deg: real rig {n} x {m} rays, disc a = {sel[0].disc_radius:g}, "
                f"{k} rotations\nmax |z| = {np.max(np.abs(zs)):.2f}, "
                f"{np.mean(np.abs(zs) < 2):.0%} within 2 sigma",
                fontsize=9,
            )
        _finish_mc_axes(ax, bx, lim)
    fig.tight_layout()
    return _save(fig, path)


def _draw_mc_result(ax, bx, x, rv: float, lim: float) -> None:
    """One Monte-Carlo disc face: its density and expectation on ``ax``, its relative deviations
    (%, ``rv`` from the expectation) on ``bx``, a value past ``lim`` pinned to the edge."""
    a_deg = round(float(np.degrees(x.alpha)), 6)
    col = _MC_COLOURS.get(a_deg, "k")
    dx = 0.006 if x.side == "back" else -0.006
    ax.errorbar(x.r + dx, x.rho_mc, yerr=2 * x.se_mc, fmt="o", ms=3.5, color=col, capsize=2, lw=0.8)
    ax.plot(x.r + dx, x.rho_expected, marker="o", ms=7, mfc="none", color=col, lw=0)
    bx.errorbar(x.r + dx, 100 * rv, yerr=200 * x.se_mc / x.rho_expected, fmt="o", ms=3.5, color=col, capsize=2, lw=0.8)
    cont = 100 * (x.rho_mc / x.rho_quad - 1.0)
    if abs(cont) <= lim:
        bx.plot(x.r + dx, cont, "x", color="0.55", ms=4)
    else:  # off the scale: pin to the edge and print the value
        bx.plot(x.r + dx, np.sign(cont) * 0.97 * lim, marker="^" if cont > 0 else "v", color="0.55", ms=5)
        if x.side == "front":
            bx.annotate(
                f"{cont:+.0f} % vs continuum\n(every bundle's central\nray crosses the centre)",
                (x.r, np.sign(cont) * 0.97 * lim),
                textcoords="offset points",
                xytext=(10, -28),
                fontsize=7,
                color="0.35",
            )


def _finish_mc_axes(ax, bx, lim: float) -> None:
    """Labels and legends of one column of :func:`plot_montecarlo`; ``bx`` spans +-``lim`` %."""
    ax.plot([], [], "ko", ms=3.5, label="Monte-Carlo, real rays (2 sigma bars)")
    ax.plot([], [], "o", mfc="none", color="k", ms=7, label="expected: quadrature over the disc + finite-M term")
    ax.set_xlabel("r")
    ax.set_ylabel("rho / (N M)")
    ax.legend(fontsize=7, loc="best")
    bx.axhline(0.0, color="k", lw=0.8)
    bx.plot([], [], "x", color="0.55", label="vs continuum only (no finite-M term)")
    bx.plot([], [], "ko", ms=3.5, label="vs expected (2 sigma bars)")
    bx.set_xlabel("r")
    bx.set_ylabel("Monte-Carlo / expected - 1  (%)")
    bx.legend(fontsize=7, loc="lower right")
    bx.set_ylim(-lim, lim)


def plot_directional(
    path: str | os.PathLike,
    cases: Sequence[tuple[float, float, np.ndarray, float]],
    beta: np.ndarray,
    gamma: np.ndarray,
    angle: float = 90.0,
) -> Path:
    """The paper's occlusion formula ``rho(r, alpha, beta, gamma)`` over the surfel's front hemisphere.

    Args:
        cases: ``(r, alpha, grid, integral)`` per panel: alpha in radians, grid (B, G) the
            density per steradian on ``beta`` x ``gamma``, integral = rho(r, alpha).
        beta: (B,) polar angle from the normal, radians in [0, pi/2]. gamma: (G,) azimuth,
            radians (0 = towards the sphere centre). angle: the cap angle (degrees, for the title).

    One polar panel per case: radius = beta (0-90 degrees), angle = gamma. The colour is
    the density per steradian of arrival direction (per unit N*M): what is lost when that
    direction is blocked. The title gives its integral (= rho(r, alpha)).
    """
    fig = new_figure(4.0 * len(cases), 4.3)
    axes = fig.subplots(1, len(cases), subplot_kw={"projection": "polar"}, squeeze=False)
    for ax, (r, a, g, integral) in zip(axes[0], cases):
        im = ax.pcolormesh(gamma, np.degrees(beta), g, shading="nearest", cmap="magma", vmin=0.0)
        ax.set_ylim(0, 90)
        ax.set_yticks([30, 60, 90])
        ax.set_yticklabels(["30", "60", "beta=90"], fontsize=7)
        ax.tick_params(axis="x", labelsize=7)
        ax.set_title(f"r = {r:g}, alpha = {np.degrees(a):g} deg\nintegral = {float(integral):.4f}", fontsize=9)
        fig.colorbar(im, ax=ax, shrink=0.7, pad=0.1).ax.tick_params(labelsize=7)
    fig.suptitle(
        f"density per steradian of arrival direction, omega = {angle:g} deg "
        "(gamma = 0 points towards the sphere centre)",
        fontsize=10,
    )
    fig.tight_layout()
    return _save(fig, path)


def plot_caps(
    path: str | os.PathLike, r_values: np.ndarray, profiles: dict[float, dict[str, np.ndarray]], table: Sequence[dict]
) -> Path:
    """How the cap angle trades uniformity for hit ratio.

    Args:
        profiles: angle -> {"alpha0": (R,), "alpha90": (R,)} densities on ``r_values``.
        table: rows with ``angle``, ``uniformity`` / ``uniformity_095`` (max/min over r <= 0.8 /
            r <= 0.95) and ``hit_ratio_05`` (fraction of a real rig's rays entering the centred
            ball of radius 0.5).
    Left: density normalised by its value at the centre, alpha = 0 (solid) and 90 deg (dashed).
    Right: uniformity against hit ratio, one point per cap angle.
    """
    fig = new_figure(11, 4.4)
    ax, bx = fig.subplots(1, 2)
    cmap = colormap("plasma")
    angles = list(profiles)
    for i, ang in enumerate(angles):
        col = cmap(i / max(len(angles), 1))
        p = profiles[ang]
        ax.plot(r_values, p["alpha0"] / p["alpha0"][0], color=col, lw=1.5, label=f"omega = {ang:g} deg, alpha = 0")
        ax.plot(
            r_values,
            p["alpha90"] / p["alpha90"][0],
            color=col,
            lw=1.5,
            ls="--",
            label=f"omega = {ang:g} deg, alpha = 90",
        )
    ax.axvline(0.8, color="red", ls=":", lw=1)
    ax.set_xlabel("r")
    ax.set_ylabel("rho(r) / rho(0)")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    ax.set_title("density relative to the centre", fontsize=10)
    for i, row in enumerate(table):
        col = cmap(i / max(len(table), 1))
        bx.plot(row["hit_ratio_05"], row["uniformity"], "o", color=col, ms=8)
        bx.plot(row["hit_ratio_05"], row["uniformity_095"], "s", color=col, ms=8)
        bx.annotate(
            f"{row['angle']:g} deg",
            (row["hit_ratio_05"], row["uniformity_095"]),
            textcoords="offset points",
            xytext=(-10, 9 if i % 2 == 0 else -15),
            fontsize=8,
        )
    bx.plot([], [], "ko", label="max / min over r <= 0.8")
    bx.plot([], [], "ks", label="max / min over r <= 0.95")
    bx.set_xlabel("hit ratio: fraction of the real rig's rays entering the ball r <= 0.5")
    bx.set_ylabel("max / min of rho over all alpha")
    bx.set_yscale("log")
    bx.set_xlim(0.0, 1.08)
    bx.legend(fontsize=8)
    bx.set_title("uniformity vs hit ratio (identical on r <= sin(omega): rho scales by 1/(1 - cos omega))", fontsize=9)
    fig.tight_layout()
    return _save(fig, path)
