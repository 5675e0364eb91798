"""Non-saturating GAN loss on multi-scale discriminator outputs (lists of feature lists; last entry = logits)."""
from __future__ import annotations

import torch
import torch.nn.functional as F


def _logits(outputs) -> list[torch.Tensor]:
    if isinstance(outputs, torch.Tensor):
        return [outputs]
    return [o[-1] if isinstance(o, (list, tuple)) else o for o in outputs]


def d_loss(real_out, fake_out) -> torch.Tensor:
    """softplus(-D(real)) + softplus(D(fake)), averaged over scales: the discriminator's side."""
    real, fake = _logits(real_out), _logits(fake_out)
    return sum(F.softplus(-r).mean() + F.softplus(f).mean() for r, f in zip(real, fake)) / len(real)


def d_loss_fake(fake_out) -> torch.Tensor:
    """The fake term alone (unpaired fake patches have no real counterpart)."""
    fake = _logits(fake_out)
    return sum(F.softplus(f).mean() for f in fake) / len(fake)


def g_loss(fake_out) -> torch.Tensor:
    """softplus(-D(G(x))): the generator's non-saturating loss."""
    fake = _logits(fake_out)
    return sum(F.softplus(-f).mean() for f in fake) / len(fake)


def r1_penalty(real_out, real_in: torch.Tensor) -> torch.Tensor:
    """R1 (Mescheder et al. 2018): mean squared norm of dD(real)/d(real input), summed over scales' logits.

    Keeps the discriminator's surface flat on the data, so it cannot win by a steep wall the generator's
    gradient then climbs (the tactile D's failure on this data: docs/training.md). `real_in` must require grad.
    """
    logits = _logits(real_out)
    total = sum(r.sum() for r in logits)
    (grad,) = torch.autograd.grad(total, real_in, create_graph=True)
    return grad.pow(2).flatten(1).sum(1).mean()
