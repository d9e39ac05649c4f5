"""The fidelities of a frame's completions, scored on threads while the frame's completion goes on
(:class:`Fidelities`, used by :func:`spotlights.completion.frame.complete_scene`'s heading check)."""

from __future__ import annotations

import numpy as np

from ..geometry.boxes import FLIP_Z
from ..geometry.neighbors import serial_queries
from ..metrics.consistency import fidelity
from ..processes import shared_thread_pool

#: threads that score the completions' fidelity (:class:`Fidelities`)
FIDELITY_THREADS = 2


def _one_openmp_thread() -> None:
    """A fidelity thread's start: OpenMP on one thread in it for good (the limit is per thread;
    :func:`~spotlights.geometry.neighbors.serial_queries`, never restored): completions are scored with
    pykdtree, whose OpenMP split of small queries costs more than it saves."""
    serial_queries()


def _fidelity_or_none(partial: np.ndarray, completion: np.ndarray) -> float | None:
    return fidelity(partial, completion) if len(completion) else None


class Fidelities:
    """:func:`~spotlights.metrics.consistency.fidelity` of a frame's completions (unit frame), scored on
    :data:`FIDELITY_THREADS` threads while the frame goes on: the KD-tree over each completion (pykdtree's:
    :class:`~spotlights.geometry.neighbors.NearestNeighbors` with ``few_queries``) is built and queried without
    the GIL, so one model's batch is scored while the other model's batch and the frame's assembly go on (on
    scene-0523, 16 objects a frame of ~15,000 points each, scoring was a fifth of ``real complete``'s frame loop
    on one core). The values are those of one thread.

    Positions are those of :func:`_complete_objects`' list: ``0..n-1`` each object of ``todo`` (its observed
    ``partial_unit``), then, with ``heading_check``, ``n..2n-1`` the same objects turned around (their partial
    turned by :data:`~spotlights.geometry.boxes.FLIP_Z`).
    """

    def __init__(self, todo: list) -> None:
        self.todo = todo
        self.pending: dict = {}

    def partial(self, position: int) -> np.ndarray:
        """(P, 3) the observed points that position ``position`` is scored against (unit frame)."""
        n = len(self.todo)
        return self.todo[position].partial_unit if position < n else self.todo[position - n].partial_unit @ FLIP_Z

    def add(self, positions, completions: list) -> None:
        """Start scoring ``completions`` ((K, 3) each), at ``positions`` (same length)."""
        pool = shared_thread_pool("fidelity", FIDELITY_THREADS, initializer=_one_openmp_thread)
        for k, comp in zip(positions, completions):
            self.pending[k] = pool.submit(_fidelity_or_none, self.partial(k), comp)

    def get(self, position: int) -> float | None:
        """The fidelity at ``position`` (waits for it; None for an empty completion)."""
        return self.pending[position].result()
