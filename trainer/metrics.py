"""Evaluation metrics (the definitions of the authors' published code), on numpy arrays or tensors in [-1, 1].

Visual: PSNR, SSIM, L1 inside the object mask (the background is not the model's work); LPIPS when VGG weights are
configured. Tactile (paired 32x32 patches, contact pixels): MSE and the angular error in degrees between
normalize(gx, gy, 1) vectors. Full field (synthetic garments): the same angular error over the object and the
friction-map MAE (0..255 levels) with the run's calibrated friction scale, also split into the pixels inside and
outside the training touch rectangles. Each additive score is also returned as per-unit sums
(`trainer.bootstrap.Units`: 32 x 32 blocks of the padded frame) so that method differences can be bootstrapped.
SIFID uses the first block of InceptionV3 (trainer.models.inception); its weight-free fallback FB-SIFID lives in
trainer.texture_distance.
"""
from __future__ import annotations

import cv2
import numpy as np
import torch

from kiosk.contract.haptics import friction_map
from trainer.bootstrap import Units, mse_to_psnr, value

BLOCK = 32   # pixel-block side of the bootstrap units (the tactile patch size)
SSIM_WINDOW = 11


def _np(t) -> np.ndarray:
    return np.asarray(t.detach().cpu() if isinstance(t, torch.Tensor) else t, dtype=np.float64)


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR (dB) of images in [-1, 1], computed on [0, 1], over every pixel."""
    mse = float((((a + 1) / 2 - (b + 1) / 2) ** 2).mean())
    return float(mse_to_psnr(mse))


def l1(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().mean())


def angle_map(gx1, gy1, gx2, gy2) -> np.ndarray:
    """Per-pixel angle (degrees) between (gx1, gy1, 1) and (gx2, gy2, 1)."""
    gx1, gy1, gx2, gy2 = (_np(t) for t in (gx1, gy1, gx2, gy2))
    # both norms are >= 1 (the third component is 1): no division by zero
    cos = (gx1 * gx2 + gy1 * gy2 + 1.0) / (np.sqrt(gx1 * gx1 + gy1 * gy1 + 1.0) * np.sqrt(gx2 * gx2 + gy2 * gy2 + 1.0))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def angular_error_deg(gx1, gy1, gx2, gy2, mask=None) -> float:
    """Mean angle (degrees) between (gx1, gy1, 1) and (gx2, gy2, 1), over `mask` (all pixels when None)."""
    ang = angle_map(gx1, gy1, gx2, gy2)
    if mask is not None:
        m = np.broadcast_to(_np(mask).astype(bool), ang.shape)
        return float(ang[m].mean()) if m.any() else float("nan")
    return float(ang.mean())


def masked_mse(a: torch.Tensor, b: torch.Tensor, m: torch.Tensor) -> float:
    mm = m.expand_as(a)
    return float((((a - b) ** 2) * mm).sum() / mm.sum().clamp_min(1.0))


def tactile_patch_metrics(fake: torch.Tensor, gx: torch.Tensor, gy: torch.Tensor, contact: torch.Tensor) -> dict:
    """fake (K, 2, 32, 32) vs ground truth (K, 1, 32, 32) each, over contact pixels."""
    gt = torch.cat([gx, gy], 1)
    return {"tactile_mse": masked_mse(fake, gt, contact),
            "tactile_angle_deg": angular_error_deg(fake[:, 0], fake[:, 1], gx[:, 0], gy[:, 0], contact[:, 0] > 0.5)}


def block_units(values: np.ndarray, weight: np.ndarray, origin: tuple[int, int], block: int = BLOCK) -> Units:
    """Sums of values x weight and of weight per `block` x `block` cell of the padded frame.

    Shape: values, weight (H, W) of a crop whose top-left is `origin` (x, y) in the padded frame. Cells are fixed in
    the padded frame, so crops of different sizes (methods with other crop sides) share unit keys.
    """
    values, weight = np.asarray(values, np.float64), np.asarray(weight, np.float64)
    assert values.shape == weight.shape and values.ndim == 2, \
        f"values and weight must be equal (H, W); got {values.shape}, {weight.shape}"
    h, w = values.shape
    ys, xs = np.mgrid[0:h, 0:w]
    cell = ((ys + origin[1]) // block) * 100_000 + (xs + origin[0]) // block
    keys, inv = np.unique(cell.ravel(), return_inverse=True)
    num = np.bincount(inv, weights=(values * weight).ravel(), minlength=len(keys))
    den = np.bincount(inv, weights=weight.ravel(), minlength=len(keys))
    return Units(keys, num, den)


def _gauss1d(window: int, sigma: float) -> np.ndarray:
    x = np.arange(window, dtype=np.float64) - (window - 1) / 2
    g = np.exp(-(x ** 2) / (2 * sigma ** 2))
    return g / g.sum()


def ssim_map(a: np.ndarray, b: np.ndarray, *, data_range: float = 1.0, window: int = SSIM_WINDOW) -> np.ndarray:
    """SSIM map (Wang et al. 2004, Gaussian window 11, sigma 1.5), mean over channels, same size as the input
    (each pixel's window is centred on it; zero padding at the crop border, where the object never is).

    Shape: a, b (C, H, W) -> (H, W).
    """
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    window = min(window, a.shape[-2], a.shape[-1])
    window -= 1 - window % 2   # odd, so the window is centred
    k = _gauss1d(window, 1.5 * window / SSIM_WINDOW)

    def blur(t):
        return cv2.sepFilter2D(t, cv2.CV_64F, k, k, borderType=cv2.BORDER_CONSTANT)

    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    out = np.zeros(a.shape[1:])
    for x, y in zip(a, b):
        mu_x, mu_y = blur(x), blur(y)
        sxx = blur(x * x) - mu_x ** 2
        syy = blur(y * y) - mu_y ** 2
        sxy = blur(x * y) - mu_x * mu_y
        out += ((2 * mu_x * mu_y + c1) * (2 * sxy + c2)) / ((mu_x ** 2 + mu_y ** 2 + c1) * (sxx + syy + c2))
    return out / a.shape[0]


def visual_scores(fake: np.ndarray, real: np.ndarray, mask: np.ndarray,
                  origin: tuple[int, int]) -> tuple[dict, dict[str, Units]]:
    """PSNR, SSIM and L1 over the object mask only. fake, real (3, H, W) in [-1, 1]; mask (H, W) bool."""
    fake, real = np.asarray(fake, np.float64), np.asarray(real, np.float64)
    m = np.asarray(mask, bool).astype(np.float64)
    a, b = (fake + 1) / 2, (real + 1) / 2
    units = {"visual_psnr": block_units(((a - b) ** 2).sum(0), 3 * m, origin),   # num / den = per-value MSE
             "visual_ssim": block_units(ssim_map(a, b), m, origin),
             "visual_l1": block_units(np.abs(fake - real).sum(0), 3 * m, origin)}
    for k in units:   # num was summed with the weight; undo the factor 3 the den carries
        if k != "visual_ssim":
            units[k].num /= 3.0
    return {k: value(k, u) for k, u in units.items()}, units


def full_field_scores(gx_fake: np.ndarray, gy_fake: np.ndarray, gx_true: np.ndarray, gy_true: np.ndarray,
                      mask: np.ndarray, inside: np.ndarray, scale: float,
                      origin: tuple[int, int], lines: np.ndarray | None = None) -> tuple[dict, dict[str, Units]]:
    """Angular error and friction-map MAE over the object, and over its parts inside / outside the training touch
    rectangles (`inside`, (H, W) bool; outside is where the model had no tactile example: generalisation). With
    `lines` ((H, W) bool, near the sketch's strokes) the outside angle is split again: `_outside_lines`, relief the
    sketch draws (seams, edges, pockets), and `_outside_open`, open cloth, where only the weave is left to get
    right and the sketch says nothing about where its ridges sit."""
    ang = angle_map(gx_fake, gy_fake, gx_true, gy_true)
    f1 = friction_map(gx_fake, gy_fake, scale).astype(np.float64)
    f2 = friction_map(gx_true, gy_true, scale).astype(np.float64)
    fr = np.abs(f1 - f2)
    m = np.asarray(mask, bool)
    ins = m & np.asarray(inside, bool)
    parts = {"": m, "_inside": ins, "_outside": m & ~ins}
    units = {}
    for suffix, w in parts.items():
        units[f"full_angle_deg{suffix}"] = block_units(ang, w, origin)
        units[f"full_friction_mae{suffix}"] = block_units(fr, w, origin)
    if lines is not None:
        out, near = parts["_outside"], np.asarray(lines, bool)
        units["full_angle_deg_outside_lines"] = block_units(ang, out & near, origin)
        units["full_angle_deg_outside_open"] = block_units(ang, out & ~near, origin)
    scores = {k: value(k, u) for k, u in units.items() if len(u)}
    scores["full_inside_fraction"] = float(ins.sum() / m.sum()) if m.any() else float("nan")
    return scores, {k: u for k, u in units.items() if len(u)}


def full_field_metrics(gx_fake: np.ndarray, gy_fake: np.ndarray, gx_true: np.ndarray, gy_true: np.ndarray,
                       mask: np.ndarray, scale: float) -> dict:
    """Angular error and friction-map MAE over the whole object mask (ground truth everywhere: synthetic data)."""
    s, _ = full_field_scores(gx_fake, gy_fake, gx_true, gy_true, mask, np.zeros_like(mask, bool), scale, (0, 0))
    return {"full_angle_deg": s["full_angle_deg"], "full_friction_mae": s["full_friction_mae"]}
