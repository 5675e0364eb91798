"""GauGAN (Park et al. 2019) as a baseline: the SPADE generator conditioned on the masked sketch (no encoder),
multi-scale PatchGANs (2 scales, ndf 64, spectral norm + instance norm; GauGAN's 4 layers, fewer where a 32 px patch
is too small: `layers_for`) on the visual and on the tactile output; hinge GAN, feature matching x10 and perceptual
x10, the same losses as pix2pixHD (paper, Sec. 5); Adam with GauGAN's two time-scale rates (G 1e-4, D 4e-4) and
betas (0, 0.9).
"""
from __future__ import annotations

from trainer.config import BaselineConfig
from trainer.methods.patch_baseline import PatchBaseline
from trainer.models.spade_generator import SpadeGenerator


class GauGAN(PatchBaseline):
    name = "gaugan"
    generator_class = "SpadeGenerator"
    gan_mode = "hinge"
    perceptual_weight = 10.0
    feature_matching_weight = 10.0
    d_layers = 4
    d_scales = 2
    d_norm = "instance"
    d_spectral = True
    lr_g = 1e-4
    lr_d = 4e-4
    betas = (0.0, 0.9)

    def make_generator(self, b: BaselineConfig) -> SpadeGenerator:
        return SpadeGenerator(ngf=b.ngf, hidden=b.spade_hidden)
