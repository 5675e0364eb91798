"""What every method offers the training loop: build networks and optimizers, one optimisation step, state."""
from __future__ import annotations

from abc import ABC, abstractmethod

import torch
from torch import nn

from trainer.config import RunConfig
from trainer.distributed import Dist, average_gradients, broadcast_module
from trainer.sampling import Batch


class Method(ABC):
    """Subclasses set `name`, build `self.generator`, `self.nets` (discriminators) and `self.opts`, and implement
    `step(batch, step) -> {loss name: float}`."""

    name = "base"
    generator_class = ""

    def __init__(self, cfg: RunConfig, *, side: int, dist: Dist | None = None, device: str = "cpu"):
        self.cfg = cfg
        self.side = side
        self.dist = dist
        self.device = torch.device(device)
        self.generator: nn.Module
        self.nets: dict[str, nn.Module] = {}
        self.opts: dict[str, torch.optim.Optimizer] = {}
        self.info: dict = {}

    # --- distributed helpers -------------------------------------------------------------------------------
    def _wrap_generator(self) -> nn.Module:
        if self.dist is None:
            return self.generator
        from torch.nn.parallel import DistributedDataParallel as DDP
        return DDP(self.generator, device_ids=None if self.device.type == "cpu" else [self.device.index])

    def _sync_nets(self) -> None:
        if self.dist is not None:
            for net in self.nets.values():
                broadcast_module(net)

    def _reduce(self, net: nn.Module) -> None:
        if self.dist is not None:
            average_gradients(net, self.dist.world)

    @staticmethod
    def _requires_grad(net: nn.Module, flag: bool) -> None:
        for p in net.parameters():
            p.requires_grad_(flag)

    # --- state ---------------------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {"generator": self.generator.state_dict(),
                "nets": {k: v.state_dict() for k, v in self.nets.items()},
                "opts": {k: v.state_dict() for k, v in self.opts.items()}}

    def load_state_dict(self, state: dict) -> None:
        self.generator.load_state_dict(state["generator"])
        for k, v in self.nets.items():
            v.load_state_dict(state["nets"][k])
        for k, v in self.opts.items():
            v.load_state_dict(state["opts"][k])

    def train(self) -> None:
        self.generator.train()
        for n in self.nets.values():
            n.train()

    @abstractmethod
    def step(self, batch: Batch, step: int) -> dict[str, float]:
        """One optimisation step of every network; returns the logged loss values."""
