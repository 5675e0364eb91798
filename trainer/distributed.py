"""Training one garment on several processes (`torchrun --nproc_per_node=N -m trainer.cli ...` or
`vtkiosk train ... ` under torchrun): DistributedDataParallel for the generator; the discriminators, which run
several forwards (real, fake, unpaired) per backward - a pattern DDP's reducer does not support - average their
gradients with the same all-reduce DDP uses. Each rank draws its own crops and patches (seeded by rank), so the
effective batch is N images + N x 64 patches. gloo on CPU, nccl on GPUs.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn


@dataclass
class Dist:
    rank: int
    world: int
    local_rank: int

    @property
    def main(self) -> bool:
        return self.rank == 0


def init_from_env(backend: str | None = None) -> Dist | None:
    """Join the process group that torchrun describes in the environment; None when not launched that way."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return None
    if not dist.is_initialized():
        backend = backend or ("nccl" if torch.cuda.is_available() else "gloo")
        dist.init_process_group(backend=backend)
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if torch.cuda.is_available():
        torch.cuda.set_device(local)
    return Dist(dist.get_rank(), dist.get_world_size(), local)


def broadcast_module(module: nn.Module) -> None:
    """Rank 0's parameters and buffers everywhere (identical starting discriminators)."""
    for t in list(module.parameters()) + list(module.buffers()):
        dist.broadcast(t.data, src=0)


def average_gradients(module: nn.Module, world: int) -> None:
    for p in module.parameters():
        if p.grad is not None:
            dist.all_reduce(p.grad, op=dist.ReduceOp.SUM)
            p.grad.div_(world)


def average_scalar(value: float, world: int) -> float:
    t = torch.tensor([value], dtype=torch.float64)
    dist.all_reduce(t, op=dist.ReduceOp.SUM)
    return float(t.item()) / world


def cleanup() -> None:
    if dist.is_initialized():
        dist.destroy_process_group()
