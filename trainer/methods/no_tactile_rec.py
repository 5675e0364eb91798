"""Ablation `no-tactile-rec` (paper Table 2 / supplement): ours with no tactile L1 / perceptual loss on paired patches."""
from __future__ import annotations

from trainer.methods.ours import Ours


class NoTactileRec(Ours):
    name = "no-tactile-rec"
    tactile_rec = False
