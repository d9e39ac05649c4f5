"""``spotlights demo``: the end-to-end demonstration on bundled CC0 data."""

from __future__ import annotations

from dataclasses import dataclass

from ..completion.demo import run_demo
from ..options import option
from ..outputs import output_folder
from ._util import add_command, add_options


@dataclass(kw_only=True)
class DemoOptions:
    """The options of ``spotlights demo``."""

    out: str = option("--out", "-o", default="out/demo", metavar="DIR", help="output folder (default out/demo)")


def register(sub) -> None:
    p = add_command(
        sub,
        "demo",
        "run the end-to-end demo on a bundled CC0 vehicle and write pictures",
        "spotlights demo --out out/demo",
        _demo,
    )
    add_options(p, DemoOptions)


def _demo(args) -> int:
    from pathlib import Path

    with output_folder(args.out) as out:  # removed again if the demo fails before writing anything
        run_demo(Path(out), log=print)
    return 0
