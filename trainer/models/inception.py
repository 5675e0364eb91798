"""The first block of torchvision's InceptionV3 (up to maxpool1, 64-d features): what SIFID compares. State_dict
keys match torchvision's `inception_v3` (`Conv2d_1a_3x3.conv.weight`, `...bn.running_mean`, ...), so its .pth
loads directly; everything after the first block is ignored.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from trainer.texture_distance import frechet


class BasicConv2d(nn.Module):
    def __init__(self, cin: int, cout: int, **kw):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, bias=False, **kw)
        self.bn = nn.BatchNorm2d(cout, eps=0.001)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.bn(self.conv(x)))


class InceptionBlock1(nn.Module):
    """Shape: (N, 3, H, W) in [-1, 1] -> (N, 64, H', W')."""

    def __init__(self):
        super().__init__()
        self.Conv2d_1a_3x3 = BasicConv2d(3, 32, kernel_size=3, stride=2)
        self.Conv2d_2a_3x3 = BasicConv2d(32, 32, kernel_size=3)
        self.Conv2d_2b_3x3 = BasicConv2d(32, 64, kernel_size=3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.Conv2d_2b_3x3(self.Conv2d_2a_3x3(self.Conv2d_1a_3x3(x)))
        return F.max_pool2d(x, 3, 2)

    @classmethod
    def from_file(cls, path: str | Path) -> "InceptionBlock1":
        state = torch.load(path, map_location="cpu", weights_only=True)
        net = cls()
        mine = {k: v for k, v in state.items() if k.split(".")[0] in dict(net.named_children())}
        missing, _ = net.load_state_dict(mine, strict=False)
        if missing:
            raise ValueError(f"{path}: not an InceptionV3 state_dict (missing {missing[:3]}...)")
        return net.eval()


def sifid(net: InceptionBlock1, a: torch.Tensor, b: torch.Tensor, *, size: int = 299) -> float:
    """Single-image FID: Frechet distance between the spatial feature statistics of two (1, 3, H, W) images."""
    with torch.no_grad():
        fa, fb = (net(F.interpolate(t, size=(size, size), mode="bilinear", align_corners=False))
                  for t in (a, b))
    xa = fa[0].reshape(fa.shape[1], -1).T.double().numpy()
    xb = fb[0].reshape(fb.shape[1], -1).T.double().numpy()
    return frechet(xa, xb)


def sifid_channels(net: InceptionBlock1, a: torch.Tensor, b: torch.Tensor) -> float:
    """Mean SIFID over patches and channels of (K, C, h, w) tensors, each channel shown as a grey image (the
    published tactile SIFID: gx and gy separately)."""
    vals = [sifid(net, a[k:k + 1, c:c + 1].expand(1, 3, -1, -1), b[k:k + 1, c:c + 1].expand(1, 3, -1, -1))
            for k in range(a.shape[0]) for c in range(a.shape[1])]
    return float(np.mean(vals))
