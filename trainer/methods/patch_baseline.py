"""What the paper's three baselines share (Sec. 5, "Baselines"): a single generator from the masked sketch to 5
channels (RGB + gx, gy), trained on paired 32x32 sketch-visual-tactile patches cut from the same crop and touches as
ours, the visual and the tactile output each judged by its own multi-scale PatchGAN conditioned on the sketch patch,
and run on the full image at test time (a fully convolutional net). Subclasses choose the generator, the GAN
objective and the other loss weights, each at its original paper's defaults.
"""
from __future__ import annotations

from abc import abstractmethod
from dataclasses import asdict

import torch
from torch import nn
from torch.nn.utils.parametrizations import spectral_norm

from trainer.config import BaselineConfig, RunConfig
from trainer.distributed import Dist
from trainer.losses.feature_matching import feature_matching
from trainer.losses.gan_modes import d_loss, g_loss
from trainer.losses.perceptual import Perceptual, per_channel
from trainer.methods.base import Method
from trainer.methods.ours import masked_l1
from trainer.models.discriminators import MultiScaleD
from trainer.sampling import PATCH, Batch, cut


def add_spectral_norm(net: nn.Module) -> nn.Module:
    """Spectral norm on every convolution of `net`, in place (GauGAN's `spectral` D norms)."""
    for m in list(net.modules()):
        if isinstance(m, nn.Conv2d):
            spectral_norm(m)
    return net


class PatchBaseline(Method):
    gan_mode = "vanilla"
    l1_weight = 0.0
    perceptual_weight = 0.0
    feature_matching_weight = 0.0
    d_layers = 3
    d_scales = 1
    d_norm = "batch"
    d_spectral = False
    lr_g = 2e-4
    lr_d = 2e-4
    betas = (0.5, 0.999)

    @abstractmethod
    def make_generator(self, b: BaselineConfig) -> nn.Module:
        """The generator at the widths in `cfg.baseline`."""

    def __init__(self, cfg: RunConfig, *, side: int, dist: Dist | None = None, device: str = "cpu"):
        super().__init__(cfg, side=side, dist=dist, device=device)
        b = cfg.baseline
        self.generator = self.make_generator(b).to(self.device)
        self.G = self._wrap_generator()
        self.opts["G"] = torch.optim.Adam(self.generator.parameters(), lr=self.lr_g, betas=self.betas)
        # DV judges (sketch, RGB) patches, DT (sketch, gx, gy) patches
        for key, in_ch in (("DV", 4), ("DT", 3)):
            d = MultiScaleD(in_ch=in_ch, ndf=b.ndf, n_layers=self.d_layers, num_D=self.d_scales, norm=self.d_norm,
                            min_input=PATCH)
            if self.d_spectral:
                add_spectral_norm(d)
            self.nets[key] = d.to(self.device)
            self.opts[key] = torch.optim.Adam(d.parameters(), lr=self.lr_d, betas=self.betas)
        pre = cfg.pretrained
        self.perceptual = (Perceptual(vgg16_path=pre.vgg16, lpips_lin_path=pre.lpips_lin).to(self.device)
                           if self.perceptual_weight else None)
        self._sync_nets()
        widths = "paper" if asdict(b) == asdict(BaselineConfig()) else "reduced (not the paper's widths)"
        self.info = {"perceptual": self.perceptual.kind if self.perceptual is not None else "none",
                     "clip_d": "not used", "gan": self.gan_mode, "baseline_widths": widths,
                     "baseline_config": asdict(b)}

    def patches(self, batch: Batch):
        """Sketch and mask patches, and the 5-channel target (RGB, then gx, gy under the contact mask)."""
        sk = cut(batch.sketch, batch.origins)
        mk = cut(batch.mask, batch.origins)
        target = torch.cat([cut(batch.visual, batch.origins), batch.gx * batch.contact, batch.gy * batch.contact], 1)
        return sk, mk, target

    def _pairs(self, sk: torch.Tensor, real: torch.Tensor, fake: torch.Tensor):
        return (("DV", torch.cat([sk, real[:, :3]], 1), torch.cat([sk, fake[:, :3]], 1)),
                ("DT", torch.cat([sk, real[:, 3:]], 1), torch.cat([sk, fake[:, 3:]], 1)))

    def step(self, batch: Batch, step: int) -> dict[str, float]:
        sk, mk, target = self.patches(batch)
        vis, tac = self.G(sk, mk)
        fake = torch.cat([vis, tac * batch.contact], 1)
        logs: dict[str, float] = {}
        for key, real_in, fake_in in self._pairs(sk, target, fake.detach()):
            D = self.nets[key]
            self.opts[key].zero_grad(set_to_none=True)
            ld = d_loss(self.gan_mode, D(real_in), D(fake_in))
            ld.backward()
            self._reduce(D)
            self.opts[key].step()
            logs[f"d_{'visual' if key == 'DV' else 'tactile'}"] = ld.item()
        for net in self.nets.values():
            self._requires_grad(net, False)
        self.opts["G"].zero_grad(set_to_none=True)
        terms = self.generator_losses(sk, mk, target, fake, batch.contact)
        total = sum(terms.values())
        total.backward()
        self.opts["G"].step()
        for net in self.nets.values():
            self._requires_grad(net, True)
        logs.update({k: v.item() for k, v in terms.items()})
        logs["g_total"] = total.item()
        return logs

    def generator_losses(self, sk: torch.Tensor, mk: torch.Tensor, target: torch.Tensor, fake: torch.Tensor,
                         contact: torch.Tensor) -> dict[str, torch.Tensor]:
        """Each weighted term of the generator loss (visual terms on the object, tactile ones on the contact)."""
        out: dict[str, torch.Tensor] = {}
        for key, real_in, fake_in in self._pairs(sk, target, fake):
            tag = "v" if key == "DV" else "t"
            D = self.nets[key]
            fake_o = D(fake_in)
            out[f"{tag}_gan"] = g_loss(self.gan_mode, fake_o)
            if self.feature_matching_weight:
                out[f"{tag}_fm"] = self.feature_matching_weight * feature_matching(D(real_in), fake_o)
        if self.l1_weight:
            out["v_l1"] = self.l1_weight * masked_l1(fake[:, :3], target[:, :3], mk)
            out["t_l1"] = self.l1_weight * masked_l1(fake[:, 3:], target[:, 3:], contact)
        if self.perceptual is not None:
            out["v_perc"] = self.perceptual_weight * self.perceptual(fake[:, :3], target[:, :3])
            out["t_perc"] = self.perceptual_weight * per_channel(self.perceptual, fake[:, 3:], target[:, 3:])
        return out
