"""Validation during training: the loss and point metrics of a model's completions over one split.

:func:`validate` runs every epoch of :func:`spotlights.learning.train.train` (and in the tests); the
batch helpers here are shared with the training loop.
"""

from __future__ import annotations

import math

import torch
from torch.utils.data import DataLoader

from ..errors import SpotlightsError
from ..geometry.box_clamp import grown_half_extents
from ..geometry.distances import accuracy, combine_directions, completeness
from ..geometry.neighbors import NearestNeighbors
from .data import TorchCompletionDataset, worker_batches
from .device import autocast
from .models.base import CLIP_DEFAULT
from .process_group import ProcessGroup
from .rays import DirectionTable


def float_outputs(out: dict) -> dict:
    """Model outputs cast to float32 (losses and metrics run in fp32 whatever the autocast dtype)."""
    return {k: (v.float() if torch.is_tensor(v) and v.is_floating_point() else v) for k, v in out.items()}


def collate(batch_list):
    """The DataLoader's collate function: torch's default (a named function, so workers can pickle it)."""
    return torch.utils.data.default_collate(batch_list)


def to_device(batch: dict, device) -> dict:
    """The batch's tensors moved to ``device`` (non-blocking); other values as they are."""
    return {k: (v.to(device, non_blocking=True) if torch.is_tensor(v) else v) for k, v in batch.items()}


def with_boxes(batch: dict, model, rays, sizes) -> dict:
    """The batch with each sample's rays and grown box when ``model``'s loss keeps points in the box.

    For a model with ``box_weight > 0`` (:class:`~spotlights.learning.models.sanet_hit.HitSANet`), adds
    ``directions`` (B, N*M, 3) float32 (``rays``, a :class:`~spotlights.learning.rays.DirectionTable`, at the
    batch's ``model`` rows) and ``box_half`` (B, 3) float32: each model's box (``sizes``, (n_models, 3) metres)
    grown by 0.15 m, in its unit frame (:func:`~spotlights.geometry.box_clamp.grown_half_extents`, the box of
    the decoding clamp). Any other model: the batch as it is.
    """
    if not getattr(model, "box_weight", 0.0):
        return batch
    if rays is None or sizes is None:
        raise SpotlightsError("box_weight > 0 needs a box-targeted rig and a dataset with each model's box size")
    rows = batch["model"]
    half = grown_half_extents(sizes[rows.cpu().numpy()])
    box_half = torch.from_numpy(half.astype("float32")).to(rows.device)
    return {**batch, "directions": rays.directions(rows), "box_half": box_half}


@torch.no_grad()
def validate(
    model,
    dataset: TorchCompletionDataset,
    batch_size: int,
    device,
    gt_trees: dict,
    dist: ProcessGroup | None = None,
    num_workers: int = 0,
    rays=None,
    precision: str = "fp32",
    thresholds=None,
) -> dict:
    """Validation loss and point metrics of the completions (SA-Net clipped at its default).

    Parameters
    ----------
    gt_trees : {model row: (L, 3) dense GT array or its NearestNeighbors}; arrays are
        replaced by their KD-tree on first use (so one tree per GT model per run).
    rays : a :class:`~spotlights.learning.rays.DirectionTable` for a box-targeted SA-Net (each
        sample decodes with its model's box); default: built from ``dataset.extents``.
    precision : ``"fp32"``, ``"bf16"`` or ``"fp16"``: autocast of the forward pass (the run's
        training precision); loss and metrics are computed in float32.
    thresholds : hit-aware SA-Net only: the p(hit) thresholds to score (default: the model's
        ``threshold_grid``, else its ``threshold``); the metrics of the one with the lowest
        CD-L1 are returned (ties: the first), with ``val_threshold`` and ``val_threshold_scan``.

    Returns
    -------
    {"val_loss": mean loss over samples,
     "val_accuracy": mean over samples of the one-sided CD prediction -> dense GT,
     "val_completeness": mean over samples of the one-sided CD dense GT -> prediction,
     "val_chamfer_l1": (accuracy + completeness) / 2, "val_n": samples,
     "val_empty": samples whose completion is empty (left out of the point metrics)}.
    Hit-aware models add ``val_threshold`` (the chosen threshold) and ``val_threshold_scan``
    ({threshold: {"accuracy", "completeness", "chamfer_l1", "empty"}}).
    With ``dist`` active, each rank evaluates a contiguous shard and the sums are all-reduced.
    """
    if rays is None and getattr(model, "needs_box", False):
        rays = DirectionTable(model.rig, dataset.extents)
    hit_aware = hasattr(model, "hit_probabilities")
    grid = _threshold_grid(model, thresholds) if hit_aware else [None]
    active = dist is not None and dist.active
    loader = _shard_loader(dataset, dist if active else None, batch_size, num_workers)
    model.eval()
    loss_sum = 0.0
    count = 0
    acc_sum, comp_sum, scored = [0.0] * len(grid), [0.0] * len(grid), [0] * len(grid)
    for batch in worker_batches(loader):
        batch = with_boxes(to_device(batch, device), model, rays, dataset.sizes)
        with autocast(precision, device):
            out = model(*model.forward_inputs(batch, rays))
        out = float_outputs(out)
        b = batch["partial"].shape[0]
        loss, _ = model.loss(out, batch, 1.0)
        loss_sum += float(loss) * b
        count += b
        dirs = rays.directions(batch["model"]) if rays is not None else None
        for j, t in enumerate(grid):
            if hit_aware:
                preds = model.outputs_to_points(out, CLIP_DEFAULT, dirs, threshold=t)
            else:
                preds = model.outputs_to_points(out, CLIP_DEFAULT, dirs)
            _score_points(preds, batch["model"].tolist(), gt_trees, j, (acc_sum, comp_sum, scored))
    sums = [loss_sum, float(count), *acc_sum, *comp_sum, *map(float, scored)]
    if active:
        sums = dist.all_sum(sums, device)
    return _results(sums, grid, hit_aware)


def _threshold_grid(model, thresholds) -> list[float]:
    """The p(hit) thresholds a hit-aware model is scored at: ``thresholds``, else its ``threshold_grid``, else its
    ``threshold``."""
    grid = thresholds if thresholds is not None else (model.threshold_grid or (model.threshold,))
    return [float(t) for t in grid]


def _shard_loader(dataset: TorchCompletionDataset, dist: ProcessGroup | None, batch_size: int, num_workers: int):
    """A DataLoader (in order) of this rank's contiguous shard of ``dataset`` (all of it when ``dist`` is None)."""
    world, rank = (dist.world, dist.rank) if dist is not None else (1, 0)
    n = len(dataset)
    lo, hi = n * rank // world, n * (rank + 1) // world
    subset = torch.utils.data.Subset(dataset, range(lo, hi))
    return DataLoader(subset, batch_size=batch_size, shuffle=False, num_workers=num_workers, collate_fn=collate)


def _score_points(preds, rows: list[int], gt_trees: dict, j: int, sums: tuple[list, list, list]) -> None:
    """Add each non-empty completion of ``preds`` ((K, 3) tensors of the model rows ``rows``) to the sums of
    threshold ``j``: ``sums`` = (accuracy sums, completeness sums, counts), against the dense ground truth of
    ``gt_trees`` (an array there is replaced by its KD-tree on first use)."""
    acc_sum, comp_sum, scored = sums
    for p, m in zip(preds, rows):
        if len(p) == 0:
            continue
        if m not in gt_trees:
            raise SpotlightsError(f"no dense ground truth for model row {m}")
        tree = gt_trees[m]
        if not isinstance(tree, NearestNeighbors):
            tree = gt_trees[m] = NearestNeighbors(tree)
        pts = p.detach().cpu().numpy()
        acc_sum[j] += accuracy(pts, tree)
        comp_sum[j] += completeness(pts, tree)
        scored[j] += 1


def _results(sums: list[float], grid: list, hit_aware: bool) -> dict:
    """:func:`validate`'s results from its (all-reduced) ``sums`` = [loss sum, count, the accuracy sums, the
    completeness sums and the counts scored of each threshold of ``grid``]: the threshold of the lowest CD-L1."""
    k = len(grid)
    loss_sum, count = sums[0], sums[1]
    acc_sum, comp_sum, scored = sums[2 : 2 + k], sums[2 + k : 2 + 2 * k], sums[2 + 2 * k : 2 + 3 * k]
    scan = []
    for j in range(k):
        acc = acc_sum[j] / scored[j] if scored[j] else float("nan")
        comp = comp_sum[j] / scored[j] if scored[j] else float("nan")
        scan.append(
            {
                "accuracy": acc,
                "completeness": comp,
                "chamfer_l1": combine_directions(acc, comp, "mean"),
                "empty": int(count - scored[j]),
            }
        )
    # The chosen threshold: the lowest CD-L1 (the first on ties); NaN (every completion empty) never wins.
    finite = [j for j in range(k) if math.isfinite(scan[j]["chamfer_l1"])]
    best = min(finite, key=lambda j: scan[j]["chamfer_l1"]) if finite else 0
    row = scan[best]
    res = {
        "val_loss": loss_sum / count if count else float("nan"),
        "val_accuracy": row["accuracy"],
        "val_completeness": row["completeness"],
        "val_chamfer_l1": row["chamfer_l1"],
        "val_n": int(count),
        "val_empty": row["empty"],
    }
    if hit_aware:
        res["val_threshold"] = grid[best]
        res["val_threshold_scan"] = {f"{t:g}": v for t, v in zip(grid, scan)}
    return res
