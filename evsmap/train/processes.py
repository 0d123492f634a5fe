"""The processes of a training run: one, or DDP under ``torchrun`` (gloo on the CPU, nccl on
CUDA, one GPU per process by ``LOCAL_RANK``); this process's rank, world and device."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import torch
import torch.distributed as dist


@dataclass
class Processes:
    """This process's place in the run (one process: rank 0 of 1)."""

    rank: int
    world: int
    local_rank: int
    device: torch.device
    backend: str | None
    started: bool  # whether this code initialised the process group (and tears it down)

    @property
    def main(self) -> bool:
        return self.rank == 0

    def sum_(self, tensor: torch.Tensor) -> torch.Tensor:
        if self.world > 1:
            dist.all_reduce(tensor, op=dist.ReduceOp.SUM)
        return tensor

    def gather(self, obj: Any) -> list[Any]:
        if self.world == 1:
            return [obj]
        out: list[Any] = [None] * self.world
        dist.all_gather_object(out, obj)
        return out


def _device(text: str | None) -> torch.device:
    if text is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    from evsmap.devices import require_device

    return require_device(text)


def start_processes(device: str | None) -> Processes:
    """Read torchrun's environment and join the process group (gloo on the CPU, nccl on CUDA)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    dev = _device(device)
    if world <= 1:
        return Processes(0, 1, 0, dev, None, False)
    if dev.type == "cuda":
        dev = torch.device("cuda", local)
        torch.cuda.set_device(dev)
    backend = "nccl" if dev.type == "cuda" else "gloo"
    started = False
    if not dist.is_initialized():
        dist.init_process_group(backend=backend, init_method="env://", rank=rank,
                                world_size=world)
        started = True
    return Processes(rank, world, local, dev, backend, started)
