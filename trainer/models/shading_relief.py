"""A generator whose tactile output borrows the fine relief its own photo shows (trainer/shading_fit.py fits it).

Why: off the training touches the tactile head has nothing that says where the weave's ridges sit, but the visual
head, trained on the garment's photo, paints the weave's shading under the lamp. Shape from shading in its simplest,
linear form reads that back: the shading's fine bands are the height's derivative along the light, so the height is
their integral along it, and its gradient the slopes. The light's direction and strength are not assumed; a few
fixed filters (fine bands of the log-luminance, integrated along a few directions) are mixed with the model's own
relief by weights fitted on the training touches. One fixed linear filter on the photo, so it is exported as one
convolution beside the tactile head (with the fill below; its cost: docs/performance.md, "The shading relief").

The photo's log-luminance is taken over the object only: the background (the visual head's 0, grey) is filled with
the object's own luminance nearby (a normalised Gaussian), so the silhouette does not read as a cliff.
"""
from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from kiosk.contract.graph import GRAPH_OUTPUTS

# Fine bands of the log-luminance (difference of Gaussians, sigma pairs in px): where the weave's shading lives.
# Coarser bands carry the lamp's falloff, prints and dye mottling more than folds (measured, docs/training.md).
BANDS = ((0.7, 1.5), (1.5, 3.0))
DIRECTIONS = 4            # integration directions over the half circle
REGULARISE = 1.0          # k.u^2 + REGULARISE |k|^2: the integral stays finite across the light
KERNEL = 11               # filter support (px): 31, 21, 15 and 11 score alike (11 best by <0.05 deg), 11 is 8x cheaper
# The background filled from the object within about 3 x this (px): it need reach only as far as the filters do
# (KERNEL // 2; at 2 px it falls short on a diagonal). 8, 3 and 2 px score alike (docs/training.md "Shading relief"):
# 3 is 19 taps a pass against 49.
FILL_SIGMA = 3.0
LUMA = (0.299, 0.587, 0.114)
FLOOR = 1e-3              # luminance floor before the log (a black pixel must not reach -inf)


def filter_bank(kernel: int = KERNEL, bands=BANDS, directions: int = DIRECTIONS,
                regularise: float = REGULARISE) -> np.ndarray:
    """(len(bands) * directions, 2, kernel, kernel) float32: per (band, direction) the slopes (gx, gy) of the height
    whose derivative along the direction is the band, as spatial filters (made in the Fourier domain on a grid four
    times the kernel, then cut to the kernel)."""
    n = 4 * kernel
    k = 2 * np.pi * np.fft.fftfreq(n)
    kx, ky = np.meshgrid(k, k)
    k2 = kx * kx + ky * ky
    out = []
    for s1, s2 in bands:
        dog = np.exp(-0.5 * s1 * s1 * k2) - np.exp(-0.5 * s2 * s2 * k2)
        for t in np.arange(directions) * math.pi / directions:
            ku = kx * math.cos(t) + ky * math.sin(t)
            den = ku * ku + regularise * k2
            h = np.divide(ku * dog, den, out=np.zeros_like(den), where=den > 0)   # 0 at k = 0: dog is 0 there too
            pair = []
            for kd in (kx, ky):
                sp = np.fft.fftshift(np.real(np.fft.ifft2(kd * h)))
                c, r = n // 2, kernel // 2
                cut = sp[c - r:c + r + 1, c - r:c + r + 1]
                pair.append(cut - cut.mean())   # the cut's leftover DC out: uniform brightness is no slope
            out.append(pair)
    return np.asarray(out, np.float32)


def _gauss(sigma: float) -> torch.Tensor:
    r = int(math.ceil(3 * sigma))
    x = torch.arange(-r, r + 1, dtype=torch.float32)
    g = torch.exp(-0.5 * (x / sigma) ** 2)
    return g / g.sum()


def blur(a: torch.Tensor, sigma: float) -> torch.Tensor:
    """A separable Gaussian blur of (N, 1, H, W), edges replicated."""
    g = _gauss(sigma).to(a)
    r = g.numel() // 2
    a = F.conv2d(F.pad(a, (r, r, 0, 0), mode="replicate"), g.view(1, 1, 1, -1))
    return F.conv2d(F.pad(a, (0, 0, r, r), mode="replicate"), g.view(1, 1, -1, 1))


def dog_bands(a: torch.Tensor) -> torch.Tensor:
    """(N, C, len(BANDS), H, W): each channel of (N, C, H, W) as its differences of Gaussians, one per band (the
    weave-scale visual loss and the photometric tactile loss compare these)."""
    n, c, h, w = a.shape
    flat = a.reshape(n * c, 1, h, w)
    blurred = {s: blur(flat, s) for s in sorted({s for band in BANDS for s in band})}
    return torch.cat([blurred[s1] - blurred[s2] for s1, s2 in BANDS], 1).reshape(n, c, len(BANDS), h, w)


def log_luma(visual: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W): the log-luminance of a [-1, 1] RGB image, finite for black pixels."""
    rgb = ((visual + 1.0) * 0.5).clamp(FLOOR, 1.0)
    w = torch.tensor(LUMA, dtype=visual.dtype, device=visual.device).view(1, 3, 1, 1)
    return torch.log((rgb * w).sum(1, keepdim=True).clamp_min(FLOOR))


def log_luminance(visual: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W): the visual output's log-luminance on the object, its background filled from the object."""
    lum = log_luma(visual)
    m = (mask > 0.5).to(visual.dtype)
    # beyond the fill's reach: 0, harmless (beyond the filters' reach of the object too, and masked later)
    filled = blur(lum * m, FILL_SIGMA) / blur(m, FILL_SIGMA).clamp_min(1e-3)
    return lum * m + filled * (1 - m)


def shading_slopes(visual: torch.Tensor, mask: torch.Tensor, bank: torch.Tensor) -> torch.Tensor:
    """(N, C, H, W): each filter's output on the visual's log-luminance, 0 off the object. `bank` is (F, 2, K, K)
    (C = 2F: every filter's gx, gy) or (C, 1, K, K)."""
    lum = log_luminance(visual, mask)
    r = bank.shape[-1] // 2
    out = F.conv2d(F.pad(lum, (r, r, r, r), mode="replicate"), bank.reshape(-1, 1, *bank.shape[-2:]))
    return out * (mask > 0.5).to(out.dtype)


class ShadingRelief(nn.Module):
    """tactile = w0 x the generator's tactile + the fitted filter of its visual's log-luminance (one (2, K, K)
    kernel: the bank mixed by the fitted weights), on the object. Like ReliefGain, no clamp after the head."""

    def __init__(self, generator: nn.Module, model_weight: float, kernel: np.ndarray):
        super().__init__()
        kernel = np.asarray(kernel, np.float32)
        if not (math.isfinite(model_weight) and kernel.ndim == 3 and kernel.shape[0] == 2
                and kernel.shape[1] == kernel.shape[2] and kernel.shape[1] % 2 == 1 and np.isfinite(kernel).all()):
            raise ValueError("shading relief needs a finite model weight and a finite (2, K, K) kernel, K odd")
        self.generator = generator
        self.register_buffer("model_weight", torch.tensor(float(model_weight)))
        self.register_buffer("kernel", torch.from_numpy(kernel)[:, None])

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor, kind: str = "full"):
        if kind == "visual":   # no relief asked for: the visual head alone
            return self.generator(sketch, mask, kind)
        names = GRAPH_OUTPUTS[kind]
        # the photo is needed for the relief: a tactile-only graph still runs the visual head
        vis, tac = self.generator(sketch, mask, "full")
        tac = self.model_weight * tac * (mask > 0.5).to(tac.dtype) + shading_slopes(vis, mask, self.kernel)
        outs = tuple({"visual": vis, "tactile": tac}[n] for n in names)
        return outs if len(outs) > 1 else outs[0]
