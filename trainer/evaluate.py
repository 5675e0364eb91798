"""Evaluate one run: visual reconstruction, held-out tactile patches, full-field tactile (synthetic ground truth),
pretrained-feature metrics when their weights are configured, and the unseen-sketch swap grid."""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import torch

from trainer.augment import CropError, eval_crop_origin, resolve_crop
from trainer.checkpoint import CheckpointError, load_generator, read_checkpoint
from trainer.config import config_from_dict
from trainer.data.touchclothing import Garment, extract_patches, find_garments, load_garment
from trainer.metrics import full_field_metrics, l1, psnr, ssim, tactile_patch_metrics
from trainer.sampling import crop_tensors, cut, patches_to_tensors
from trainer.sheets import grid, label, normal_tile, friction_tile, save_png, to_uint8
from trainer.texture_distance import fb_sifid_channels

log = logging.getLogger(__name__)

HIGHER_IS_BETTER = {"visual_psnr", "visual_ssim"}


class Prediction:
    """A run's outputs on its garment's evaluation crop, plus what is needed to score and picture them."""

    def __init__(self, run_dir: Path, which: str = "best"):
        self.run = Path(run_dir)
        self.net, self.info = load_generator(self.run, which)
        ck = read_checkpoint(self.run, which)
        self.cfg = config_from_dict(ck["config"])
        garment_dir = Path(self.cfg.garment)
        if not garment_dir.is_dir():
            raise CheckpointError(f"{self.run}: its garment folder {garment_dir} is gone; cannot evaluate")
        self.g: Garment = load_garment(garment_dir)
        self.side = int(self.info["crop"])
        self.origin = eval_crop_origin(self.g.mask, self.side)
        self.sketch, self.mask, self.visual = crop_tensors(self.g, self.origin, self.side)
        with torch.no_grad():
            self.vis, self.tac = self.net(self.sketch, self.mask)

    def crop(self, a: np.ndarray) -> np.ndarray:
        x, y = self.origin
        return a[y:y + self.side, x:x + self.side]


def evaluate_run(run_dir: Path, which: str = "best", *, swap: bool = True) -> dict:
    p = Prediction(run_dir, which)
    out: dict = {"method": p.info["method"], "garment": p.g.name, "step": p.info["step"], "crop": p.side,
                 "checkpoint": which, "perceptual": (p.info.get("info") or {}).get("perceptual")}
    out["visual_psnr"] = psnr(p.vis, p.visual)
    out["visual_ssim"] = ssim(p.vis, p.visual)
    out["visual_l1"] = l1(p.vis, p.visual)
    ps = extract_patches(p.g, "test", crop_origin=p.origin, crop_size=(p.side, p.side), mode="centre")
    patches = None
    if len(ps):
        gx, gy, c = patches_to_tensors(ps, np.arange(len(ps)))
        patches = (cut(p.tac, ps.origin), torch.cat([gx, gy], 1), c)
        tm = tactile_patch_metrics(patches[0], gx, gy, c)
        out.update(tactile_mse=tm["tactile_mse"], tactile_angle_deg=tm["tactile_angle_deg"], test_patches=len(ps))
    ft = p.g.full_tactile
    if ft is not None:
        out.update(full_field_metrics(p.tac[0, 0].numpy(), p.tac[0, 1].numpy(), p.crop(ft.gx), p.crop(ft.gy),
                                      p.crop(p.g.mask), float(p.info["friction_scale"])))
    pre = p.cfg.pretrained
    if pre.vgg16 and Path(pre.vgg16).is_file():
        from trainer.losses.perceptual import Perceptual, per_channel
        lp = Perceptual(vgg16_path=pre.vgg16, lpips_lin_path=pre.lpips_lin)
        with torch.no_grad():
            out["visual_lpips"] = float(lp(p.vis, p.visual))
            if len(ps):
                out["tactile_lpips"] = float(per_channel(lp, patches[0] * c, patches[1] * c, size=224))
        out["lpips_backbone"] = lp.kind
    else:
        log.info("eval: no VGG16 weights configured; LPIPS not computed")
    if pre.inception and Path(pre.inception).is_file():
        from trainer.models.inception import InceptionBlock1, sifid, sifid_channels
        net = InceptionBlock1.from_file(pre.inception)
        out["visual_sifid"] = sifid(net, p.vis, p.visual)
        if len(ps):
            out["tactile_sifid"] = sifid_channels(net, patches[0] * c, patches[1] * c)
    else:
        log.info("eval: no InceptionV3 weights configured; SIFID not computed (FB-SIFID, weight-free, is reported)")
    out.update(texture_metrics(p, patches))
    if swap:
        path = swap_grid(p)
        if path is not None:
            out["swap_grid"] = str(path)
    return out


def texture_metrics(p: Prediction, patches: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None) -> dict:
    """FB-SIFID (trainer.texture_distance), always: visual per RGB channel over the object, tactile per channel on
    each held-out patch's contact pixels (`patches` = predicted, true (K, 2, 32, 32) and contact (K, 1, 32, 32)),
    and over the whole object against the synthetic full-field ground truth."""
    mask = p.crop(p.g.mask).astype(bool)
    out = {"visual_fbsifid": fb_sifid_channels(p.vis[0].numpy(), p.visual[0].numpy(), mask)}
    if patches is not None:
        fake, real, contact = (t.numpy() for t in patches)
        cm = contact[:, 0] > 0.5
        vals = [fb_sifid_channels(fake[k] * cm[k], real[k] * cm[k], cm[k]) for k in range(len(fake))]
        vals = [v for v in vals if np.isfinite(v)]
        if vals:
            out["tactile_fbsifid"] = float(np.mean(vals))
    ft = p.g.full_tactile
    if ft is not None:
        truth = np.stack([p.crop(ft.gx), p.crop(ft.gy)])
        out["full_fbsifid"] = fb_sifid_channels(p.tac[0].numpy(), truth, mask)
    return out


def swap_grid(p: Prediction) -> Path | None:
    """The paper's swap experiment: this garment's model on every other garment's sketch in the same dataset."""
    try:
        others = [d for d in find_garments(Path(p.cfg.garment).parent) if d.resolve() != p.g.root.resolve()]
    except Exception:  # noqa: BLE001 - a garment folder given directly has no siblings
        others = []
    rows = []
    for d in others:
        g = load_garment(d, tactile=False)
        try:
            side = resolve_crop(p.side, g.mask, fit=False)
        except CropError:
            continue
        origin = eval_crop_origin(g.mask, side)
        sk, mk, _ = crop_tensors(g, origin, side, visual=np.zeros(g.mask.shape + (3,), np.uint8))
        with torch.no_grad():
            vis, tac = p.net(sk, mk)
        gx, gy = tac[0, 0].numpy(), tac[0, 1].numpy()
        rows.append([label(to_uint8(sk[0, 0].numpy()), g.material), label(to_uint8(vis[0].permute(1, 2, 0).numpy()),
                                                                          "visual"),
                     label(normal_tile(gx, gy), "normal map"), label(friction_tile(gx, gy, float(
                         p.info["friction_scale"])), "friction map")])
    if not rows:
        return None
    path = p.run / "eval" / "swap.png"
    save_png(path, grid(rows))
    return path


def write_eval(run_dir: Path, result: dict, json_out: Path | None = None) -> None:
    run_dir = Path(run_dir)
    (run_dir / "eval").mkdir(parents=True, exist_ok=True)
    (run_dir / "eval" / "metrics.json").write_text(json.dumps(result, indent=2))
    mpath = run_dir / "metrics.json"
    merged = json.loads(mpath.read_text()) if mpath.is_file() else {}
    merged["eval"] = result
    mpath.write_text(json.dumps(merged, indent=2))
    if json_out is not None:
        Path(json_out).parent.mkdir(parents=True, exist_ok=True)
        Path(json_out).write_text(json.dumps(result, indent=2))
