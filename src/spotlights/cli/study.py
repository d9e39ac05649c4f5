"""Study commands: ``study rigs`` (hit ratio and completeness of cap and box-targeted rigs)."""

from __future__ import annotations

from ..experiments.rig_study import RigStudySettings, run_rig_study, study_summary_lines
from ._util import add_command, add_group, add_options, settings_of


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
    add_options(r, RigStudySettings)


def _rigs(args) -> int:
    res = run_rig_study(settings_of(RigStudySettings, args))
    print("\n".join(study_summary_lines(res)))
    return 0
