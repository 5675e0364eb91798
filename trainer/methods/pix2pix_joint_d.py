"""pix2pix with one joint discriminator: the earlier stand-in for the paper's pix2pix baseline, kept under a name
that says how it differs, so runs made with it stay reproducible (`pix2pix` is now the paper's setting).

A ResNet generator from the 1-channel masked sketch to 5 channels (RGB + gx, gy), trained on paired 32x32 patches
with L1 x100 and ONE conditional PatchGAN on all 6 channels (sketch + RGB + gx, gy), at this repository's D width
(`model.d_ndf`, 8) and `model.resnet_ngf`; instance norm, no dropout. The paper's baselines feed the visual and the
tactile output to two discriminators of pix2pix's own width (64).
"""
from __future__ import annotations

import torch

from trainer.config import RunConfig
from trainer.distributed import Dist
from trainer.losses.gan import d_loss, g_loss
from trainer.methods.base import Method
from trainer.methods.ours import masked_l1
from trainer.models.discriminators import MultiScaleD
from trainer.models.pix2pix_generator import ResnetGenerator
from trainer.sampling import PATCH, Batch, cut

L1_WEIGHT = 100.0  # pix2pix default lambda_L1


class Pix2PixJointD(Method):
    name = "pix2pix-joint-d"
    generator_class = "ResnetGenerator"

    def __init__(self, cfg: RunConfig, *, side: int, dist: Dist | None = None, device: str = "cpu"):
        super().__init__(cfg, side=side, dist=dist, device=device)
        m, o = cfg.model, cfg.optim
        self.generator = ResnetGenerator(ngf=m.resnet_ngf, n_blocks=m.resnet_blocks).to(self.device)
        self.G = self._wrap_generator()
        # pix2pix defaults: Adam lr 2e-4, betas (0.5, 0.999)
        self.opts["G"] = torch.optim.Adam(self.generator.parameters(), lr=2e-4, betas=(0.5, 0.999))
        self.nets["D"] = MultiScaleD(in_ch=6, ndf=m.d_ndf, n_layers=m.d_layers, num_D=1, norm=m.d_norm,
                                     min_input=PATCH).to(self.device)
        self.opts["D"] = torch.optim.Adam(self.nets["D"].parameters(), lr=2e-4, betas=(0.5, 0.999))
        self._sync_nets()
        self.info = {"perceptual": "none (pix2pix: L1 + cGAN)", "clip_d": "not used"}

    def patches(self, batch: Batch):
        sk = cut(batch.sketch, batch.origins)
        mk = cut(batch.mask, batch.origins)
        target = torch.cat([cut(batch.visual, batch.origins), batch.gx * batch.contact, batch.gy * batch.contact], 1)
        return sk, mk, target

    def step(self, batch: Batch, step: int) -> dict[str, float]:
        sk, mk, target = self.patches(batch)
        vis, tac = self.G(sk, mk)
        fake = torch.cat([vis, tac * batch.contact], 1)
        D = self.nets["D"]
        self.opts["D"].zero_grad(set_to_none=True)
        ld = d_loss(D(torch.cat([sk, target], 1)), D(torch.cat([sk, fake.detach()], 1)))
        ld.backward()
        self._reduce(D)
        self.opts["D"].step()
        self._requires_grad(D, False)
        self.opts["G"].zero_grad(set_to_none=True)
        lg = g_loss(D(torch.cat([sk, fake], 1)))
        l1 = L1_WEIGHT * (masked_l1(vis, target[:, :3], mk) + masked_l1(tac, target[:, 3:], batch.contact))
        (lg + l1).backward()
        self.opts["G"].step()
        self._requires_grad(D, True)
        return {"d": ld.item(), "g_total": (lg + l1).item(), "g_gan": lg.item(), "l1": l1.item()}
