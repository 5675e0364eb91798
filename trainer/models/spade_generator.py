"""GauGAN's SPADE generator (Park et al. 2019) conditioned on the masked sketch in place of a label map.

As in GauGAN's defaults (`netG spade`, `ngf 64`, `num_upsampling_layers normal`, `norm_G spectralspadebatch3x3`, no
encoder): a 3x3 convolution of the sketch resized to H/32 x W/32 starts at 16 x ngf channels; seven SPADE residual
blocks (head, two middle, four up) halve the width while five nearest upsamplings restore the size; leaky ReLU,
3x3 conv to RGB + gx, gy, tanh. SPADE: parameter-free normalisation, then a per-pixel scale and shift predicted
from the resized sketch by a shared 3x3 conv (128 hidden) and two 3x3 convs. Spectral norm on every block convolution.

The normalisation always uses the batch's own statistics, in evaluation as in training (a batch norm without
running statistics; at one crop per batch, an instance norm). GauGAN's BatchNorm evaluated with running statistics gathered over single training
crops, which drifted far from any one crop's: the trained generator's visual L1 on a training crop was 0.70 in eval
mode against 0.20 with the crop's own statistics, and the baseline did not train at all.

Shape: sketch, mask (N, 1, H, W), H and W multiples of 32 -> (N, 3, H, W), (N, 2, H, W).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.parametrizations import spectral_norm

from trainer.models.split_outputs import SplitOutputs

MULTIPLE = 32  # five upsamplings


@dataclass
class SpadeConfig:
    ngf: int = 64
    hidden: int = 128
    label_nc: int = 1
    out_visual: int = 3
    out_tactile: int = 2


NORM_EPS = 1e-5   # BatchNorm2d's


def batch_normalise(x: torch.Tensor) -> torch.Tensor:
    """Parameter-free batch norm with the batch's own statistics, in eval as in training (written out so it
    exports to ONNX, which BatchNorm2d without running statistics does not)."""
    mean = x.mean(dim=(0, 2, 3), keepdim=True)
    var = x.var(dim=(0, 2, 3), unbiased=False, keepdim=True)
    return (x - mean) * torch.rsqrt(var + NORM_EPS)


class SPADE(nn.Module):
    def __init__(self, *, channels: int, label_nc: int, hidden: int):
        super().__init__()
        self.shared = nn.Sequential(nn.Conv2d(label_nc, hidden, 3, padding=1), nn.ReLU(True))
        self.gamma = nn.Conv2d(hidden, channels, 3, padding=1)
        self.beta = nn.Conv2d(hidden, channels, 3, padding=1)

    def forward(self, x: torch.Tensor, seg: torch.Tensor) -> torch.Tensor:
        a = self.shared(F.interpolate(seg, size=x.shape[-2:], mode="nearest"))
        return batch_normalise(x) * (1 + self.gamma(a)) + self.beta(a)


class SPADEResBlock(nn.Module):
    def __init__(self, *, fin: int, fout: int, label_nc: int, hidden: int):
        super().__init__()
        mid = min(fin, fout)
        self.norm_0 = SPADE(channels=fin, label_nc=label_nc, hidden=hidden)
        self.conv_0 = spectral_norm(nn.Conv2d(fin, mid, 3, padding=1))
        self.norm_1 = SPADE(channels=mid, label_nc=label_nc, hidden=hidden)
        self.conv_1 = spectral_norm(nn.Conv2d(mid, fout, 3, padding=1))
        self.learned_shortcut = fin != fout
        if self.learned_shortcut:
            self.norm_s = SPADE(channels=fin, label_nc=label_nc, hidden=hidden)
            self.conv_s = spectral_norm(nn.Conv2d(fin, fout, 1, bias=False))

    def forward(self, x: torch.Tensor, seg: torch.Tensor) -> torch.Tensor:
        s = self.conv_s(self.norm_s(x, seg)) if self.learned_shortcut else x
        dx = self.conv_0(F.leaky_relu(self.norm_0(x, seg), 0.2))
        dx = self.conv_1(F.leaky_relu(self.norm_1(dx, seg), 0.2))
        return s + dx


class SpadeGenerator(SplitOutputs):
    def __init__(self, *, ngf: int = 64, hidden: int = 128, label_nc: int = 1, out_visual: int = 3,
                 out_tactile: int = 2):
        super().__init__()
        self.config = SpadeConfig(ngf, hidden, label_nc, out_visual, out_tactile)
        self.out_visual = out_visual
        nf = ngf
        self.fc = nn.Conv2d(label_nc, 16 * nf, 3, padding=1)

        def block(fin: int, fout: int) -> SPADEResBlock:
            return SPADEResBlock(fin=fin * nf, fout=fout * nf, label_nc=label_nc, hidden=hidden)

        self.head = block(16, 16)
        self.middle = nn.ModuleList([block(16, 16), block(16, 16)])
        self.ups = nn.ModuleList([block(16, 8), block(8, 4), block(4, 2), block(2, 1)])
        self.conv_img = nn.Conv2d(nf, out_visual + out_tactile, 3, padding=1)

    @classmethod
    def from_config(cls, cfg: dict | SpadeConfig) -> "SpadeGenerator":
        d = asdict(cfg) if isinstance(cfg, SpadeConfig) else dict(cfg)
        return cls(**d)

    def model_config(self) -> dict:
        return asdict(self.config)

    @staticmethod
    def _up(x: torch.Tensor) -> torch.Tensor:
        return F.interpolate(x, scale_factor=2.0, mode="nearest")

    def _all(self, sketch: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        self.check_inputs(sketch, mask, MULTIPLE)
        seg = sketch * mask
        h, w = sketch.shape[-2] // MULTIPLE, sketch.shape[-1] // MULTIPLE
        x = self.fc(F.interpolate(seg, size=(h, w), mode="nearest"))
        x = self._up(self.head(x, seg))
        x = self.middle[1](self.middle[0](x, seg), seg)
        for blk in self.ups:
            x = self._up(x)
            x = blk(x, seg)
        return torch.tanh(self.conv_img(F.leaky_relu(x, 0.2))) * mask
