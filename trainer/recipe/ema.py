"""Exponential moving average of the generator's weights, used for validation, evaluation and export.

GAN generators oscillate around a good solution; averaging their weights over the last few hundred steps removes
most of that jitter at no training cost (Karras et al. 2018; Yazici et al. 2019). Buffers (none in our instance-norm
U-Net, running stats elsewhere) are copied, not averaged.
"""
from __future__ import annotations

import copy

import torch
from torch import nn


class EMA:
    def __init__(self, model: nn.Module, decay: float, ramp: float = 10.0):
        if not 0.0 < decay < 1.0:
            raise ValueError(f"EMA decay must be in (0, 1); got {decay}")
        if not ramp > 1.0:
            raise ValueError(f"EMA ramp must be > 1; got {ramp}")
        self.decay, self.ramp = decay, ramp
        self.model = copy.deepcopy(model).eval()
        for p in self.model.parameters():
            p.requires_grad_(False)

    @torch.no_grad()
    def update(self, model: nn.Module, step: int) -> None:
        # warm-up: the average covers about the last 1 / (ramp - 1) of the steps so far, so early weights are not
        # stuck at init (ramp 2 is the plain mean of every step so far)
        d = min(self.decay, (1.0 + step) / (self.ramp + step))
        for pe, p in zip(self.model.parameters(), model.parameters()):
            pe.lerp_(p.detach(), 1.0 - d)
        for be, b in zip(self.model.buffers(), model.buffers()):
            be.copy_(b)

    def state_dict(self) -> dict:
        return self.model.state_dict()

    def load_state_dict(self, state: dict) -> None:
        self.model.load_state_dict(state)
