"""The pix2pix ResNet-9 generator, the paper's main baseline: masked sketch only (no positional encoding) ->
5 channels (RGB + gx, gy), tanh. Trained on 32x32 patches and run on the full image, as in the paper (Sec. 5).

It offers the same interface as `TwoBranchUNet` (forward(sketch, mask, kind) with the contract's graph kinds,
model_config) so evaluation and the exporter treat both alike.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from kiosk.contract.graph import GRAPH_OUTPUTS


@dataclass
class ResnetConfig:
    ngf: int = 64
    n_blocks: int = 9
    out_visual: int = 3
    out_tactile: int = 2


class ResnetBlock(nn.Module):
    def __init__(self, *, dim: int):
        super().__init__()
        self.body = nn.Sequential(
            nn.ReflectionPad2d(1), nn.Conv2d(dim, dim, 3), nn.InstanceNorm2d(dim), nn.ReLU(True),
            nn.ReflectionPad2d(1), nn.Conv2d(dim, dim, 3), nn.InstanceNorm2d(dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


class ResnetGenerator(nn.Module):
    """Shape: sketch, mask (N, 1, H, W), H and W multiples of 4 -> visual (N, 3, H, W), tactile (N, 2, H, W)."""

    def __init__(self, *, ngf: int = 64, n_blocks: int = 9, out_visual: int = 3, out_tactile: int = 2):
        super().__init__()
        self.config = ResnetConfig(ngf, n_blocks, out_visual, out_tactile)
        layers: list[nn.Module] = [nn.ReflectionPad2d(3), nn.Conv2d(1, ngf, 7), nn.InstanceNorm2d(ngf), nn.ReLU(True)]
        for i in range(2):
            m = 2 ** i
            layers += [nn.Conv2d(ngf * m, ngf * m * 2, 3, 2, 1), nn.InstanceNorm2d(ngf * m * 2), nn.ReLU(True)]
        layers += [ResnetBlock(dim=ngf * 4) for _ in range(n_blocks)]
        for i in range(2):
            m = 2 ** (2 - i)
            layers += [nn.ConvTranspose2d(ngf * m, ngf * m // 2, 3, 2, 1, output_padding=1),
                       nn.InstanceNorm2d(ngf * m // 2), nn.ReLU(True)]
        layers += [nn.ReflectionPad2d(3), nn.Conv2d(ngf, out_visual + out_tactile, 7), nn.Tanh()]
        self.net = nn.Sequential(*layers)

    @classmethod
    def from_config(cls, cfg: dict | ResnetConfig) -> "ResnetGenerator":
        d = asdict(cfg) if isinstance(cfg, ResnetConfig) else dict(cfg)
        return cls(**d)

    def model_config(self) -> dict:
        return asdict(self.config)

    def _all(self, sketch: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        assert sketch.dim() == 4 and sketch.shape[1] == 1, f"sketch must be (N, 1, H, W); got {tuple(sketch.shape)}"
        assert mask.shape == sketch.shape, f"mask must match sketch {tuple(sketch.shape)}; got {tuple(mask.shape)}"
        return self.net(sketch * mask) * mask

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor, kind: str = "full"):
        """One network computes every channel; `kind` only picks which are returned."""
        assert kind in GRAPH_OUTPUTS, f"kind must be one of {', '.join(GRAPH_OUTPUTS)}; got {kind!r}"
        y = self._all(sketch, mask)
        parts = {"visual": y[:, :self.config.out_visual], "tactile": y[:, self.config.out_visual:]}
        outs = tuple(parts[name] for name in GRAPH_OUTPUTS[kind])
        return outs if len(outs) > 1 else outs[0]
