"""Ablation `no-visual-rec` (paper Table 2 / supplement): ours with no visual L1 / perceptual loss."""
from __future__ import annotations

from trainer.methods.ours import Ours


class NoVisualRec(Ours):
    name = "no-visual-rec"
    visual_rec = False
