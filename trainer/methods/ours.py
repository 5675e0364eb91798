"""Ours (Gao, Yuan, Zhu, ICCV 2023): two-branch U-Net; visual D on (sketch, image) + CLIP-D; tactile patch D on
(gx, gy, sketch patch, visual patch, contact) with paired real, paired fake and unpaired fake patches.

Fixes of the published code's defects: the tactile GAN term trains the generator's tactile branch (the fake visual
patch is detached, so no gradient reaches the visual branch from it, as the paper says); feature matching is in
the generator loss; the CLIP head has its own optimizer. Ablations switch the four flags off.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from trainer.config import RunConfig
from trainer.distributed import Dist
from trainer.losses.clip_d import ClipD
from trainer.losses.feature_matching import feature_matching
from trainer.losses.gan import d_loss, d_loss_fake, g_loss, r1_penalty
from trainer.losses.perceptual import Perceptual, per_channel
from trainer.methods.base import Method
from trainer.models.discriminators import MultiScaleD
from trainer.models.generator import TwoBranchUNet
from trainer.recipe.diffaug import DiffAugment
from trainer.recipe.registration import best_shift_patches
from trainer.recipe.shading import shading_loss
from trainer.recipe.texture import TextureStatsLoss
from trainer.recipe.weave import weave_loss
from trainer.sampling import PATCH, Batch, cut


def masked_l1(a: torch.Tensor, b: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """Mean |a - b| over the pixels where m = 1 (all channels)."""
    return ((a - b).abs() * m).sum() / (m.sum() * a.shape[1]).clamp_min(1.0)


class Ours(Method):
    name = "ours"
    generator_class = "TwoBranchUNet"
    separable_visual = True
    visual_gan = True
    tactile_gan = True
    visual_rec = True
    tactile_rec = True

    def __init__(self, cfg: RunConfig, *, side: int, dist: Dist | None = None, device: str = "cpu"):
        super().__init__(cfg, side=side, dist=dist, device=device)
        m, o, lc = cfg.model, cfg.optim, cfg.loss
        self.generator = TwoBranchUNet(base=m.base, pe_dim=m.pe_dim, outer_skip=m.outer_skip,
                                       tactile_mult=m.tactile_mult,
                                       tactile_reads_visual=m.tactile_reads_visual,
                                       weave_waves=m.weave_waves,
                                       weave_waves_heads=m.weave_waves_heads).to(self.device)
        self.G = self._wrap_generator()
        betas = tuple(o.betas)
        self.opts["G"] = torch.optim.Adam(self.generator.parameters(), lr=o.lr, betas=betas)
        if self.visual_gan:
            self.nets["DI"] = MultiScaleD(in_ch=4, ndf=m.d_ndf, n_layers=m.d_layers, num_D=m.d_scales,
                                          norm=m.d_norm, min_input=side).to(self.device)
            self.opts["DI"] = torch.optim.Adam(self.nets["DI"].parameters(), lr=o.lr, betas=betas)
        if self.tactile_gan:
            self.nets["DT"] = MultiScaleD(in_ch=7, ndf=m.d_ndf, n_layers=m.d_layers, num_D=m.td_scales,
                                          norm=m.d_norm, min_input=PATCH).to(self.device)
            self.opts["DT"] = torch.optim.Adam(self.nets["DT"].parameters(), lr=o.lr_tactile_d, betas=betas)
        pre = cfg.pretrained
        self.perceptual = Perceptual(vgg16_path=pre.vgg16, lpips_lin_path=pre.lpips_lin).to(self.device)
        self.clip = ClipD(encoder_path=pre.clip_encoder if (self.visual_gan and lc.clip > 0) else None,
                          lr=o.lr, betas=betas, device=self.device)
        if self.clip.active:
            self.nets["CLIP"] = self.clip.net.head
            self.opts["CLIP"] = self.clip.opt
        # D inputs: visual = (sketch, RGB); tactile = (gx, gy, sketch, RGB, contact)
        self.aug_visual = DiffAugment(lc.diffaug, rgb=slice(1, 4), seed=cfg.train.seed)
        self.aug_tactile = DiffAugment(lc.diffaug, rgb=slice(3, 6), seed=cfg.train.seed + 1)
        self.texture = TextureStatsLoss().to(self.device) if lc.tactile_texture > 0 else None
        self.picks: list[np.ndarray] = []   # the shifts `touch_patches` picked this step (`loss.tactile_shift`)
        self._sync_nets()
        self.info = {"perceptual": self.perceptual.kind, "clip_d": "torchscript" if self.clip.active else "skipped",
                     "losses": {"visual_gan": self.visual_gan, "tactile_gan": self.tactile_gan,
                                "visual_rec": self.visual_rec, "tactile_rec": self.tactile_rec}}

    def touch_patches(self, batch: Batch, tactile_fake: torch.Tensor) -> torch.Tensor:
        """The generated relief where each paired touch patch was recorded, or at the best shift within
        `loss.tactile_shift` px of it (trainer/recipe/registration.py); the picks are kept for `pick_logs`."""
        k = self.cfg.loss.tactile_shift
        if not k:
            return cut(tactile_fake, batch.origins)
        patches, picked = best_shift_patches(tactile_fake, batch.origins, torch.cat([batch.gx, batch.gy], 1),
                                             batch.contact, k)
        self.picks.append(picked)
        return patches

    def pick_logs(self) -> dict[str, float]:
        """The shifts picked since the last call (every crop of a step): mean length, share at the recorded corner."""
        picked = np.concatenate(self.picks) if self.picks else np.zeros((0, 2), int)
        self.picks = []
        if not len(picked):
            return {}
        return {"t_shift_px": float(np.hypot(*picked.T).mean()), "t_shift_zero": float((picked == 0).all(1).mean())}

    # --- inputs of the discriminators ------------------------------------------------------------------------
    def tactile_inputs(self, batch: Batch, visual_fake: torch.Tensor, tactile_fake: torch.Tensor,
                       paired: torch.Tensor | None = None):
        """(real paired, fake paired, fake unpaired) 7-channel patches.

        The fake visual patch is detached (paper), the ground-truth crop (`loss.tactile_d_visual: real`), or no
        colour at all for real and fake alike (`none`: zeros in the RGB channels); the
        unpaired contact mask is the object's or a paired patch's (`loss.unpaired_contact`). Both choices decide
        whether D can separate fakes by something other than their tactile channels. `paired` is
        `touch_patches` of `tactile_fake` when the caller has it.
        """
        lc = self.cfg.loss
        c = batch.contact
        sk = cut(batch.sketch, batch.origins)
        shown = batch.visual if lc.tactile_d_visual == "real" else visual_fake.detach()
        real_visual = batch.visual
        if lc.tactile_d_visual == "none":   # D sees no colour: no reward for tactile that follows the print
            shown = real_visual = torch.zeros_like(batch.visual)
        real = torch.cat([batch.gx * c, batch.gy * c, sk, cut(real_visual, batch.origins), c], 1)
        if paired is None:
            paired = self.touch_patches(batch, tactile_fake)
        fake = torch.cat([paired * c, sk, cut(shown, batch.origins), c], 1)
        um = cut(batch.mask, batch.unpaired)
        if lc.unpaired_contact == "borrowed" and len(um):
            # paired patches are drawn at random, so taking them in order is a random, seeded pairing
            um = um * c[torch.arange(len(um)) % len(c)]
        unpaired = torch.cat([cut(tactile_fake, batch.unpaired) * um, cut(batch.sketch, batch.unpaired),
                              cut(shown, batch.unpaired), um], 1)
        return real, fake, unpaired

    def tactile_d(self, real: torch.Tensor, fake: torch.Tensor, unpaired: torch.Tensor):
        """DT's outputs on (real, fake, unpaired); None for an empty unpaired set. Paired real and fake patches get
        the same DiffAugment transform (feature matching compares them feature by feature)."""
        DT = self.nets["DT"]
        real, fake = self.aug_tactile(real, fake)
        (unpaired,) = self.aug_tactile(unpaired)
        return DT(real), DT(fake), (DT(unpaired) if len(unpaired) else None)

    def visual_d(self, batch: Batch, visual: torch.Tensor, visual_fake: torch.Tensor):
        """DI's outputs on (real, fake) images, both under the same DiffAugment transform."""
        DI = self.nets["DI"]
        real, fake = self.aug_visual(torch.cat([batch.sketch, visual], 1), torch.cat([batch.sketch, visual_fake], 1))
        return DI(real), DI(fake)

    def trains_visual(self, batch: Batch) -> bool:
        """False for a mirrored crop (either mirror) under `data.transpose_visual=false`, and for the mirrored twin
        of `data.mirror_extra`: they train the tactile side only."""
        d = self.cfg.data
        return not batch.mirrored or (d.transpose_visual and not d.mirror_extra)

    def tactile_gan_weight(self, step: int) -> float:
        """`loss.tactile_gan`, ramped linearly from 0 over the first `loss.tactile_gan_ramp` of the schedule."""
        lc = self.cfg.loss
        ramp = lc.tactile_gan_ramp * self.cfg.train.steps
        return lc.tactile_gan * (min(1.0, step / ramp) if ramp > 0 else 1.0)

    def generator_losses(self, batch: Batch, visual_fake: torch.Tensor, tactile_fake: torch.Tensor,
                         step: int = 0, *, gan: bool = True) -> dict[str, torch.Tensor]:
        """Each weighted term of the generator loss, separately (tests backpropagate them one by one); `gan=False`
        leaves out the tactile GAN and feature-matching terms (a twin under `data.twin_gan=false`)."""
        lc = self.cfg.loss
        out: dict[str, torch.Tensor] = {}
        visual_on = self.trains_visual(batch)
        if self.visual_rec and visual_on:
            out["v_l1"] = lc.visual_l1 * F.l1_loss(visual_fake, batch.visual)
            if lc.visual_weave:
                out["v_weave"] = lc.visual_weave * weave_loss(visual_fake, batch.visual, batch.mask)
            if lc.visual_perceptual:
                out["v_perc"] = lc.visual_perceptual * self.perceptual(visual_fake, batch.visual)
        if self.visual_gan and visual_on:
            real_o, fake_o = self.visual_d(batch, batch.visual, visual_fake)
            out["v_gan"] = lc.visual_gan * g_loss(fake_o)
            if lc.feature_matching:
                out["v_fm"] = lc.feature_matching * feature_matching(real_o, fake_o)
            if self.clip.active and step >= lc.clip_start * self.cfg.train.steps and lc.clip:
                out["v_clip"] = lc.clip * self.clip.g_loss(visual_fake)
        tp = self.touch_patches(batch, tactile_fake)
        gt = torch.cat([batch.gx, batch.gy], 1)
        if self.tactile_rec:
            out["t_l1"] = lc.tactile_l1 * masked_l1(tp, gt, batch.contact)
            if lc.tactile_perceptual:
                out["t_perc"] = lc.tactile_perceptual * per_channel(self.perceptual, tp * batch.contact,
                                                                     gt * batch.contact)
        if lc.tactile_shading and self.tactile_rec:
            out["t_shade"] = lc.tactile_shading * shading_loss(tactile_fake, batch.visual, batch.mask)
        if self.texture is not None:
            out["t_tex"] = lc.tactile_texture * self.texture(tp, gt, batch.contact)
        if self.tactile_gan and gan:
            real_o, fake_o, unpaired_o = self.tactile_d(*self.tactile_inputs(batch, visual_fake, tactile_fake, tp))
            adv = g_loss(fake_o)
            if unpaired_o is not None:
                adv = (adv + g_loss(unpaired_o)) / 2
            out["t_gan"] = self.tactile_gan_weight(step) * adv
            if lc.feature_matching:
                out["t_fm"] = lc.feature_matching * feature_matching(real_o, fake_o)
        return out

    def tactile_d_loss(self, batch: Batch, visual_fake: torch.Tensor, tactile_fake: torch.Tensor):
        """(DT's loss, its R1 penalty on the real patches; 0 when `loss.tactile_r1` is off) for one crop, on
        detached fakes."""
        real, fake, unpaired = self.tactile_inputs(batch, visual_fake, tactile_fake.detach())
        gamma = self.cfg.loss.tactile_r1
        if gamma > 0:
            real.requires_grad_(True)
        real_o, fake_o, unpaired_o = self.tactile_d(real, fake, unpaired)
        loss = d_loss(real_o, fake_o)
        if unpaired_o is not None:
            loss = loss + d_loss_fake(unpaired_o)
        r1 = r1_penalty(real_o, real) if gamma > 0 else loss.new_zeros(())
        return loss, r1

    def step(self, batch: Batch, step: int) -> dict[str, float]:
        logs: dict[str, float] = {}
        # one augmentation stream per step, so a resumed run augments exactly as an uninterrupted one
        self.aug_visual.reseed(self.cfg.train.seed * 1_000_003 + 2 * step)
        self.aug_tactile.reseed(self.cfg.train.seed * 1_000_003 + 2 * step + 1)
        twin = batch.twin
        # the weave waves' coordinates travel with a mirrored crop's pixels (trainer/recipe/mirror.py)
        waves = self.cfg.model.weave_waves > 0
        if twin is None:
            more = {"coords": batch.wave_coords()} if waves else {}
            visual_fake, tactile_fake = self.G(batch.sketch, batch.mask, **more)
        else:   # one pass over both crops (G's norms are per image), so a distributed G sees one forward
            more = {"coords": torch.cat([batch.wave_coords(), twin.wave_coords()])} if waves else {}
            v2, t2 = self.G(torch.cat([batch.sketch, twin.sketch]), torch.cat([batch.mask, twin.mask]), **more)
            (visual_fake, twin_visual), (tactile_fake, twin_tactile) = v2.split(1), t2.split(1)
        # Discriminators first, on detached fakes.
        if self.visual_gan and self.trains_visual(batch):
            DI = self.nets["DI"]
            self.opts["DI"].zero_grad(set_to_none=True)
            loss = d_loss(*self.visual_d(batch, batch.visual, visual_fake.detach()))
            loss.backward()
            self._reduce(DI)
            self.opts["DI"].step()
            logs["d_visual"] = loss.item()
            if self.clip.active and step >= self.cfg.loss.clip_start * self.cfg.train.steps:
                logs["d_clip"] = self.clip.d_step(batch.visual, visual_fake, reduce=self._reduce)
        if self.tactile_gan:
            DT = self.nets["DT"]
            self.opts["DT"].zero_grad(set_to_none=True)
            loss, r1 = self.tactile_d_loss(batch, visual_fake, tactile_fake)
            if twin is not None and self.cfg.data.twin_gan:
                twin_loss, twin_r1 = self.tactile_d_loss(twin, twin_visual, twin_tactile)
                loss, r1 = (loss + twin_loss) / 2, (r1 + twin_r1) / 2
            logs["d_tactile"] = loss.item()
            gamma = self.cfg.loss.tactile_r1
            if gamma > 0:
                logs["d_tactile_r1"] = r1.item()
                loss = loss + gamma / 2 * r1
            loss.backward()
            self._reduce(DT)
            self.opts["DT"].step()
        # Generator.
        for net in self.nets.values():
            self._requires_grad(net, False)
        self.opts["G"].zero_grad(set_to_none=True)
        terms = self.generator_losses(batch, visual_fake, tactile_fake, step)
        if twin is not None:   # the twin adds tactile terms only; each is the mean over the two crops
            for k, v in self.generator_losses(twin, twin_visual, twin_tactile, step,
                                              gan=self.cfg.data.twin_gan).items():
                terms[k] = (terms[k] + v) / 2
        total = sum(terms.values())
        total.backward()
        self.opts["G"].step()
        for net in self.nets.values():
            self._requires_grad(net, True)
        logs.update({k: v.item() for k, v in terms.items()})
        logs["g_total"] = total.item()
        logs.update(self.pick_logs())
        return logs
