"""Metrics (numpy + pykdtree only, no torch): every score of a completion, in one layer below ``data``.

- :mod:`.completion` - completions against ground truth: ``accuracy``, ``completeness``, ``chamfer_l1``,
  ``chamfer_l2``, ``fscore`` (one setting each of :func:`spotlights.geometry.distances.chamfer_distance`,
  the nearest-neighbour kernel), batched per ground-truth model (:func:`~.completion.evaluate_completions`,
  one KD-tree per model) and aggregated per category (:func:`~.completion.summarize`); ``kept_ratio``.
- :mod:`.consistency` - real data without ground truth: the Chamfer variants between two completions
  (:func:`~.consistency.chamfer`: ``cd``, ``cd_half``, ``d_ab``, ``d_ba``, ``cd_l2``), consistency of tracks
  across frames (the paper's Table 2), ``fidelity`` (PCN's), the minimal matching distance (MMD) to
  reference shapes, diversity and the resampling noise floor (:func:`~.consistency.same_observation_cd`).

Distances are unsquared Euclidean in the unit frame unless a name says ``l2``. Layers: ``geometry`` below,
``data``, ``learning`` and ``experiments`` above (docs/architecture.md).
"""

from __future__ import annotations

from ..geometry.distances import accuracy, chamfer_distance, chamfer_l1, chamfer_l2, completeness, fscore
from .completion import METRIC_DESCRIPTIONS, METRIC_NAMES, evaluate_completions, kept_ratio, summarize
from .consistency import (
    aggregate,
    chamfer,
    consecutive_pairs,
    diversity,
    fidelity,
    minimal_matching_distance,
    same_observation_cd,
    track_consistency,
)

__all__ = [
    "METRIC_DESCRIPTIONS",
    "METRIC_NAMES",
    "accuracy",
    "aggregate",
    "chamfer",
    "chamfer_distance",
    "chamfer_l1",
    "chamfer_l2",
    "completeness",
    "consecutive_pairs",
    "diversity",
    "evaluate_completions",
    "fidelity",
    "fscore",
    "kept_ratio",
    "minimal_matching_distance",
    "same_observation_cd",
    "summarize",
    "track_consistency",
]
