"""The real-data steps of ``spotlights reproduce``: extracting the real scans and scoring Table 2's consistency.

:func:`real_steps` lists them as :class:`~.pipeline.Step` records (``real-<source>``,
``consistency-<set>``, ``consistency-av2-box``); :func:`.steps.work_steps` puts them in
execution order with the other work steps.
"""

from __future__ import annotations

from pathlib import Path

from ...data.real import SceneReader, open_reader
from ...data.real.extract import SKIP_REASONS, ExtractConfig, extract, write_observations
from ...errors import SpotlightsError
from ...learning.inference import load_completer
from .. import real_evaluation
from ..real_evaluation import evaluate_consistency, reference_shapes
from .pipeline import Context, Step, shell_quote
from .settings import BOX_RUNS, TABLE2_CLASSES, TABLE2_RUNS, TABLE2_SETS


def completers(ctx: Context, runs) -> list:
    """The completers (``learning.inference``) of the ``best.pt`` of ``runs``, on the CPU."""
    return [load_completer(ctx.run_dir(r) / "best.pt", device="cpu") for r in runs]


# --- real data ----------------------------------------------------------------------------------
REAL_SOURCES = {  # name -> (folder under --lidar, format)
    "kitti": ("kitti-object/training-fov-cropped", "kitti"),
    "av2": ("argoverse2", "av2"),
    "nuscenes": ("nuscenes", "nuscenes"),
}


class FirstFrames(SceneReader):
    """The first ``n`` frames of ``reader`` (in its time order): ``reproduce --quick`` scores a short stretch."""

    def __init__(self, reader: SceneReader, n: int):
        self.reader, self.n = reader, int(n)
        self.format, self.root = reader.format, reader.root

    def frame_keys(self) -> list[tuple[str, str]]:
        """The first ``n`` (sequence, frame_id) keys of the wrapped reader."""
        return self.reader.frame_keys()[: self.n]

    def load(self, key: tuple[str, str]):
        """One frame of the wrapped reader."""
        return self.reader.load(key)


def real_frames(ctx: Context, name: str) -> int | None:
    """Frames extracted from source ``name``: --quick keeps the first few of each Table 2 set (None: all)."""
    return ctx.s.real_frames if name in TABLE2_SETS else None


def real_min_points(ctx: Context, name: str) -> int | None:
    """Points an extracted object of source ``name`` needs: --quick keeps the better-seen objects of each
    Table 2 set (None: the extraction's default)."""
    return ctx.s.real_min_points if name in TABLE2_SETS else None


def real_classes(name: str) -> tuple | None:
    """Classes extracted from source ``name``: Table 2's (car, truck, trailer) for its sets, None (the
    extraction's default, the paper's four classes) for KITTI (the qualitative figure)."""
    return TABLE2_CLASSES if name in TABLE2_SETS else None


def _real_command(ctx: Context, name: str) -> str:
    folder, fmt = REAL_SOURCES[name]
    classes = real_classes(name)
    return (
        f"spotlights real extract {shell_quote(Path(ctx.s.lidar) / folder)} --format {fmt}"
        + (f" --classes {','.join(classes)}" if classes else "")
        + (f" --min-points {real_min_points(ctx, name)}" if real_min_points(ctx, name) else "")
        + f" --out {shell_quote(ctx.out / 'data' / f'{name}.h5')}"
        + (f" (--quick: the first {real_frames(ctx, name)} frames)" if real_frames(ctx, name) else "")
    )


def _run_real(ctx: Context, name: str) -> dict:
    folder, fmt = REAL_SOURCES[name]
    src = Path(ctx.s.lidar) / folder
    if not src.exists():
        raise SpotlightsError(
            f"{src}: real LiDAR data not found (pass --lidar DIR, the folder of the shared lidar data)"
        )
    classes = real_classes(name)
    min_points = real_min_points(ctx, name)
    cfg = ExtractConfig(
        seed=ctx.s.seed,
        **({"classes": classes} if classes else {}),
        **({"min_points": min_points} if min_points else {}),
    )
    reader = open_reader(src, fmt)
    if real_frames(ctx, name):
        reader = FirstFrames(reader, real_frames(ctx, name))
    obs = extract(reader, cfg, progress=ctx.s.progress)
    write_observations(ctx.out / "data" / f"{name}.h5", obs)
    return {"observations": len(obs), "frames": int(obs.meta["n_frames"]), "classes": list(cfg.classes)}


def _skip_reasons() -> list[str]:
    """The extraction's skip reasons: a new one (e.g. duplicate_box) changes what is extracted, so it re-runs the step."""
    return list(SKIP_REASONS)


CONSISTENCY_OPTIONS = {
    "classes": list(TABLE2_CLASSES),
    "equal_points": real_evaluation.EQUAL_POINTS,
    "equal_density": real_evaluation.EQUAL_DENSITY,
    "noise_floor": True,
    "heading_check": True,
}
"""What Table 2's consistency steps ask of :func:`evaluate_consistency`: Table 2's classes and the defaults of
``spotlights real evaluate`` (equal density 0.1, equal point counts 512, the resampling noise floor, the heading
check)."""


def _consistency_command(ctx: Context, name: str) -> str:
    ck = " ".join(shell_quote(ctx.run_dir(r) / "best.pt") for r in TABLE2_RUNS)
    return (
        f"spotlights real evaluate {shell_quote(ctx.out / 'data' / f'{name}.h5')} --checkpoint {ck} "
        f"--classes {','.join(CONSISTENCY_OPTIONS['classes'])} --equal-points {CONSISTENCY_OPTIONS['equal_points']} "
        f"--equal-density {CONSISTENCY_OPTIONS['equal_density']:g} "
        f"--names {' '.join(TABLE2_RUNS)} "
        f"--out {shell_quote(ctx.out / 'eval' / f'{name}_consistency')} --reference {shell_quote(ctx.s.cars_path)}"
    )


def _run_consistency(ctx: Context, name: str) -> dict:
    """Table 2 on real set ``name``: consistency (native and at equal counts), noise floor, fidelity, MMD,
    diversity, heading flips and out-of-domain counts of every Table 1 and product checkpoint."""
    runs = list(TABLE2_RUNS)
    refs, ref_info = reference_shapes(ctx.s.cars_path)
    rep = evaluate_consistency(
        ctx.out / "data" / f"{name}.h5",
        completers(ctx, runs),
        names=runs,
        checkpoints=[str(ctx.run_dir(r) / "best.pt") for r in runs],
        progress=ctx.s.progress,
        references=refs,
        reference_info=ref_info,
        **CONSISTENCY_OPTIONS,
    )
    real_evaluation.write_report(rep, ctx.out / "eval" / f"{name}_consistency")
    return {"objects": rep["data"]["n_objects_tracked"], "pairs": rep["data"]["n_pairs"]}


def _consistency_box_command(ctx: Context) -> str:
    ck = " ".join(shell_quote(ctx.run_dir(r) / "best.pt") for r in BOX_RUNS.values())
    return (
        f"spotlights real evaluate {shell_quote(ctx.out / 'data' / 'av2.h5')} --checkpoint {ck} "
        f"--out {shell_quote(ctx.out / 'eval' / 'av2_consistency_box')}"
    )


def _run_consistency_box(ctx: Context) -> dict:
    """Consistency on the AV2 tracks of SA-Net on the paper's rig and on the box rig (each observation's own box)."""
    runs = list(BOX_RUNS.values())
    rep = evaluate_consistency(
        ctx.out / "data" / "av2.h5",
        completers(ctx, runs),
        names=runs,
        checkpoints=[str(ctx.run_dir(r) / "best.pt") for r in runs],
        progress=ctx.s.progress,
    )
    real_evaluation.write_report(rep, ctx.out / "eval" / "av2_consistency_box")
    return {"objects": rep["data"]["n_objects_tracked"], "pairs": rep["data"]["n_pairs"]}


def _real_step(name: str) -> Step:
    """The step that extracts the real source ``name`` into ``OUT/data/<name>.h5``."""
    return Step(
        f"real-{name}",
        (lambda c, n=name: _run_real(c, n)),
        (lambda c, n=name: _real_command(c, n)),
        (lambda c, n=name: [c.out / "data" / f"{n}.h5"]),
        params=(
            lambda c, n=name: {
                "lidar": str(c.s.lidar),
                "skip_reasons": _skip_reasons(),
                "classes": list(real_classes(n) or ()),
                "frames": real_frames(c, n),
                # only when set: a full run's signature (and its finished steps) stays as it was
                **({"min_points": real_min_points(c, n)} if real_min_points(c, n) else {}),
            }
        ),
    )


def _consistency_step(name: str) -> Step:
    """The step that scores Table 2 on the real set ``name`` with every Table 2 checkpoint."""
    return Step(
        f"consistency-{name}",
        (lambda c, n=name: _run_consistency(c, n)),
        (lambda c, n=name: _consistency_command(c, n)),
        (lambda c, n=name: [c.out / "eval" / f"{n}_consistency.json"]),
        needs=(f"real-{name}", "cars-data") + tuple(f"train-{r}" for r in TABLE2_RUNS),
        inputs=(
            lambda c, n=name: (
                [c.out / "data" / f"{n}.h5", c.s.cars_path] + [c.run_dir(r) / "best.pt" for r in TABLE2_RUNS]
            )
        ),
        params=lambda c: {
            "scores": ["consistency", "fidelity", "mmd", "diversity"],
            "runs": list(TABLE2_RUNS),
            **CONSISTENCY_OPTIONS,
        },
    )


def _consistency_box_step() -> Step:
    """The step that scores consistency on the AV2 tracks of SA-Net on the paper's rig and on the box rig."""
    box_runs = tuple(BOX_RUNS.values())
    return Step(
        "consistency-av2-box",
        _run_consistency_box,
        _consistency_box_command,
        lambda c: [c.out / "eval" / "av2_consistency_box.json"],
        needs=("real-av2",) + tuple(f"train-{r}" for r in box_runs),
        inputs=lambda c: [c.out / "data" / "av2.h5"] + [c.run_dir(r) / "best.pt" for r in box_runs],
    )


def real_steps() -> list[Step]:
    """The real-data steps in execution order: one extraction per source, one consistency per Table 2 set, the box
    rig's consistency."""
    return [
        *(_real_step(name) for name in REAL_SOURCES),
        *(_consistency_step(name) for name in TABLE2_SETS),
        _consistency_box_step(),
    ]
