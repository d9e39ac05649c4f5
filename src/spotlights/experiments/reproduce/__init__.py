"""``spotlights reproduce``: every table of the paper, recomputed, beside the paper's values.

:func:`reproduce` runs the *steps* each selected *table* needs (build or reuse the car
dataset, train or reuse the checkpoints, evaluate them, extract the real scans, run the
rig study, draw the figures) and writes, under ``OUT``::

    OUT/REPORT.md                 every table, ours beside the paper's, differences explained,
                                  figures, commands, versions, seeds, wall time of every step
    OUT/results.json              every number of the report (ours and the paper's)
    OUT/tables/table<K>.json|csv  one table each (CSV: table, row, column, ours, paper)
    OUT/figures/*.png             the figures
    OUT/steps.json                one record per step: status, seconds, command, inputs
    OUT/data/cars.h5              the car dataset (or --cars-data FILE), kitti.h5, av2.h5, nuscenes.h5
    OUT/runs/<run>/               checkpoints: sanet pcn foldingnet topnet atlasnet (Table 1),
                                  sanet-hit-box sanet-hit-dense (Tables 1 and 2: the product's hit-aware
                                  SA-Nets, 2,048 and 16,384 rays; the second is the default model),
                                  sanet-64x32 sanet-256x64 (Table 5; its 32x64 row is run sanet),
                                  sanet-box (the box table: SA-Net on box-32x64-ellipsoid-s1)
    OUT/eval/<run>.md|json        'spotlights evaluate' report of each checkpoint;
                                  av2_consistency, nuscenes_consistency (Table 2), av2_consistency_box
    OUT/rig_study/                the per-mesh rig study behind Tables 3, 4 and box (cached per mesh)

Resuming: every output is written atomically and each finished step is recorded in
``steps.json`` with the signature of its inputs (file sizes and times, parameters); a
rerun reuses every step whose record, inputs and outputs still hold, so an interrupted run
continues at its first unfinished step. Datasets and checkpoints that exist are reused
even without a record (a run whose ``last.pt`` finished its epochs as is, an unfinished
one is resumed).

The parts: :mod:`.settings` (what is computed: runs, rigs, sizes), :mod:`.pipeline` (the step
engine: signatures, records, resuming), :mod:`.steps` (datasets, training, evaluation, rig
study; the real data and consistency in :mod:`.steps_real`), :mod:`.figures`, :mod:`.tables`
(a registry: one module per group of tables), :mod:`.report` (REPORT.md from the template ``report.md``; results.json; publish).
Adding a table is one :class:`~.tables.Table` entry of :data:`~.tables.TABLES` and its
builder (and its steps, if they are new): see docs/architecture.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ...errors import ParameterError, SpotlightsError
from ...learning.models import schedule_path
from ...locks import exclusive_lock
from ...timing import StageTimer
from .figures import figure_steps
from .pipeline import Context, Step, execute, load_records, now, resolve, save_records
from .report import publish, write_report
from .settings import (
    BOX_RIG,
    BOX_RUNS,
    BOX_STUDY_LABELS,
    PRODUCT_RUNS,
    RUNS,
    TABLE1_RUNS,
    TABLE5_RUNS,
    RunSpec,
    Settings,
)
from .steps import run_state, work_steps
from .tables import TABLES, Table, parse_tables, table_steps

__all__ = [
    "BOX_RIG",
    "BOX_RUNS",
    "BOX_STUDY_LABELS",
    "PRODUCT_RUNS",
    "RUNS",
    "TABLE1_RUNS",
    "TABLE5_RUNS",
    "TABLES",
    "Context",
    "ReproduceResult",
    "RunSpec",
    "Settings",
    "Step",
    "Table",
    "all_steps",
    "parse_tables",
    "plan",
    "publish",
    "reproduce",
    "run_state",
    "write_report",
]


def all_steps(ctx: Context) -> dict:
    """Every step of a reproduction, by name, in execution order: work, figures, tables."""
    return {st.name: st for st in [*work_steps(), *figure_steps(), *table_steps(ctx)]}


def plan(ctx: Context, tables: Sequence[str]) -> list[Step]:
    """The steps the tables need (``ctx.steps``), their dependencies included, in execution order."""
    return resolve(ctx.steps, [f"table-{k}" for k in tables])


@dataclass
class ReproduceResult:
    """What :func:`reproduce` did: the report's path, the steps run and reused, the wall time."""

    report: Path
    results: Path
    ran: list = field(default_factory=list)
    reused: list = field(default_factory=list)
    seconds: float = 0.0


def _settings(
    out, *, quick, schedule, cars_data, cars_meshes, category_meshes, lidar, eval_views, workers, seed, progress
) -> Settings:
    """The :class:`Settings` of :func:`reproduce`'s arguments; raises :class:`ParameterError` for bad counts."""
    if eval_views == "default":
        eval_views = 4 if quick else 200
    if eval_views is not None and int(eval_views) < 1:
        raise ParameterError(f"`eval_views` must be >= 1, got {eval_views}", "eval_views")
    if workers is not None and int(workers) < 1:
        raise ParameterError(f"`workers` must be >= 1, got {workers}", "workers")
    kw = {
        k: Path(v)
        for k, v in (("cars_meshes", cars_meshes), ("category_meshes", category_meshes), ("lidar", lidar))
        if v is not None
    }
    return Settings(
        out=Path(out),
        quick=quick,
        schedule=schedule or ("quick" if quick else "budget"),
        cars_data=Path(cars_data) if cars_data else None,
        eval_views=None if eval_views is None else int(eval_views),
        workers=int(workers or 1),
        seed=int(seed),
        progress=progress,
        **kw,
    )


def _check_paths(s: Settings) -> None:
    """Fail before anything is made: an unknown schedule, an output that is a file, a missing --cars-data."""
    schedule_path(s.schedule)  # an unknown schedule fails now, not after an hour
    if s.out.exists() and not s.out.is_dir():
        raise SpotlightsError(f"{s.out}: exists and is not a folder")
    if s.cars_data is not None and not s.cars_data.is_file():  # fails before the output folder is made
        raise SpotlightsError(f"{s.cars_data}: --cars-data names no such file")


def _execute_all(ctx: Context, todo: list, progress: bool) -> tuple[list, list]:
    """Run or reuse each step of ``todo`` in order under a progress bar: (names run, names reused)."""
    from tqdm import tqdm

    ran, reused = [], []
    bar = tqdm(total=len(todo), desc="reproduce", unit="step", disable=not progress, position=0, dynamic_ncols=True)
    try:
        for st in todo:
            bar.set_postfix_str(st.name)
            (ran if execute(ctx, st) == "ran" else reused).append(st.name)
            bar.update()
    finally:
        bar.close()
    return ran, reused


def reproduce(
    out,
    tables=None,
    quick: bool = False,
    schedule: str | None = None,
    cars_data=None,
    cars_meshes=None,
    category_meshes=None,
    lidar=None,
    eval_views: int | None | str = "default",
    workers: int | None = None,
    seed: int = 0,
    progress: bool = True,
    log=None,
    argv: Sequence[str] | None = None,
) -> ReproduceResult:
    """Run (or resume) the reproduction of ``tables`` into ``out``; see the module docstring.

    Parameters
    ----------
    tables : keys of :data:`TABLES` or a "1,2,5" string (default: all).
    quick : small data and the ``quick`` schedule (minutes; its numbers only show that all runs).
    schedule : schedule of new training runs (default ``budget``; ``quick`` with ``quick``).
    cars_data : an existing car dataset (with rigs cap-32x64-60, cap-64x32-60, cap-256x64-60; the runs on
        box-32x64-ellipsoid-s1 and box-128x128-ellipsoid-s1 add those rigs with dataset add-rig when the
        file lacks them). Finished runs in ``OUT/runs/<run>/`` are reused whatever their schedule.
    cars_meshes, category_meshes, lidar : shared data folders (default ``../shared/data/...``).
    eval_views : test views per test car for Tables 1 and 5 (default 200, --quick 4; None = all).
    workers : processes for the dataset build and the rig study (default 1).
    argv : the command line, recorded in the report.
    """
    timer = StageTimer()  # laps: prepare, steps, records, report
    keys = parse_tables(tables)
    s = _settings(
        out,
        quick=quick,
        schedule=schedule,
        cars_data=cars_data,
        cars_meshes=cars_meshes,
        category_meshes=category_meshes,
        lidar=lidar,
        eval_views=eval_views,
        workers=workers,
        seed=seed,
        progress=progress,
    )
    _check_paths(s)
    ctx = Context(s, log)
    ctx.steps = all_steps(ctx)
    s.out.mkdir(parents=True, exist_ok=True)
    with exclusive_lock(
        s.out / ".reproduce.lock", f"{s.out}: another 'spotlights reproduce' is running in this folder", remove=True
    ):
        load_records(ctx)
        inv = {"started": now(), "argv": list(argv) if argv is not None else None, "tables": keys, "seconds": None}
        ctx.invocations.append(inv)
        todo = plan(ctx, keys)
        timer.lap("prepare")
        try:
            ran, reused = _execute_all(ctx, todo, progress)
        finally:
            timer.lap("steps")
            inv["seconds"] = round(timer.total, 2)
            save_records(ctx)
        timer.lap("records")
        report, results = write_report(ctx, keys, timer.total)
        timer.lap("report")
        inv["seconds"] = round(timer.total, 2)
        save_records(ctx)
    timer.lap("records")
    return ReproduceResult(report, results, ran, reused, timer.total)
