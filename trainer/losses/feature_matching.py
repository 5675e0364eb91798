"""pix2pixHD feature matching: L1 between the discriminator's intermediate features on real and fake inputs.

The published code computed this term but never added it (a known defect); here it is part of the generator loss.
Real features are detached: the term trains the generator only.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F


def feature_matching(real_out: list[list[torch.Tensor]], fake_out: list[list[torch.Tensor]]) -> torch.Tensor:
    """Mean over scales of sum over intermediate layers (all but the logits) of L1, weighted 4 / (n_layers + 1)."""
    assert len(real_out) == len(fake_out), "real and fake must come from the same multi-scale D"
    total = fake_out[0][0].new_zeros(())
    for real, fake in zip(real_out, fake_out):
        w = 4.0 / len(real)
        for r, f in zip(real[:-1], fake[:-1]):
            total = total + w * F.l1_loss(f, r.detach())
    return total / len(real_out)
