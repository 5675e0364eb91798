"""The pix2pix ResNet-9 generator, the paper's main baseline: masked sketch only (no positional encoding) ->
5 channels (RGB + gx, gy), tanh. Trained on 32x32 patches and run on the full image, as in the paper (Sec. 5).

It offers the same interface as `TwoBranchUNet` (forward(sketch, mask, kind) with the contract's graph kinds,
model_config) so evaluation and the exporter treat both alike. `norm` and `dropout` default to the
earlier variant (instance norm, no dropout) so its checkpoints load unchanged; the pix2pix method sets the pix2pix
defaults (batch norm, dropout 0.5 in the residual blocks).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from trainer.models.split_outputs import SplitOutputs


@dataclass
class ResnetConfig:
    ngf: int = 64
    n_blocks: int = 9
    out_visual: int = 3
    out_tactile: int = 2
    norm: str = "instance"
    dropout: float = 0.0


NORMS = {"instance": nn.InstanceNorm2d, "batch": nn.BatchNorm2d}


def norm_layer(norm: str, channels: int) -> nn.Module:
    assert norm in NORMS, f"norm must be one of {', '.join(NORMS)}; got {norm!r}"
    return NORMS[norm](channels)


class ResnetBlock(nn.Module):
    """x + (pad, conv3, norm, ReLU, [dropout], pad, conv3, norm): the pix2pix / pix2pixHD residual block."""

    def __init__(self, *, dim: int, norm: str = "instance", dropout: float = 0.0):
        super().__init__()
        drop = [nn.Dropout(dropout)] if dropout > 0 else []
        self.body = nn.Sequential(
            nn.ReflectionPad2d(1), nn.Conv2d(dim, dim, 3), norm_layer(norm, dim), nn.ReLU(True), *drop,
            nn.ReflectionPad2d(1), nn.Conv2d(dim, dim, 3), norm_layer(norm, dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


class ResnetGenerator(SplitOutputs):
    """Shape: sketch, mask (N, 1, H, W), H and W multiples of 4 -> visual (N, 3, H, W), tactile (N, 2, H, W)."""

    def __init__(self, *, ngf: int = 64, n_blocks: int = 9, out_visual: int = 3, out_tactile: int = 2,
                 norm: str = "instance", dropout: float = 0.0):
        super().__init__()
        self.config = ResnetConfig(ngf, n_blocks, out_visual, out_tactile, norm, dropout)
        self.out_visual = out_visual
        layers: list[nn.Module] = [nn.ReflectionPad2d(3), nn.Conv2d(1, ngf, 7), norm_layer(norm, ngf), nn.ReLU(True)]
        for i in range(2):
            m = 2 ** i
            layers += [nn.Conv2d(ngf * m, ngf * m * 2, 3, 2, 1), norm_layer(norm, ngf * m * 2), nn.ReLU(True)]
        layers += [ResnetBlock(dim=ngf * 4, norm=norm, dropout=dropout) for _ in range(n_blocks)]
        for i in range(2):
            m = 2 ** (2 - i)
            layers += [nn.ConvTranspose2d(ngf * m, ngf * m // 2, 3, 2, 1, output_padding=1),
                       norm_layer(norm, ngf * m // 2), nn.ReLU(True)]
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
