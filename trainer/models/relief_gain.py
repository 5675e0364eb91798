"""A generator whose tactile output is multiplied by one calibrated gain (trainer/calibration.py).

A wrapper rather than a weight edit because the tactile head ends in tanh: a gain after it cannot be folded into the
last convolution. It keeps the generator's forward(sketch, mask, kind) contract, so evaluation, the exporter's graphs
and their parity check run through it unchanged, and the exported graph carries the gain as one Mul."""
from __future__ import annotations

import math

import torch
from torch import nn

from kiosk.contract.graph import GRAPH_OUTPUTS


class ReliefGain(nn.Module):
    def __init__(self, generator: nn.Module, gain: float):
        super().__init__()
        if not (math.isfinite(gain) and gain > 0):
            raise ValueError(f"relief gain must be a positive finite number; got {gain!r}")
        self.generator = generator
        self.register_buffer("gain", torch.tensor(float(gain)))

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor, kind: str = "full"):
        out = self.generator(sketch, mask, kind)
        names = GRAPH_OUTPUTS[kind]
        outs = out if isinstance(out, tuple) else (out,)
        outs = tuple(o * self.gain if name == "tactile" else o for name, o in zip(names, outs))
        return outs if len(outs) > 1 else outs[0]
