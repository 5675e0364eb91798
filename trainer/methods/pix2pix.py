"""pix2pix (Isola et al. 2017) as the paper ran it as a baseline: a ResNet-9 generator (ngf 64, batch norm, dropout
0.5 in the residual blocks) from the masked sketch to RGB + gx, gy; the visual and the tactile output each judged by
a 70x70-style PatchGAN (C64-C128-C256-C512, batch norm) conditioned on the sketch; cross-entropy GAN + L1 x100;
Adam 2e-4, betas (0.5, 0.999). Trained on paired 32x32 patches (patch_baseline.py), run on the full image.
"""
from __future__ import annotations

from trainer.config import BaselineConfig
from trainer.methods.patch_baseline import PatchBaseline
from trainer.models.pix2pix_generator import ResnetGenerator


class Pix2Pix(PatchBaseline):
    name = "pix2pix"
    generator_class = "ResnetGenerator"
    gan_mode = "vanilla"
    l1_weight = 100.0
    d_layers = 3
    d_scales = 1
    d_norm = "batch"

    def make_generator(self, b: BaselineConfig) -> ResnetGenerator:
        return ResnetGenerator(ngf=b.ngf, n_blocks=b.resnet_blocks, norm="batch", dropout=0.5)
