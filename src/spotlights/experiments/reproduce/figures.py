"""The figures of the ``spotlights reproduce`` report: one step each, drawn on matplotlib Figures (no pyplot state).

:data:`FIGURES` maps a figure step to its file under ``OUT/figures`` and its caption;
:func:`figure_steps` lists the steps.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ...data.real.extract import read_observations
from ...data.real.frames import frame_rows
from ...data.store import open_dataset
from ...geometry.encode import MeshProbe, decode
from ...geometry.io import load_mesh
from ...geometry.rig import make_rig, make_rig_spec
from ...geometry.sampling import sample_surface
from ...viz import render_cloud_grid, render_frame, render_rig_rays
from ..density_report import DensityConfig, run_density_analysis
from ..real_evaluation import complete_all
from ..rig_study import BOX_RIGS, find_meshes, mesh_axes
from .pipeline import Context, Step, shell_quote
from .settings import ABLATION_RAYS, BOX_STUDY_LABELS, DISPLAY, TABLE1_RUNS, Settings
from .steps import completers

FIGURES = {  # figure step -> (file under figures/, caption)
    "fig-rig": (
        "rig.png",
        "The rig (32 x 64 rays, 60°): the viewpoints on the unit sphere and one viewpoint's bundle of rays on a car.",
    ),
    "fig-density": (
        "density/density_heatmap.png",
        "Ray density per unit N*M over the sphere (radius r, angle alpha to the radial) "
        "for a 60° cap and the paper's hemisphere (90°) (spotlights.analysis).",
    ),
    "fig-gt": (
        "gt_clouds.png",
        "Ground truth from uniform sampling (grey) and from Spotlights at 2048, 4096 and 8192 rays (green).",
    ),
    "fig-synthetic": (
        "completions_synthetic.png",
        "Completions of synthetic test scans: partial input (purple), each model's "
        "completion (green), the uniform ground truth (grey).",
    ),
    "fig-box": (
        "box_rig_clouds.png",
        "One car's Spotlights points at 2048 rays (32 x 64): the paper's 60° cap rig and the "
        "box-targeted rigs of the box table (green), beside uniform surface samples (grey).",
    ),
    "fig-real": (
        "completions_kitti.png",
        "KITTI: raw scan (grey), partial inputs (purple), SA-Net completions (green).",
    ),
}
EXTRA_FIGURES = {
    "fig-real": [
        ("completions_av2.png", "Argoverse 2: raw scan (grey), partial inputs (purple), SA-Net completions (green).")
    ]
}


def _cloud_grid(
    path: Path,
    rows: Sequence[Sequence[tuple]],
    title: str,
    row_labels: Sequence[str] | None = None,
    elev: float = 22.0,
    azim: float = -60.0,
) -> Path:
    """A grid of 3-D scatter panels, axes fixed to the unit sphere (see :func:`spotlights.viz.render_cloud_grid`)."""
    return render_cloud_grid(path, rows, title, row_labels, elev, azim)


def _figure_meshes(s: Settings) -> list:
    """A car and two category meshes for the pictures (first of their folders, sorted)."""
    cars = find_meshes([s.cars_meshes])
    cats = find_meshes([s.category_meshes])
    pick = [cars[0]]
    for c in ("chair", "lamp"):
        pick += [e for e in cats if e.category == c][:1]
    return pick


def _load_unit_mesh(entry):
    mesh = load_mesh(entry.path, **mesh_axes(entry.path))
    return mesh, MeshProbe(mesh)


def _run_fig_rig(ctx: Context) -> dict:
    """The rig with one viewpoint's rays on a car: hits (green) end on the surface, misses (orange) cross the sphere."""
    entry = _figure_meshes(ctx.s)[0]
    mesh, probe = _load_unit_mesh(entry)
    rig = make_rig(32, 64, angle=60.0)
    depth = probe.encode(rig).reshape(rig.n_primary, rig.n_secondary)
    share = (depth > 0).mean(axis=1)
    i = int(np.argmin(np.abs(share - 0.5)))  # a viewpoint with about half of its rays on the car
    surf = probe.normalization.to_unit(sample_surface(mesh, 4000, ctx.s.seed))
    render_rig_rays(
        ctx.figures / "rig.png",
        rig,
        depth,
        i,
        surf,
        f"{rig.name}: the {rig.n_primary} viewpoints (black) and the {rig.n_secondary} rays of viewpoint {i} (red):\n"
        f"{int((depth[i] > 0).sum())} hit the car (green), the others cross the sphere (orange)",
    )
    return {"mesh": entry.mesh_id, "viewpoint": i}


def _run_fig_density(ctx: Context) -> dict:
    summary, _ = run_density_analysis(
        ctx.figures / "density", DensityConfig(angles=(60.0, 90.0), mc=False), progress=False, log=lambda *a: None
    )
    return {"uniformity_max_over_min": {k: v["uniformity_max_over_min"] for k, v in summary["angles"].items()}}


def _run_fig_gt(ctx: Context) -> dict:
    """Uniform surface samples beside Spotlights points at 2048, 4096 and 8192 rays (cap 60)."""
    rows, labels = [], []
    for entry in _figure_meshes(ctx.s):
        mesh, probe = _load_unit_mesh(entry)
        uni = probe.normalization.to_unit(sample_surface(mesh, 2048, ctx.s.seed))
        row = [("uniform, 2048 points", [(uni, "#8c8c8c", 1.2)])]
        for rays in ABLATION_RAYS:
            rig = make_rig(rays // 64, 64, angle=60.0)
            pts, mask = decode(probe.encode(rig), rig)
            row.append((f"Spotlights {rays} rays ({int(mask.sum())} hits)", [(pts[mask], "#2a9d3f", 1.2)]))
        rows.append(row)
        labels.append(f"{entry.mesh_set}/{entry.mesh_id}")
    _cloud_grid(
        ctx.figures / "gt_clouds.png",
        rows,
        "Ground truth: uniform sampling vs Spotlights (32..128 x 64 rays, 60 deg)",
        labels,
    )
    return {"meshes": labels}


def _run_fig_box(ctx: Context) -> dict:
    """One car's Spotlights points at 2048 rays: the paper's 60-degree cap rig beside the box rigs of the box table."""
    entry = _figure_meshes(ctx.s)[0]
    mesh, probe = _load_unit_mesh(entry)
    uni = probe.normalization.to_unit(sample_surface(mesh, 2048, ctx.s.seed))
    row = [("uniform, 2048 points", [(uni, "#8c8c8c", 1.2)])]
    variants = [("paper, cap 60", dict(angle=60.0))] + [(lab, kw) for lab, kw in BOX_RIGS if lab in BOX_STUDY_LABELS]
    hits = {}
    for label, kw in variants:
        rig = probe.rig_for(make_rig_spec(32, 64, **kw))
        pts, mask = decode(probe.encode(rig), rig)
        hits[rig.name] = int(mask.sum())
        row.append((f"{label}: {rig.name}\n{int(mask.sum())} of {rig.n_rays} rays hit", [(pts[mask], "#2a9d3f", 1.2)]))
    _cloud_grid(
        ctx.figures / "box_rig_clouds.png",
        [row],
        "2048 rays (32 x 64): the paper's cap rig vs box-targeted rigs",
        [f"{entry.mesh_set}/{entry.mesh_id}"],
    )
    return {"mesh": entry.mesh_id, "hits": hits}


def _run_fig_synthetic(ctx: Context) -> dict:
    """Test samples (one per car category): partial, each model's completion, ground truth."""
    runs = ["sanet", "pcn", "foldingnet", "topnet", "atlasnet"]
    comps = completers(ctx, runs)
    rows, labels = [], []
    with open_dataset(ctx.s.cars_path) as ds:
        test = ds.split_indices("test")
        cats = ds.categories[ds.sample_model[test]]
        picks = []
        for c in sorted(set(cats.tolist())):
            picks.append(int(test[np.flatnonzero(cats == c)[0]]))
        for i in picks:
            smp = ds.sample(i)
            row = [(f"partial ({len(smp['partial'])} pts)", [(smp["partial"], "#7b2cbf", 2.0)])]
            for c in comps:
                out = c.complete(smp["partial"][None])[0]
                row.append((f"{DISPLAY[c.model_name]} ({len(out)} pts)", [(out, "#2a9d3f", 1.0)]))
            row.append(("ground truth (2048)", [(smp["gt_points"], "#8c8c8c", 1.0)]))
            rows.append(row)
            labels.append(f"{smp['model']} ({smp['category']}), view {smp['view']}")
    _cloud_grid(
        ctx.figures / "completions_synthetic.png", rows, "Completions of synthetic test scans (unit frame)", labels
    )
    return {"samples": labels}


def _run_fig_real(ctx: Context) -> dict:
    """KITTI and AV2: the frame with most vehicles, SA-Net completions drawn back in the scan."""
    sanet = completers(ctx, ["sanet"])[0]
    done = {}
    for name in ("kitti", "av2"):
        obs = read_observations(ctx.out / "data" / f"{name}.h5")
        rows = sorted(frame_rows(obs), key=lambda i: -int(obs.n_points_raw[i]))[:6]
        comps = complete_all(sanet, obs.partial[rows], progress=False)
        i0 = rows[0]
        render_frame(
            ctx.figures / f"completions_{name}.png",
            obs,
            rows,
            comps,
            title=f"{name}: frame {obs.frame_id[i0]}, SA-Net completions (green), partial inputs (purple)",
        )
        done[name] = {"frame": obs.frame_id[i0], "objects": len(rows)}
    return done


FIGURE_COMMAND = "(drawn by spotlights reproduce; helpers in spotlights.experiments.reproduce.figures)"


def figure_steps() -> list[Step]:
    """The figure steps, in execution order."""
    fig_cmd = lambda c: FIGURE_COMMAND  # noqa: E731
    return [
        Step("fig-rig", _run_fig_rig, fig_cmd, lambda c: [c.figures / "rig.png"]),
        Step(
            "fig-density",
            _run_fig_density,
            lambda c: f"spotlights analyze density --angle 60 90 --no-mc --out {shell_quote(c.figures / 'density')}",
            lambda c: [c.figures / "density" / "density_heatmap.png"],
        ),
        Step("fig-gt", _run_fig_gt, fig_cmd, lambda c: [c.figures / "gt_clouds.png"]),
        Step("fig-box", _run_fig_box, fig_cmd, lambda c: [c.figures / "box_rig_clouds.png"]),
        Step(
            "fig-synthetic",
            _run_fig_synthetic,
            fig_cmd,
            lambda c: [c.figures / "completions_synthetic.png"],
            needs=("cars-data",) + tuple(f"train-{r}" for r in TABLE1_RUNS),
            inputs=lambda c: [c.s.cars_path] + [c.run_dir(r) / "best.pt" for r in TABLE1_RUNS],
        ),
        Step(
            "fig-real",
            _run_fig_real,
            fig_cmd,
            lambda c: [c.figures / "completions_kitti.png", c.figures / "completions_av2.png"],
            needs=("real-kitti", "real-av2", "train-sanet"),
            inputs=lambda c: [c.out / "data" / "kitti.h5", c.out / "data" / "av2.h5", c.run_dir("sanet") / "best.pt"],
        ),
    ]
