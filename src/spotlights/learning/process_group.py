"""The process group of a training run under ``torchrun``, or a no-op shell in a single process."""

from __future__ import annotations

import os

import torch


class ProcessGroup:
    """Process-group facts of a training run (torchrun: ``WORLD_SIZE``, ``RANK``, ``LOCAL_RANK``); a no-op shell in
    a single process. Sets the group up (NCCL on GPUs, gloo on CPU) when torchrun started several processes and no
    group exists yet, and :meth:`close` destroys only a group it set up."""

    def __init__(self):
        self.world = int(os.environ.get("WORLD_SIZE", "1"))
        self.rank = int(os.environ.get("RANK", "0"))
        self.active = self.world > 1
        self.owned = False
        if self.active and not torch.distributed.is_initialized():
            backend = "nccl" if torch.cuda.is_available() else "gloo"
            if torch.cuda.is_available():
                torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", 0)))
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
