"""Ablation `ours-no-gan` (paper Table 2 / supplement): ours with no adversarial terms (visual GAN, CLIP-D, feature matching, tactile GAN)."""
from __future__ import annotations

from trainer.methods.ours import Ours


class OursNoGAN(Ours):
    name = "ours-no-gan"
    visual_gan = False
    tactile_gan = False
