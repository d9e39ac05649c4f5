"""The one stage timer (``StageTimer``): the only place that reads ``time.perf_counter`` for a stage's time."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator


class StageTimer:
    """The one stage timer: wall seconds spent in named stages, summed over repeated entries.

    ``with timer("read"): ...`` adds the block's wall time (``time.perf_counter``, seconds) to
    ``timer.seconds["read"]``; stages keep the order of their first entry. ``timer.add(name, s)``
    adds a time measured elsewhere; ``timer.lap(name)`` adds the time since the previous lap (or since
    the timer was made) to ``name``, for consecutive stages of straight-line code (early returns, no
    block to indent); ``timer.total`` is the sum. Latency of repeated calls (medians,
    round-robin) is :func:`spotlights.learning.bench.time_calls`'s job, not this one's.

    >>> t = StageTimer()
    >>> with t("a"):
    ...     pass
    >>> list(t.seconds), t.seconds["a"] >= 0.0
    (['a'], True)
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        self._mark = time.perf_counter()  # where the next lap starts

    @contextlib.contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - t0)

    def add(self, name: str, seconds: float) -> None:
        """Add ``seconds`` (float, wall seconds) to stage ``name`` and count one entry."""
        self.seconds[name] = self.seconds.get(name, 0.0) + float(seconds)
        self.counts[name] = self.counts.get(name, 0) + 1

    def lap(self, name: str) -> float:
        """Add the wall seconds since the previous :meth:`lap` (or since this timer was made) to stage
        ``name`` and return them (float, seconds). Laps ignore ``with`` blocks and :meth:`add`."""
        t = time.perf_counter()
        seconds, self._mark = t - self._mark, t
        self.add(name, seconds)
        return seconds

    @property
    def total(self) -> float:
        """Sum of every stage's seconds."""
        return float(sum(self.seconds.values()))

    def rounded(self, digits: int = 3) -> dict[str, float]:
        """``{stage: seconds}`` rounded to ``digits`` (for JSON reports)."""
        return {k: round(v, digits) for k, v in self.seconds.items()}
