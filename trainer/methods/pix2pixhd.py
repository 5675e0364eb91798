"""pix2pixHD (Wang et al. 2018) as a baseline, as the paper describes it: coarse-to-fine generator (global net +
local enhancer, instance norm), multi-scale PatchGANs (2 scales, 3 layers, ndf 64, instance norm) on the visual and
on the tactile output, least-squares GAN, feature matching x10 and perceptual loss x10 (pix2pixHD's lambda_feat for
both); Adam 2e-4, betas (0.5, 0.999). The perceptual term is this repository's (`losses/perceptual.py`: LPIPS-VGG
when its weights are configured, else the documented substitute; the run records which), on the visual patch and
on gx, gy as grey images, as ours uses it.
"""
from __future__ import annotations

from trainer.config import BaselineConfig
from trainer.methods.patch_baseline import PatchBaseline
from trainer.models.pix2pixhd_generator import Pix2PixHDGenerator


class Pix2PixHD(PatchBaseline):
    name = "pix2pixhd"
    generator_class = "Pix2PixHDGenerator"
    gan_mode = "lsgan"
    perceptual_weight = 10.0
    feature_matching_weight = 10.0
    d_layers = 3
    d_scales = 2
    d_norm = "instance"

    def make_generator(self, b: BaselineConfig) -> Pix2PixHDGenerator:
        return Pix2PixHDGenerator(ngf=b.hd_ngf, global_blocks=b.hd_global_blocks, local_blocks=b.hd_local_blocks)
