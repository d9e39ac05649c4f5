"""The step engine of ``spotlights reproduce``: steps, their signatures, the record of finished steps, resuming.

A :class:`Step` is one unit of work (build a dataset, train a run, draw a figure, assemble a
table) with the files and parameters its result depends on. :func:`execute` runs a step, or
reuses it when ``OUT/steps.json`` records it as done with the same signature and its outputs
exist; :func:`resolve` orders the steps some targets need. Nothing here knows a table or a
model: those are the step lists of :mod:`.steps`, :mod:`.figures` and :mod:`.tables`.
"""

from __future__ import annotations

import json
import math
import shlex
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from ...errors import SpotlightsError
from ...outputs import atomic_output
from ...timing import StageTimer
from .settings import Settings

STEPS_FORMAT = "spotlights-reproduce-steps"


@dataclass
class Step:
    """One unit of work: ``run(ctx) -> info dict``; reused when its record, inputs and outputs hold.

    ``command(ctx)``: the equivalent command line (for the report). ``outputs(ctx)``: the
    files it writes. ``needs``: names of the steps to run first. ``inputs``: files whose size
    and time enter the step's signature (a retrained checkpoint makes its evaluation stale).
    ``params``: anything else the result depends on. ``reuse``: optional check for artifacts
    made outside a recorded run (existing datasets and checkpoints); returns
    ``(message, info)`` when the step can be skipped.
    """

    name: str
    run: Callable
    command: Callable
    outputs: Callable
    needs: tuple = ()
    inputs: Callable = lambda ctx: []
    params: Callable = lambda ctx: {}
    reuse: Callable | None = None


def tqdm_print(msg: str) -> None:
    """Print a log line above the progress bars."""
    from tqdm import tqdm

    tqdm.write(msg, file=sys.stdout)
    sys.stdout.flush()


class Context:
    """A reproduction in progress: settings, the steps, their records and logging."""

    def __init__(self, settings: Settings, log=None):
        self.s = settings
        self.out = Path(settings.out)
        self.log = log or tqdm_print
        self.records: dict = {}
        self.invocations: list = []
        self.steps: dict = {}

    # paths
    def run_dir(self, run: str) -> Path:
        return self.out / "runs" / run

    def eval_json(self, run: str) -> Path:
        return self.out / "eval" / f"{run}.json"

    def table_json(self, key: str) -> Path:
        return self.out / "tables" / f"table{key}.json"

    @property
    def figures(self) -> Path:
        return self.out / "figures"


def shell_quote(p) -> str:
    """``p`` quoted for a shell command line."""
    return shlex.quote(str(p))


def signature(paths) -> dict:
    """{path: [size, mtime_ns] or None when missing} of ``paths``: what a step's inputs were."""
    sig = {}
    for p in paths:
        p = Path(p)
        if p.is_file():
            st = p.stat()
            sig[str(p)] = [st.st_size, st.st_mtime_ns]
        else:
            sig[str(p)] = None
    return sig


def to_json(x):
    """``x`` with JSON-ready values: string keys, lists for tuples, Python numbers, None for NaN/inf, str paths."""
    if isinstance(x, dict):
        return {str(k): to_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_json(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, Path):
        return str(x)
    return x


def write_json(path: Path, obj) -> None:
    """Write ``obj`` (through :func:`to_json`) to ``path`` atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path, suffix=".json") as tmp:
        Path(tmp).write_text(json.dumps(to_json(obj), indent=1) + "\n")


def read_json(path: Path) -> dict:
    """A step's JSON output; SpotlightsError when the step did not finish."""
    if not path.is_file():
        raise SpotlightsError(f"{path}: missing (its step did not finish; rerun to resume)")
    return json.loads(path.read_text())


def now() -> str:
    """The current UTC time, ISO 8601 to the second."""
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def load_records(ctx: Context) -> None:
    """Read ``OUT/steps.json`` (if any) into ``ctx.records`` and ``ctx.invocations``."""
    p = ctx.out / "steps.json"
    if not p.is_file():
        return
    try:
        d = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError):
        raise SpotlightsError(f"{p}: unreadable step record; remove it to start the bookkeeping again") from None
    if d.get("format") != STEPS_FORMAT:
        raise SpotlightsError(f"{p}: not a spotlights reproduce step record")
    if d.get("mode") != ctx.s.mode:
        raise SpotlightsError(
            f"{ctx.out}: holds a {d.get('mode')} reproduction; use another --out for a {ctx.s.mode} one"
        )
    ctx.records = d.get("steps", {})
    ctx.invocations = d.get("invocations", [])


def save_records(ctx: Context) -> None:
    """Write the step records and invocations to ``OUT/steps.json`` (atomically)."""
    write_json(
        ctx.out / "steps.json",
        {"format": STEPS_FORMAT, "mode": ctx.s.mode, "steps": ctx.records, "invocations": ctx.invocations},
    )


def execute(ctx: Context, st: Step) -> str:
    """Run or reuse one step; returns "ran" or "reused"."""
    key = {"inputs": signature(st.inputs(ctx)), "params": to_json(st.params(ctx))}
    rec = ctx.records.get(st.name)
    outputs_ok = all(Path(p).exists() for p in st.outputs(ctx))
    if rec and rec.get("status") == "done" and rec.get("key") == key and outputs_ok:
        ctx.log(f"[{st.name}] reusing the result of {rec.get('finished', '?')} ({rec.get('seconds', 0):.1f} s then)")
        rec["reused"] = True
        return "reused"
    if st.reuse is not None:
        found = st.reuse(ctx)
        if found:
            msg, info = found
            ctx.log(f"[{st.name}] {msg}")
            prev = rec if rec and rec.get("status") == "done" else {}
            ctx.records[st.name] = {
                "status": "done",
                "seconds": prev.get("seconds", 0.0),
                "command": prev.get("command", st.command(ctx)),
                "reused": True,
                "finished": prev.get("finished", now()),
                "key": key,
                "info": info,
                "note": prev.get("note", "made outside this reproduction (or in an earlier run) and reused"),
            }
            return "reused"
    ctx.log(f"[{st.name}] running: {st.command(ctx)}")
    ctx.records[st.name] = {"status": "running", "started": now(), "command": st.command(ctx), "key": key}
    save_records(ctx)
    timer = StageTimer()
    with timer(st.name):
        info = st.run(ctx)
    dt = timer.seconds[st.name]
    cmd = ctx.records[st.name].get("command", st.command(ctx))
    # a step's inputs may be its own products (train -> best.pt): sign them after the run
    key = {"inputs": signature(st.inputs(ctx)), "params": to_json(st.params(ctx))}
    ctx.records[st.name] = {
        "status": "done",
        "seconds": round(dt, 2),
        "command": cmd,
        "reused": False,
        "finished": now(),
        "key": key,
        "info": to_json(info or {}),
    }
    save_records(ctx)
    ctx.log(f"[{st.name}] done in {dt:.1f} s")
    return "ran"


def resolve(steps: dict, targets: Sequence[str]) -> list[Step]:
    """The steps ``targets`` (step names) need, their dependencies included, in the order of ``steps``."""
    want: set = set()

    def add(name):
        if name in want:
            return
        want.add(name)
        for n in steps[name].needs:
            add(n)

    for t in targets:
        add(t)
    return [st for name, st in steps.items() if name in want]
