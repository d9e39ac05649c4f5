"""The tables of the ``spotlights reproduce`` report: a registry of table builders, ours beside the paper's.

A table is one :class:`Table` entry of :data:`TABLES`: its title, the steps it needs and a
``build(ctx) -> dict`` function (one module of this package each: :mod:`.synthetic` Tables 1
and 5, :mod:`.real` Table 2 (Argoverse 2 and nuScenes), :mod:`.ablations` Tables 3 and 4, :mod:`.box` the box-rig
table) that reads those steps' outputs (``OUT/eval/*.json``, ``OUT/rig_study/summary.csv``...)
and returns ``markdown`` (its section of REPORT.md), ``rows`` (``{"row", "column", "ours",
"paper"}`` for the CSV), ``checks`` (the paper's claims, each ``{"claim", "holds",
"detail"}``) and anything else worth keeping in the JSON. :func:`table_steps` turns the
registry into steps. The paper's values are in :mod:`spotlights.experiments.paper_tables`.
"""

from __future__ import annotations

import csv
import hashlib
import io
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from ....errors import ParameterError
from ....outputs import atomic_output
from ... import paper_tables as paper
from ..pipeline import Context, Step, to_json, write_json
from ..settings import BOX_RUNS, PEER_RUNS, PRODUCT_RUNS, TABLE1_RUNS, TABLE2_SETS, TABLE5_RUNS
from .ablations import build_table3, build_table4
from .box import build_table_box
from .real import build_table2
from .synthetic import build_table1, build_table5


@dataclass(frozen=True)
class Table:
    """A table of the report: the steps it needs and the function that builds it.

    ``steps(settings) -> list of step names``; ``build(ctx) -> dict`` with ``markdown`` (the
    section of REPORT.md), ``rows`` (dicts ``row, column, ours, paper`` for the CSV),
    ``checks`` (the paper's expectations, each ``{"claim", "holds", "detail"}``) and anything
    else worth keeping in the JSON.
    """

    key: str
    title: str
    steps: Callable
    build: Callable


TABLES = {
    "1": Table(
        "1",
        "Table 1: completion accuracy and efficiency on the synthetic cars",
        lambda s: [f"eval-{r}" for r in TABLE1_RUNS + PRODUCT_RUNS + PEER_RUNS] + ["fig-synthetic"],
        build_table1,
    ),
    "2": Table(
        "2",
        "Table 2: consistency on real scans",
        lambda s: (
            [f"consistency-{k}" for k in TABLE2_SETS] + [f"real-{k}" for k in TABLE2_SETS] + ["real-kitti", "fig-real"]
        ),
        build_table2,
    ),
    "3": Table(
        "3",
        "Table 3: completeness of the Spotlights point cloud",
        lambda s: ["rig-study", "fig-rig", "fig-density", "fig-gt"],
        build_table3,
    ),
    "4": Table("4", "Table 4: hit ratio of the rays", lambda s: ["rig-study"], build_table4),
    "5": Table(
        "5", "Table 5: sampling resolution", lambda s: [f"eval-{r}" for r in TABLE5_RUNS.values()], build_table5
    ),
    "box": Table(
        "box",
        "Beyond the paper: box-targeted rigs",
        lambda s: ["rig-study", "fig-box"] + [f"eval-{r}" for r in BOX_RUNS.values()] + ["consistency-av2-box"],
        build_table_box,
    ),
}
"""Table key -> :class:`Table`; ``--tables`` selects from these keys."""


def parse_tables(text: str | Sequence | None) -> list[str]:
    """``"1,2,5"`` -> ``["1", "2", "5"]`` (registry order); None or "all" -> every table.

    Raises :class:`ParameterError` for an unknown or empty selection.
    """
    if text is None:
        return list(TABLES)
    items = [str(x).strip() for x in (text.split(",") if isinstance(text, str) else text)]
    if [x.lower() for x in items] == ["all"]:
        return list(TABLES)
    bad = [x for x in items if x not in TABLES]
    if bad or not items or not all(items):
        what = f"unknown table {bad[0]!r}" if bad and bad[0] else "empty table list"
        raise ParameterError(
            f"`tables`: {what}; choose from {', '.join(TABLES)} (comma-separated, e.g. `tables` 1,3)", "tables"
        )
    return [k for k in TABLES if k in items]


def _run_table(ctx: Context, key: str) -> dict:
    t = TABLES[key]
    res = t.build(ctx)
    res = {"key": key, "title": t.title, **res}
    write_json(ctx.table_json(key), res)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=["table", "row", "column", "ours", "paper"], lineterminator="\n")
    w.writeheader()
    for r in res.get("rows", []):
        w.writerow({"table": key, **{k: to_json(r.get(k)) for k in ("row", "column", "ours", "paper")}})
    with atomic_output(ctx.out / "tables" / f"table{key}.csv", suffix=".csv") as tmp:
        Path(tmp).write_text(buf.getvalue())
    return {"checks": [c["holds"] for c in res.get("checks", [])]}


def _code_version() -> str:
    """Hash of the table builders and the paper's values: a table is rebuilt (cheap) when the code that writes it changed."""
    h = hashlib.sha256()
    for f in sorted(Path(__file__).parent.glob("*.py")):
        h.update(f.read_bytes())
    h.update(Path(paper.__file__).read_bytes())
    return h.hexdigest()[:16]


def _table_inputs(ctx: Context, key: str) -> list:
    files = []
    for name in TABLES[key].steps(ctx.s):
        st = ctx.steps[name]
        if not name.startswith(("train-", "cars-data", "fig-")):
            files += list(st.outputs(ctx))
    return files


def table_steps(ctx: Context) -> list[Step]:
    """One ``table-<key>`` step per entry of :data:`TABLES`; each needs its table's steps."""
    return [
        Step(
            f"table-{key}",
            (lambda c, k=key: _run_table(c, k)),
            lambda c: "(assembled by spotlights reproduce from the steps above)",
            (lambda c, k=key: [c.table_json(k)]),
            needs=tuple(t.steps(ctx.s)),
            inputs=(lambda c, k=key: _table_inputs(c, k)),
            params=lambda c: {"code": _code_version()},
        )
        for key, t in TABLES.items()
    ]
