"""The process group of a training run under ``torchrun``, or a no-op shell in a single process."""

from __future__ import annotations

import os

import torch

from ..errors import ParameterError
from .device import resolve_device


def group_backend(device: torch.device, local_rank: int, n_gpus: int, local_world: int = 1) -> tuple[str, int | None]:
    """The process-group backend of a rank that trains on ``device`` (its type decides: ``cuda`` -> NCCL, else
    gloo) and, for NCCL, the CUDA device index it takes (``device.index``, else its ``local_rank``). Raises
    :class:`ParameterError` when that index is not one of the ``n_gpus`` devices of the node (torchrun started
    more processes per node than it has GPUs), or when an explicit index would be shared by the ``local_world``
    processes of the node (NCCL needs one GPU per process)."""
    if device.type != "cuda":
        return "gloo", None
    if device.index is not None and local_world > 1:
        raise ParameterError(
            f"`device` {device}: the {local_world} processes of this node would share one GPU; give `device` cuda "
            "(each process takes the GPU of its local rank)",
            "device",
        )
    index = local_rank if device.index is None else int(device.index)
    if not 0 <= index < n_gpus:
        raise ParameterError(
            f"torchrun rank with local rank {local_rank} would train on cuda:{index}, but this node has {n_gpus} "
            f"CUDA device(s): start one process per GPU (`nproc_per_node` {n_gpus}) or train on the CPU with "
            "`device` cpu (gloo)",
            "nproc_per_node",
            "device",
        )
    return "nccl", index


class ProcessGroup:
    """Process-group facts of a training run (torchrun: ``WORLD_SIZE``, ``RANK``, ``LOCAL_RANK``); a no-op shell in
    a single process. Sets the group up (:func:`group_backend`: NCCL when the run trains on CUDA, gloo otherwise)
    when torchrun started several processes and no group exists yet, and :meth:`close` destroys only a group it set
    up. ``device``: the run's (``--device``; None: CUDA when available, else the CPU)."""

    def __init__(self, device=None):
        self.world = int(os.environ.get("WORLD_SIZE", "1"))
        self.rank = int(os.environ.get("RANK", "0"))
        self.active = self.world > 1
        self.owned = False
        if self.active and not torch.distributed.is_initialized():
            local = int(os.environ.get("LOCAL_RANK", 0))
            dev = resolve_device(device)
            n_gpus = torch.cuda.device_count() if dev.type == "cuda" else 0
            backend, index = group_backend(dev, local, n_gpus, int(os.environ.get("LOCAL_WORLD_SIZE", 1)))
            if index is not None:
                torch.cuda.set_device(index)
            torch.distributed.init_process_group(backend=backend)
            self.owned = True

    @property
    def main(self) -> bool:
        return self.rank == 0

    def all_sum(self, values: list[float], device) -> list[float]:
        if not self.active:
            return values
        t = torch.tensor(values, dtype=torch.float64, device=device)
        torch.distributed.all_reduce(t)
        return t.tolist()

    def barrier(self):
        if self.active:
            torch.distributed.barrier()

    def close(self):
        if self.owned:
            torch.distributed.destroy_process_group()
