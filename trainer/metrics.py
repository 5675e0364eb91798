"""Evaluation metrics (the definitions of the authors' published code), on numpy arrays or tensors in [-1, 1].

Visual: PSNR, SSIM, L1 on the masked image; LPIPS when VGG weights are configured. Tactile (paired 32x32 patches,
contact pixels): MSE and the angular error in degrees between normalize(gx, gy, 1) vectors. Full field (synthetic
garments): the same angular error over the whole object mask and the friction-map MAE (0..255 levels) with the
run's calibrated friction scale. SIFID uses the first block of InceptionV3 (trainer.models.inception); its
weight-free fallback FB-SIFID lives in trainer.texture_distance.
"""
from __future__ import annotations

import numpy as np
import torch

from kiosk.contract.haptics import friction_map
from trainer.losses.perceptual import ssim as _ssim


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR (dB) of images in [-1, 1], computed on [0, 1]."""
    mse = float((((a + 1) / 2 - (b + 1) / 2) ** 2).mean())
    return float(10 * np.log10(1.0 / max(mse, 1e-12)))


def ssim(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(_ssim((a + 1) / 2, (b + 1) / 2, data_range=1.0))


def l1(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().mean())


def angular_error_deg(gx1, gy1, gx2, gy2, mask=None) -> float:
    """Mean angle (degrees) between (gx1, gy1, 1) and (gx2, gy2, 1), over `mask` (all pixels when None)."""
    gx1, gy1, gx2, gy2 = (np.asarray(t.detach().cpu() if isinstance(t, torch.Tensor) else t, dtype=np.float64)
                          for t in (gx1, gy1, gx2, gy2))
    n1 = np.stack([gx1, gy1, np.ones_like(gx1)], -1)
    n2 = np.stack([gx2, gy2, np.ones_like(gx2)], -1)
    n1 /= np.linalg.norm(n1, axis=-1, keepdims=True)
    n2 /= np.linalg.norm(n2, axis=-1, keepdims=True)
    ang = np.degrees(np.arccos(np.clip((n1 * n2).sum(-1), -1.0, 1.0)))
    if mask is not None:
        m = np.asarray(mask.detach().cpu() if isinstance(mask, torch.Tensor) else mask).astype(bool)
        m = np.broadcast_to(m, ang.shape)
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


def full_field_metrics(gx_fake: np.ndarray, gy_fake: np.ndarray, gx_true: np.ndarray, gy_true: np.ndarray,
                       mask: np.ndarray, scale: float) -> dict:
    """Angular error and friction-map MAE over the whole object mask (ground truth everywhere: synthetic data)."""
    f1 = friction_map(gx_fake, gy_fake, scale).astype(np.float64)
    f2 = friction_map(gx_true, gy_true, scale).astype(np.float64)
    m = mask.astype(bool)
    return {"full_angle_deg": angular_error_deg(gx_fake, gy_fake, gx_true, gy_true, m),
            "full_friction_mae": float(np.abs(f1 - f2)[m].mean())}
