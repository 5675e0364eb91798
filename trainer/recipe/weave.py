"""Weave-scale visual loss (`loss.visual_weave`): the generated photo's fine shading bands matched to the real one's.

Why: the shading relief (trainer/models/shading_relief.py) reads the weave back from the visual output's fine
log-luminance bands, so its ceiling is how faithfully the visual head paints them. An RGB L1 barely sees them (a few
percent of contrast under the colour and the lamp's falloff) and rewards their blurred average; this term compares
exactly the bands the relief reads, in log-luminance (contrast, not brightness), on the object only.
"""
from __future__ import annotations

import torch

from trainer.models.shading_relief import BANDS, dog_bands, log_luma


def fine_bands(visual: torch.Tensor) -> torch.Tensor:
    """(N, len(BANDS), H, W): differences of Gaussians of the image's log-luminance, one channel a band."""
    return dog_bands(log_luma(visual))[:, 0]


def weave_loss(fake: torch.Tensor, real: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean |bands(fake) - bands(real)| over the object's pixels (0 for an empty mask, never a division by 0)."""
    m = (mask > 0.5).to(fake.dtype)
    diff = (fine_bands(fake) - fine_bands(real)).abs() * m
    return diff.sum() / (m.sum() * len(BANDS)).clamp_min(1.0)
