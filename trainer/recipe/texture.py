"""Texture-statistics loss on tactile patches: match the mean and covariance of Gaussian-derivative filter responses
(the bank FB-SIFID scores with) between generated and real patches, inside the contact mask.

An L1 loss rewards the blurred average of plausible textures; this term only asks that the generated patches have
the real ones' strength, fineness and orientation of relief, which is what a fingertip discriminates.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F

SIGMAS = (1.0, 2.0)
ORDERS = ((0, 1), (1, 0), (0, 2), (1, 1), (2, 0))


def _gauss_derivative_kernels(dtype=torch.float32) -> torch.Tensor:
    ks = []
    for s in SIGMAS:
        r = int(math.ceil(3 * s))
        t = torch.arange(-r, r + 1, dtype=torch.float64)
        g = torch.exp(-t ** 2 / (2 * s * s))
        g = g / g.sum()
        d1 = -t / (s * s) * g
        d2 = (t ** 2 / s ** 4 - 1 / (s * s)) * g
        d = {0: g, 1: d1, 2: d2}
        size = 2 * max(int(math.ceil(3 * sg)) for sg in SIGMAS) + 1
        for oy, ox in ORDERS:
            k = torch.outer(d[oy], d[ox]) * s ** (oy + ox)
            pad = (size - k.shape[0]) // 2
            ks.append(F.pad(k, (pad, pad, pad, pad)))
    return torch.stack(ks)[:, None].to(dtype)


class TextureStatsLoss(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.register_buffer("kernels", _gauss_derivative_kernels(), persistent=False)

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """(N, C, H, W) -> (N, C*K, H', W') filter responses per channel (valid convolution: no border effects)."""
        n, c, h, w = x.shape
        k = self.kernels.to(x.dtype)
        f = F.conv2d(x.reshape(n * c, 1, h, w), k)
        return f.reshape(n, c * k.shape[0], *f.shape[-2:])

    def forward(self, fake: torch.Tensor, real: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Squared distance of feature means plus covariances, pooled over the masked positions of all patches."""
        ff, fr = self.features(fake * mask), self.features(real * mask)
        m = self.features_mask(mask)
        wsum = m.sum().clamp_min(1.0)

        def stats(f):
            x = f.permute(0, 2, 3, 1).reshape(-1, f.shape[1])
            wv = m.reshape(-1, 1)
            mu = (x * wv).sum(0) / wsum
            xc = (x - mu) * wv
            return mu, xc.T @ xc / wsum

        mu_f, cov_f = stats(ff)
        mu_r, cov_r = stats(fr)
        # the eps keeps the norm's gradient finite where the statistics agree (or no position is in full contact)
        return (mu_f - mu_r).pow(2).sum() + ((cov_f - cov_r).pow(2).sum() + 1e-12).sqrt()

    def features_mask(self, mask: torch.Tensor) -> torch.Tensor:
        """Positions whose whole filter support lies in contact (so mask edges do not count as texture)."""
        size = self.kernels.shape[-1]
        inside = -F.max_pool2d(-mask[:, :1], size, stride=1)
        return (inside > 0.5).to(mask.dtype)
