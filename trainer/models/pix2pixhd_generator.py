"""pix2pixHD's coarse-to-fine generator (Wang et al. 2018): a global ResNet generator at half resolution whose last
features are added to a local enhancer's at full resolution. Masked sketch (1 channel) -> RGB + gx, gy (tanh).

Widths as in pix2pixHD's high-resolution recipe (`--netG local --ngf 32`: enhancer 32, global net 64, 9 global and
3 local residual blocks). The global net downsamples 3 times, not pix2pixHD's 4: its input is half of a 32 px
training patch, and a fourth halving leaves a 1x1 bottleneck that reflection padding cannot pad.

Shape: sketch, mask (N, 1, H, W), H and W multiples of `multiple` (2^(downsample + 1)) -> (N, 3, H, W), (N, 2, H, W).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

from trainer.models.pix2pix_generator import ResnetBlock, norm_layer
from trainer.models.split_outputs import SplitOutputs


@dataclass
class HDConfig:
    ngf: int = 32                 # local enhancer width; the global net has 2 x ngf
    global_blocks: int = 9
    local_blocks: int = 3
    global_downsample: int = 3
    out_visual: int = 3
    out_tactile: int = 2
    norm: str = "instance"


def _global_trunk(*, in_ch: int, ngf: int, n_down: int, n_blocks: int, norm: str) -> nn.Sequential:
    """pix2pixHD GlobalGenerator without its output layer: ends with ngf features at the input's resolution."""
    layers: list[nn.Module] = [nn.ReflectionPad2d(3), nn.Conv2d(in_ch, ngf, 7), norm_layer(norm, ngf), nn.ReLU(True)]
    for i in range(n_down):
        c = ngf * 2 ** i
        layers += [nn.Conv2d(c, 2 * c, 3, 2, 1), norm_layer(norm, 2 * c), nn.ReLU(True)]
    layers += [ResnetBlock(dim=ngf * 2 ** n_down, norm=norm) for _ in range(n_blocks)]
    for i in range(n_down, 0, -1):
        c = ngf * 2 ** i
        layers += [nn.ConvTranspose2d(c, c // 2, 3, 2, 1, output_padding=1), norm_layer(norm, c // 2), nn.ReLU(True)]
    return nn.Sequential(*layers)


class Pix2PixHDGenerator(SplitOutputs):
    def __init__(self, *, ngf: int = 32, global_blocks: int = 9, local_blocks: int = 3, global_downsample: int = 3,
                 out_visual: int = 3, out_tactile: int = 2, norm: str = "instance"):
        super().__init__()
        self.config = HDConfig(ngf, global_blocks, local_blocks, global_downsample, out_visual, out_tactile, norm)
        self.out_visual = out_visual
        self.multiple = 2 ** (global_downsample + 1)
        self.global_net = _global_trunk(in_ch=1, ngf=2 * ngf, n_down=global_downsample, n_blocks=global_blocks,
                                        norm=norm)
        self.local_down = nn.Sequential(
            nn.ReflectionPad2d(3), nn.Conv2d(1, ngf, 7), norm_layer(norm, ngf), nn.ReLU(True),
            nn.Conv2d(ngf, 2 * ngf, 3, 2, 1), norm_layer(norm, 2 * ngf), nn.ReLU(True))
        self.local_up = nn.Sequential(
            *[ResnetBlock(dim=2 * ngf, norm=norm) for _ in range(local_blocks)],
            nn.ConvTranspose2d(2 * ngf, ngf, 3, 2, 1, output_padding=1), norm_layer(norm, ngf), nn.ReLU(True),
            nn.ReflectionPad2d(3), nn.Conv2d(ngf, out_visual + out_tactile, 7), nn.Tanh())

    @classmethod
    def from_config(cls, cfg: dict | HDConfig) -> "Pix2PixHDGenerator":
        d = asdict(cfg) if isinstance(cfg, HDConfig) else dict(cfg)
        return cls(**d)

    def model_config(self) -> dict:
        return asdict(self.config)

    def _all(self, sketch: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        self.check_inputs(sketch, mask, self.multiple)
        x = sketch * mask
        coarse = self.global_net(F.avg_pool2d(x, 3, stride=2, padding=1, count_include_pad=False))
        return self.local_up(self.local_down(x) + coarse) * mask
