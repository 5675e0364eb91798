"""Ablation `no-tactile-gan` (paper Table 2 / supplement): ours with no tactile patch discriminator (nor its feature matching)."""
from __future__ import annotations

from trainer.methods.ours import Ours


class NoTactileGAN(Ours):
    name = "no-tactile-gan"
    tactile_gan = False
