"""Ablation `ours-no-rec` (paper Table 2 / supplement): ours with no reconstruction terms (visual L1 + perceptual, tactile L1 + perceptual)."""
from __future__ import annotations

from trainer.methods.ours import Ours


class OursNoRec(Ours):
    name = "ours-no-rec"
    visual_rec = False
    tactile_rec = False
