"""``spotlights reproduce``: recompute the paper's tables and write a report beside the paper's values."""

from __future__ import annotations

from dataclasses import dataclass

from ..experiments.reproduce import parse_tables, publish, reproduce
from ..options import option
from ._util import add_command, add_options, add_quiet, positive_int


@dataclass(kw_only=True)
class ReproduceOptions:
    """The options of ``spotlights reproduce`` (then ``-q``)."""

    out: str = option(
        "--out",
        "-o",
        metavar="DIR",
        help="output folder: REPORT.md, results.json, tables/, figures/, steps.json, data/, runs/, eval/; "
        "rerun with the same DIR to resume",
    )
    tables: str | None = option(
        default=None,
        metavar="LIST",
        help="comma-separated tables to reproduce, from 1,2,3,4,5 and box (box-targeted rigs, docs/box-rig.md; default: all)",
    )
    quick: bool = option(
        default=False,
        action="store_true",
        help="small data (9 cars, 16 views), the tiny 'quick' schedule, a few meshes per category: every "
        "stage in a few minutes; the numbers mean nothing",
    )
    schedule: str | None = option(
        default=None,
        metavar="NAME|YAML",
        help="training schedule of new runs (default 'budget', with --quick 'quick'); existing runs keep theirs",
    )
    cars_data: str | None = option(
        default=None,
        metavar="FILE.h5|INDEX.json",
        help="use this car dataset (a file, or the index .json of a sharded dataset) instead of building "
        "DIR/data/cars.h5 (needs rigs 32x64, 64x32 and 256x64 at 60 deg; "
        "the box table adds rig box-32x64-ellipsoid-s1 to it with dataset add-rig if it lacks it)",
    )
    eval_views: int | None = option(
        default=None,
        type=positive_int,
        metavar="V",
        help="score the first V views of each test car in Tables 1 and 5 (default 200, --quick 4; 2000 = all)",
    )
    meshes: str | None = option(
        default=None, metavar="DIR", help="car meshes (default ../shared/data/meshes/apolloscape-cars)"
    )
    category_meshes: str | None = option(
        default=None,
        metavar="DIR",
        help="category meshes of Tables 3 and 4 (default ../shared/data/meshes/categories)",
    )
    lidar: str | None = option(default=None, metavar="DIR", help="real LiDAR data (default ../shared/data/lidar)")
    workers: int | None = option(
        default=None,
        type=positive_int,
        help="processes for the dataset build and the rig study (default 1; results do not depend on it)",
    )
    publish: str | None = option(
        default=None,
        metavar="DIR",
        help="afterwards, copy REPORT.md, results.json, steps.json, tables/ and figures/ into DIR "
        "(e.g. docs/results/reproduction)",
    )


def register(sub) -> None:
    p = add_command(
        sub,
        "reproduce",
        "recompute the paper's tables (datasets, training, evaluation, rig study, figures) and write "
        "OUT/REPORT.md with ours beside the paper's; resumable",
        "spotlights reproduce --quick --out out/repro_quick      # every stage, small, minutes\n"
        "  spotlights reproduce --tables 3,4 --out out/repro       # the ablations only (no learning)\n"
        "  spotlights reproduce --out out/repro --cars-data cars.h5 # everything, reusing a car dataset",
        _reproduce,
    )
    add_options(p, ReproduceOptions)
    add_quiet(p, "no progress bars")


def _reproduce(args) -> int:
    import sys

    parse_tables(args.tables)  # a bad --tables fails before anything runs
    res = reproduce(
        args.out,
        tables=args.tables,
        quick=args.quick,
        schedule=args.schedule,
        cars_data=args.cars_data,
        cars_meshes=args.meshes,
        category_meshes=args.category_meshes,
        lidar=args.lidar,
        eval_views=args.eval_views if args.eval_views is not None else "default",
        workers=args.workers,
        progress=not args.quiet,
        argv=sys.argv[1:],
    )
    print(
        f"{len(res.ran)} step(s) run, {len(res.reused)} reused, {res.seconds:.1f} s; report -> {res.report}, "
        f"numbers -> {res.results}"
    )
    if args.publish:
        print(f"published -> {publish(args.out, args.publish)}")
    return 0
