"""A generator whose tactile output is averaged over mirrored views of its input (test-time mirroring).

Why: a 1 000-step model's relief away from the training touches is partly noise of its seed and of the crop's
orientation; the same sketch mirrored is another draw of it. Each view's relief is mirrored back (the height field's
derivatives follow the mirror, as in trainer/recipe/mirror.py: across the diagonal gx and gy trade places, left to
right gx changes sign) and the views are averaged. Averaging shrinks the relief where the views disagree, so it is
meant to be scored with a relief calibration after it (trainer/calibration.py, ReliefGain outside this wrapper).
The visual output is the plain view's: only the relief is averaged, so the photo and its scores do not change.

It keeps the generator's forward(sketch, mask, kind) contract, so evaluation, the exporter's graphs and their
parity check run through it; an exported graph runs the generator once per view (its latency grows with them).
"""
from __future__ import annotations

import torch
from torch import nn

from kiosk.contract.graph import GRAPH_OUTPUTS

# Which views each mode averages, besides the plain one. A view names its mirrors in the order they are applied to
# the input: "t" across the main diagonal, "f" left to right.
MODES = {"none": (), "flip": ("f",), "transpose": ("t",), "flip+transpose": ("f", "t", "tf")}


def _mirror_in(x: torch.Tensor, op: str) -> torch.Tensor:
    return x.transpose(-1, -2) if op == "t" else torch.flip(x, dims=(-1,))


def _mirror_relief_back(tac: torch.Tensor, op: str) -> torch.Tensor:
    """Undo one mirror on a (gx, gy) relief: the image is mirrored back and the slope vector with it."""
    gx, gy = tac[:, 0:1], tac[:, 1:2]
    if op == "t":
        return torch.cat([gy.transpose(-1, -2), gx.transpose(-1, -2)], dim=1)
    return torch.cat([-torch.flip(gx, dims=(-1,)), torch.flip(gy, dims=(-1,))], dim=1)


def view_in(x: torch.Tensor, view: str) -> torch.Tensor:
    for op in view:
        x = _mirror_in(x, op)
    return x.contiguous()


def view_back(tac: torch.Tensor, view: str) -> torch.Tensor:
    for op in reversed(view):
        tac = _mirror_relief_back(tac, op)
    return tac


class MirrorAverage(nn.Module):
    def __init__(self, generator: nn.Module, mode: str):
        super().__init__()
        if mode not in MODES or mode == "none":
            raise ValueError(f"mirror mode must be one of {', '.join(m for m in MODES if m != 'none')}; got {mode!r}")
        self.generator, self.mode, self.views = generator, mode, MODES[mode]

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor, kind: str = "full"):
        out = self.generator(sketch, mask, kind)
        names = GRAPH_OUTPUTS[kind]
        outs = list(out) if isinstance(out, tuple) else [out]
        if "tactile" in names:
            i = names.index("tactile")
            total = outs[i]
            for view in self.views:
                o = self.generator(view_in(sketch, view), view_in(mask, view), kind)
                total = total + view_back(o[i] if isinstance(o, tuple) else o, view)
            outs[i] = total / (1 + len(self.views))
        return tuple(outs) if len(outs) > 1 else outs[0]
