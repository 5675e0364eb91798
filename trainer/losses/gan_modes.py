"""The GAN objectives the baselines were published with, on multi-scale discriminator outputs (lists of feature
lists; the last entry is the logits), averaged over scales:
- "vanilla": pix2pix's cross-entropy (non-saturating for G), the D loss halved as pix2pix does;
- "lsgan": pix2pixHD's least squares (targets 1 and 0), the D loss halved;
- "hinge": GauGAN's hinge loss, D: relu(1 - real) + relu(1 + fake); G: -fake.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

from trainer.losses.gan import _logits

MODES = ("vanilla", "lsgan", "hinge")


def _check(mode: str) -> None:
    if mode not in MODES:
        raise ValueError(f"unknown GAN mode {mode!r}; choose one of {', '.join(MODES)}")


def d_loss(mode: str, real_out, fake_out) -> torch.Tensor:
    _check(mode)
    real, fake = _logits(real_out), _logits(fake_out)
    total = real[0].new_zeros(())
    for r, f in zip(real, fake):
        if mode == "vanilla":
            total = total + 0.5 * (F.softplus(-r).mean() + F.softplus(f).mean())
        elif mode == "lsgan":
            total = total + 0.5 * ((r - 1).pow(2).mean() + f.pow(2).mean())
        else:
            total = total + F.relu(1 - r).mean() + F.relu(1 + f).mean()
    return total / len(real)


def g_loss(mode: str, fake_out) -> torch.Tensor:
    _check(mode)
    fake = _logits(fake_out)
    total = fake[0].new_zeros(())
    for f in fake:
        if mode == "vanilla":
            total = total + F.softplus(-f).mean()
        elif mode == "lsgan":
            total = total + (f - 1).pow(2).mean()
        else:
            total = total - f.mean()
    return total / len(fake)
