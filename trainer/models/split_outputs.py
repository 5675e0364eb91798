"""The contract's graph kinds for single-trunk generators: one network computes 3 + 2 channels, and the exporter,
evaluation and kiosk call forward(sketch, mask, kind) as they do for `TwoBranchUNet` (the kind only picks which
channels are returned; a single trunk cannot skip a branch)."""
from __future__ import annotations

import torch
from torch import nn

from kiosk.contract.graph import GRAPH_OUTPUTS


class SplitOutputs(nn.Module):
    """Subclasses implement `_all(sketch, mask) -> (N, 5, H, W)` (already masked) and set `out_visual`."""

    out_visual = 3

    def _all(self, sketch: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    @staticmethod
    def check_inputs(sketch: torch.Tensor, mask: torch.Tensor, multiple: int) -> None:
        assert sketch.dim() == 4 and sketch.shape[1] == 1, f"sketch must be (N, 1, H, W); got {tuple(sketch.shape)}"
        assert mask.shape == sketch.shape, f"mask must match sketch {tuple(sketch.shape)}; got {tuple(mask.shape)}"
        assert sketch.shape[-1] % multiple == 0 and sketch.shape[-2] % multiple == 0, \
            f"H and W must be multiples of {multiple}; got {tuple(sketch.shape[-2:])}"

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor, kind: str = "full"):
        assert kind in GRAPH_OUTPUTS, f"kind must be one of {', '.join(GRAPH_OUTPUTS)}; got {kind!r}"
        y = self._all(sketch, mask)
        parts = {"visual": y[:, :self.out_visual], "tactile": y[:, self.out_visual:]}
        outs = tuple(parts[name] for name in GRAPH_OUTPUTS[kind])
        return outs if len(outs) > 1 else outs[0]
