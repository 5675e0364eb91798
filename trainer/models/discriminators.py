"""Multi-scale PatchGAN discriminators (pix2pixHD): each scale is an N-layer PatchGAN that returns its intermediate
features too, for the feature-matching loss. The visual D sees (sketch, image); the tactile D sees 32x32 patches
of (gx, gy, sketch, RGB, contact mask) - 7 channels.

A 4x4/stride-2 PatchGAN with n layers needs an input side of at least 3 * 2^n; scales whose input would be smaller
use fewer layers (`min_input` = the smallest side the D will see), so 32x32 tactile patches work at every scale.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


class NLayerD(nn.Module):
    """PatchGAN: returns a list of feature maps, the last being the (N, 1, h, w) logits."""

    def __init__(self, *, in_ch: int, ndf: int = 8, n_layers: int = 3, norm: str = "batch"):
        super().__init__()
        assert n_layers >= 1, f"n_layers must be >= 1; got {n_layers}"
        Norm = {"batch": nn.BatchNorm2d, "instance": nn.InstanceNorm2d, "none": None}[norm]
        blocks = [nn.Sequential(nn.Conv2d(in_ch, ndf, 4, 2, 1), nn.LeakyReLU(0.2, True))]
        nf = ndf
        for i in range(1, n_layers + 1):
            prev, nf = nf, min(nf * 2, ndf * 8)
            stride = 2 if i < n_layers else 1
            layers: list[nn.Module] = [nn.Conv2d(prev, nf, 4, stride, 1)]
            if Norm is not None:
                layers.append(Norm(nf))
            layers.append(nn.LeakyReLU(0.2, True))
            blocks.append(nn.Sequential(*layers))
        blocks.append(nn.Sequential(nn.Conv2d(nf, 1, 4, 1, 1)))
        self.blocks = nn.ModuleList(blocks)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        feats = []
        for b in self.blocks:
            x = b(x)
            feats.append(x)
        return feats


def layers_for(side: int, n_layers: int) -> int:
    """Most layers (<= n_layers) a PatchGAN can use on a `side` px input (stride-2 convs = n_layers, then two
    4x4/stride-1 convs, each removing one pixel)."""
    fit = int(math.floor(math.log2(max(side, 1) / 3.0))) if side >= 3 else 0
    return max(1, min(n_layers, fit))


class MultiScaleD(nn.Module):
    """`num_D` PatchGANs on the input downsampled by 1, 2, 4, ...; returns [features per scale]."""

    def __init__(self, *, in_ch: int, ndf: int = 8, n_layers: int = 3, num_D: int = 3, norm: str = "batch",
                 min_input: int = 256):
        super().__init__()
        self.min_input = min_input
        self.scales = nn.ModuleList([
            NLayerD(in_ch=in_ch, ndf=ndf, n_layers=layers_for(min_input // 2 ** k, n_layers), norm=norm)
            for k in range(num_D)])

    def forward(self, x: torch.Tensor) -> list[list[torch.Tensor]]:
        assert x.dim() == 4 and min(x.shape[-2:]) >= self.min_input, \
            f"expected (N, C, H, W) with H, W >= {self.min_input}; got {tuple(x.shape)}"
        # Standard layout first: CUDA's avg_pool2d (torch 2.11, H100) differentiates a channels-last input wrongly
        # under create_graph (R1's double backward), which made the tactile D diverge on GPUs (docs/training.md,
        # "On a GPU"); forward values were right, so nothing but R1 showed it.
        x = x.contiguous()
        out = []
        for k, d in enumerate(self.scales):
            if k:
                x = F.avg_pool2d(x, 3, stride=2, padding=1, count_include_pad=False)
            out.append(d(x))
        return out
