"""Study commands: ``study rigs`` (hit ratio and completeness of cap and box-targeted rigs)."""

from __future__ import annotations

from ..errors import SpotlightsError
from ..experiments.rig_study import rig_study, study_summary_lines
from ._util import add_command, add_group, add_quiet, non_negative_int, positive_int

DEFAULT_MESHES = ("../shared/data/meshes/apolloscape-cars", "../shared/data/meshes/categories")


def register(sub) -> None:
    study = add_group(
        sub,
        "study",
        "studies beyond the paper (rigs: cap against box-targeted ray bundles)",
        "spotlights study rigs --out rig_study --rays 2048",
        metavar="STUDY",
    )
    r = add_command(
        study,
        "rigs",
        "hit ratio and completeness of the paper's cap rigs and box-targeted rigs",
        "spotlights study rigs --out docs/results/rig_study --rays 2048 4096 8192",
        _rigs,
    )
    r.add_argument(
        "--out",
        "-o",
        required=True,
        metavar="DIR",
        help="output folder: rigs.csv (means), rigs_per_mesh.csv.gz, rigs.md, rigs.png; DIR/.cache resumes a run",
    )
    r.add_argument(
        "--meshes",
        nargs="+",
        default=list(DEFAULT_MESHES),
        metavar="DIR",
        help="mesh folders, one sub-folder per category; categories with fewer than 5 meshes are "
        "skipped (default: the shared cars and category meshes)",
    )
    r.add_argument(
        "--rays",
        nargs="+",
        type=int,
        default=[2048, 4096, 8192],
        metavar="K",
        help="ray counts, multiples of 64 (N = K / 64 viewpoints x 64 rays; default 2048 4096 8192)",
    )
    r.add_argument(
        "--seed", type=non_negative_int, default=0, help="seed of the 16,384 surface samples per mesh (default 0)"
    )
    r.add_argument(
        "--workers",
        "-j",
        type=positive_int,
        default=1,
        help="processes over meshes (results do not depend on it; default 1)",
    )
    add_quiet(r)


def _rigs(args) -> int:
    if args.workers < 1:
        raise SpotlightsError(f"--workers must be >= 1, got {args.workers}")
    res = rig_study(
        args.out, args.meshes, rays=args.rays, seed=args.seed, workers=args.workers, progress=not args.quiet
    )
    print("\n".join(study_summary_lines(res)))
    return 0
