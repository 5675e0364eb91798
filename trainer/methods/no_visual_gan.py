"""Ablation `no-visual-gan` (paper Table 2 / supplement): ours with no visual adversarial terms (visual D, CLIP-D and their feature matching)."""
from __future__ import annotations

from trainer.methods.ours import Ours


class NoVisualGAN(Ours):
    name = "no-visual-gan"
    visual_gan = False
