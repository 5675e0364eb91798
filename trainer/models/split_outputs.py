"""The two-branch interface for single-trunk generators: one network computes 3 + 2 channels, and the exporter,
evaluation and kiosk still see forward(sketch, mask) -> (visual, tactile), forward_visual, forward_tactile."""
from __future__ import annotations

import torch
from torch import nn

OUTPUTS = ("both", "visual", "tactile")


class SplitOutputs(nn.Module):
    """Subclasses implement `_all(sketch, mask) -> (N, 5, H, W)` (already masked) and set `out_visual`, `outputs`."""

    out_visual = 3
    outputs = "both"

    def _all(self, sketch: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    @staticmethod
    def check_inputs(sketch: torch.Tensor, mask: torch.Tensor, multiple: int) -> None:
        assert sketch.dim() == 4 and sketch.shape[1] == 1, f"sketch must be (N, 1, H, W); got {tuple(sketch.shape)}"
        assert mask.shape == sketch.shape, f"mask must match sketch {tuple(sketch.shape)}; got {tuple(mask.shape)}"
        assert sketch.shape[-1] % multiple == 0 and sketch.shape[-2] % multiple == 0, \
            f"H and W must be multiples of {multiple}; got {tuple(sketch.shape[-2:])}"

    def forward_visual(self, sketch: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self._all(sketch, mask)[:, :self.out_visual]

    def forward_tactile(self, sketch: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self._all(sketch, mask)[:, self.out_visual:]

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor):
        y = self._all(sketch, mask)
        if self.outputs == "visual":
            return y[:, :self.out_visual]
        if self.outputs == "tactile":
            return y[:, self.out_visual:]
        return y[:, :self.out_visual], y[:, self.out_visual:]
