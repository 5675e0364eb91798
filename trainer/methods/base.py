"""What every method offers the training loop: build networks and optimizers, one optimisation step, state."""
from __future__ import annotations

from abc import ABC, abstractmethod

import torch
from torch import nn

from trainer.config import RunConfig
from trainer.distributed import Dist, average_gradients, broadcast_module
from trainer.recipe.ema import EMA
from trainer.sampling import Batch


class Method(ABC):
    """Subclasses set `name`, build `self.generator`, `self.nets` (discriminators) and `self.opts`, and implement
    `step(batch, step) -> {loss name: float}`."""

    name = "base"
    generator_class = ""
    # whether a mirrored crop can train its tactile side alone (`data.transpose_visual=false`): two-branch methods
    separable_visual = False

    def __init__(self, cfg: RunConfig, *, side: int, dist: Dist | None = None, device: str = "cpu"):
        self.cfg = cfg
        self.side = side
        self.dist = dist
        self.device = torch.device(device)
        self.generator: nn.Module
        self.nets: dict[str, nn.Module] = {}
        self.opts: dict[str, torch.optim.Optimizer] = {}
        self.info: dict = {}
        self.ema: EMA | None = None
        self.ema_probe: EMA | None = None

    def attach_ema(self, decay: float, ramp: float = 10.0, probe_ramp: float = 0.0) -> None:
        """Average G's weights from now on (`train.ema`); 0 leaves the raw weights in charge. A probe ramp keeps a
        second average that nothing reads while training, so two warm-ups compare on one trajectory."""
        self.ema = EMA(self.generator, decay, ramp) if decay > 0 else None
        self.ema_probe = EMA(self.generator, decay, probe_ramp) if decay > 0 and probe_ramp > 0 else None

    @property
    def eval_generator(self) -> nn.Module:
        """The weights that are validated, evaluated and exported: the average when there is one."""
        return self.ema.model if self.ema is not None else self.generator

    def after_step(self, step: int) -> None:
        for avg in (self.ema, self.ema_probe):
            if avg is not None:
                avg.update(self.generator, step)

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
        state = {"generator": self.generator.state_dict(),
                 "nets": {k: v.state_dict() for k, v in self.nets.items()},
                 "opts": {k: v.state_dict() for k, v in self.opts.items()}}
        if self.ema is not None:
            state["ema"] = self.ema.state_dict()
        if self.ema_probe is not None:
            state["ema_probe"] = self.ema_probe.state_dict()
        return state

    def load_state_dict(self, state: dict) -> None:
        self.generator.load_state_dict(state["generator"])
        for k, v in self.nets.items():
            v.load_state_dict(state["nets"][k])
        for k, v in self.opts.items():
            v.load_state_dict(state["opts"][k])
        if self.ema is not None:
            if "ema" not in state:
                raise KeyError("the checkpoint holds no weight average (train.ema was off when it was saved)")
            self.ema.load_state_dict(state["ema"])
        if self.ema_probe is not None:
            if "ema_probe" not in state:
                raise KeyError("the checkpoint holds no probe average (train.ema_probe_ramp was off when it was saved)")
            self.ema_probe.load_state_dict(state["ema_probe"])

    def train(self) -> None:
        self.generator.train()
        for n in self.nets.values():
            n.train()

    @abstractmethod
    def step(self, batch: Batch, step: int) -> dict[str, float]:
        """One optimisation step of every network; returns the logged loss values."""
