"""``evaluate --backend ray``: the per-model metric work of an evaluation as Ray tasks.

:func:`spotlights.metrics.completion.evaluate_completions` scores predictions model by model
(one KD-tree per ground-truth model for accuracy, one per prediction for completeness);
every sample's metrics depend only on its own prediction and its model's dense ground truth.
:class:`RayMetrics` is a drop-in replacement with the same signature: each model's dense
ground truth is put in the object store once (shared by every checkpoint and variant
scored in one run), its samples are cut into chunks, and each chunk is one Ray task
running ``evaluate_completions`` on the cluster. The values are identical to the local
computation (the same function on the same arrays; chunking does not change a sample's value).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..distributed import DEFAULT_RETRIES, error_reason
from ..errors import SpotlightsError
from ..metrics.completion import evaluate_completions

CHUNK = 256  # samples per task: enough work per task (~0.1-1 s), enough tasks to spread a split


def _score_task(preds: list, gt: np.ndarray, fscore_threshold: float, with_completeness: bool) -> dict:
    return evaluate_completions(preds, np.zeros(len(preds), dtype=np.int64), [gt], fscore_threshold, with_completeness)


class RayMetrics:
    """Callable like :func:`~spotlights.metrics.completion.evaluate_completions`, on Ray.

    ray : the connected ``ray`` module (:func:`spotlights.distributed.ray_session`).
    chunk : samples per task. retries : Ray retries of a task that crashes.
    """

    def __init__(self, ray, chunk: int = CHUNK, retries: int = DEFAULT_RETRIES):
        self.ray = ray
        self.chunk = max(1, int(chunk))
        self.retries = int(retries)
        self._task = ray.remote(num_cpus=1, max_retries=self.retries, retry_exceptions=True)(_score_task)
        self._gt_refs: dict = {}

    def __call__(
        self,
        predictions: Sequence[np.ndarray],
        model_index: np.ndarray,
        gt_dense,
        fscore_threshold: float = 0.01,
        with_completeness: bool = True,
        trees: dict | None = None,
    ) -> dict[str, np.ndarray]:
        """Same arguments and result as ``evaluate_completions`` (``trees`` is ignored: the trees
        are built on the workers)."""
        ray = self.ray
        model_index = np.asarray(model_index, dtype=np.int64).reshape(-1)
        if len(model_index) != len(predictions):
            raise ValueError(f"{len(predictions)} predictions but {len(model_index)} model indices")
        jobs = []
        for m in np.unique(model_index):
            if int(m) not in self._gt_refs:
                self._gt_refs[int(m)] = ray.put(np.asarray(gt_dense[int(m)]))
            sel = np.flatnonzero(model_index == m)
            for a in range(0, len(sel), self.chunk):
                idx = sel[a : a + self.chunk]
                jobs.append(
                    (
                        int(m),
                        idx,
                        self._task.remote(
                            [predictions[i] for i in idx],
                            self._gt_refs[int(m)],
                            float(fscore_threshold),
                            bool(with_completeness),
                        ),
                    )
                )
        out: dict[str, np.ndarray] = {}
        for m, idx, ref in jobs:
            try:
                res = ray.get(ref)
            except ray.exceptions.RayError as exc:
                raise SpotlightsError(
                    f"metrics of ground-truth model row {m} failed on the Ray cluster after "
                    f"{self.retries + 1} attempts: {error_reason(exc)}"
                ) from None
            for k, v in res.items():
                if k not in out:
                    out[k] = np.full(len(model_index), np.nan)
                out[k][idx] = v
        if not out:  # no samples
            return evaluate_completions([], model_index, gt_dense, fscore_threshold, with_completeness)
        return out
