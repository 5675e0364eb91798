"""Texture-statistics distance that needs no pretrained weights: the fallback for SIFID.

SIFID (Shaham et al. 2019) is the Frechet distance between the per-pixel feature statistics (mean, covariance over
positions) of two single images, features from InceptionV3's first block. Without Inception weights we keep the
recipe and swap the features for a fixed Gaussian-derivative filter bank (orders 0-2 at three scales: local level,
slope and curvature, i.e. what a fingertip's friction follows). Like SIFID it ignores where a texture's bumps sit and
compares how strong, how fine and how oriented they are, which per-pixel errors cannot see: a blurred prediction
scores well on MSE and badly here. Values are not comparable with Inception SIFID; reports name it `FB-SIFID`.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

SIGMAS = (1.0, 2.0, 4.0)
ORDERS = ((0, 0), (0, 1), (1, 0), (0, 2), (1, 1), (2, 0))   # (d/dy, d/dx) orders per filter


def filter_bank(img: np.ndarray) -> np.ndarray:
    """(H, W) -> (H, W, len(SIGMAS) * len(ORDERS)) Gaussian-derivative responses, scale-normalised (x sigma^order)
    so fine and coarse structure weigh alike."""
    x = np.asarray(img, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"filter_bank: expected a 2-D image; got shape {x.shape}")
    return np.stack([ndimage.gaussian_filter(x, s, order=o, mode="reflect") * s ** sum(o)
                     for s in SIGMAS for o in ORDERS], -1)


def frechet(xa: np.ndarray, xb: np.ndarray) -> float:
    """Frechet distance between Gaussians fitted to two (N, D) samples.

    tr(sqrt(S1 S2)) is computed as the trace of sqrt(sqrt(S1) S2 sqrt(S1)), a symmetric PSD matrix, from
    eigenvalues clipped at 0: no complex parts to drop and no division, so flat (rank-deficient) inputs are exact.
    """
    if len(xa) < 2 or len(xb) < 2:
        return float("nan")
    mu1, mu2 = xa.mean(0), xb.mean(0)
    s1, s2 = np.atleast_2d(np.cov(xa, rowvar=False)), np.atleast_2d(np.cov(xb, rowvar=False))
    w, v = np.linalg.eigh(s1)
    r1 = (v * np.sqrt(np.clip(w, 0.0, None))) @ v.T
    cross = np.sqrt(np.clip(np.linalg.eigvalsh(r1 @ s2 @ r1), 0.0, None)).sum()
    d = float(((mu1 - mu2) ** 2).sum() + np.trace(s1) + np.trace(s2) - 2.0 * cross)
    return max(d, 0.0)


def fb_sifid(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None,
             mask_b: np.ndarray | None = None) -> float:
    """FB-SIFID between two (H, W) images over `mask` (all pixels when None); NaN with fewer than 2 pixels.

    `mask_b` selects b's pixels when they differ from a's: texture statistics need no pixel correspondence, so an
    output on an unseen sketch (its own shape) is compared with the garment's photo over the photo's object.
    Then a and b may differ in size."""
    fa, fb = filter_bank(a), filter_bank(b)
    ma = None if mask is None else np.asarray(mask).astype(bool)
    mb = ma if mask_b is None else np.asarray(mask_b).astype(bool)
    xa = fa.reshape(-1, fa.shape[-1]) if ma is None else fa[ma]
    xb = fb.reshape(-1, fb.shape[-1]) if mb is None else fb[mb]
    return frechet(xa, xb)


def fb_sifid_channels(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None,
                      mask_b: np.ndarray | None = None) -> float:
    """Mean FB-SIFID over channels of (C, H, W) images (per channel, as the paper's tactile SIFID)."""
    vals = [fb_sifid(a[c], b[c], mask, mask_b) for c in range(a.shape[0])]
    return float(np.mean(vals))
