"""Weave waves: plane waves at the training photo's weave frequencies, placed by object-relative coordinates, that a
generator head mixes into its output with per-pixel weights (`model.weave_waves`; exploratory, off by default).

Why: off the training touches nothing a model sees says where the weave's ridges sit. The positional encoding is
crop-relative (as published) and training crops start at random origins, so no head can tie the weave's phase to
the garment. The photo, though, shows the weave over the whole object, and the shading relief reads a painted weave
back into the relief (trainer/models/shading_relief.py). With the real photo in place of the visual head, that reading
closes 38-50 % of the outside gap against 29-46 % from the model's own photo (docs/training.md, "Weave waves"). So
the heads are given waves they can place: sin and cos of k . (u, v) for a few frequencies k read off the training
photo's fine-band spectrum, where (u, v) is the pixel's offset from the object's bounding box. That offset is the
same in every training crop (the crop keeps the object inside) and at evaluation, and is computed in the graph from
the mask, so an exported graph still takes only the sketch and the mask. The head outputs, besides its channels, a
weight per channel and wave (sin, cos): a smooth weight field places a plane wave's phase and strength, which a
network of stride-2 convolutions cannot draw itself at a few pixels' period. Measured and not adopted: the photo
gains, the relief does not (docs/training.md, "Weave waves").
"""
from __future__ import annotations

import math

import numpy as np
import torch

from trainer.models.shading_relief import BANDS, LUMA

PAD = 4               # FFT zero padding (times the larger side): peaks located to a quarter of a bin before refining
MIN_PERIOD_PX = 2.5   # above Nyquist's 2 px: a wave at the grid's limit aliases in the head's stride-2 weights
MAX_PERIOD_PX = 40.0  # longer waves are folds, prints and the lamp's falloff, not weave
SUPPRESS = 3          # bins (of the padded grid) around a picked peak that no later peak may take


def object_coords(mask: torch.Tensor) -> torch.Tensor:
    """(N, 2, H, W): each pixel's (u, v) = (x - x0, y - y0) in px, (x0, y0) the top-left of the mask's bounding box
    (the mask's first column and row holding the object; an empty mask gives the crop's own grid). Made of
    reductions an ONNX export keeps (max, cumsum, min), so it runs in a graph."""
    m = (mask[:, :1] > 0.5).to(mask.dtype)
    px = torch.cumsum(torch.ones_like(m[0, 0, 0, :]), 0) - 1   # 0..W-1
    py = torch.cumsum(torch.ones_like(m[0, 0, :, 0]), 0) - 1   # 0..H-1
    cols = m.amax(dim=2)[:, 0]   # (N, W): 1 where the column holds the object
    rows = m.amax(dim=3)[:, 0]   # (N, H)
    big_x, big_y = px[-1] + 1, py[-1] + 1
    x0 = (px[None] + (1 - cols) * big_x).amin(dim=1)   # an empty mask: W, then 0 below
    y0 = (py[None] + (1 - rows) * big_y).amin(dim=1)
    x0 = torch.where(x0 >= big_x, torch.zeros_like(x0), x0)
    y0 = torch.where(y0 >= big_y, torch.zeros_like(y0), y0)
    u = px[None, None, :] - x0[:, None, None]
    v = py[None, :, None] - y0[:, None, None]
    n, _, h, w = m.shape
    return torch.stack([u.expand(n, h, w), v.expand(n, h, w)], 1)


def wave_mix(weights: torch.Tensor, coords: torch.Tensor, k: torch.Tensor, channels: int) -> torch.Tensor:
    """(N, channels, H, W): sum over waves j of weights[c, j, sin] sin(k_j . (u, v)) + weights[c, j, cos] cos(...).

    weights (N, channels * 2K, H, W), channel-major (each output channel's K sin weights, then its K cos weights);
    coords (N, 2, H, W); k (K, 2) in rad/px (x, y)."""
    n, _, h, w = weights.shape
    kk = k.to(coords.dtype)
    phase = coords[:, :1] * kk[:, 0].view(1, -1, 1, 1) + coords[:, 1:2] * kk[:, 1].view(1, -1, 1, 1)   # (N, K, H, W)
    basis = torch.cat([torch.sin(phase), torch.cos(phase)], 1)   # (N, 2K, H, W)
    wts = weights.reshape(n, channels, basis.shape[1], h, w)
    return (wts * basis[:, None]).sum(2)


def _fine_band(photo: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The photo's fine log-luminance bands (the shading relief's, summed) on the object, mean removed there, 0 off
    it: float64 (H, W)."""
    import cv2   # the trainer's dependency; kept local so the graph code does not need it

    rgb = photo.astype(np.float64) / 255.0
    lum = np.log(np.maximum(rgb @ np.asarray(LUMA), 1e-3))
    band = sum(cv2.GaussianBlur(lum, (0, 0), s1) - cv2.GaussianBlur(lum, (0, 0), s2) for s1, s2 in BANDS)
    m = mask > 0
    if not m.any():
        raise ValueError("weave waves: the mask holds no object")
    band = np.where(m, band - band[m].mean(), 0.0)
    return band


def weave_frequencies(photo: np.ndarray, mask: np.ndarray, count: int) -> np.ndarray:
    """(count, 2) float32 rad/px (kx, ky): the strongest peaks of the photo's fine-band spectrum on the object, one
    per conjugate pair (ky >= 0), periods within [MIN_PERIOD_PX, MAX_PERIOD_PX], each refined to a fraction of a bin
    by a parabola through its neighbours. Fewer peaks than `count` (a weave-free photo) are padded by repeating the
    strongest; a photo with no fine band at all raises ValueError, so a run never starts on waves of nothing."""
    if count < 1:
        raise ValueError(f"weave waves: count must be >= 1; got {count}")
    band = _fine_band(photo, mask)
    if not np.isfinite(band).all() or float(np.abs(band).max()) <= 0.0:
        raise ValueError("weave waves: the photo has no fine shading on the object to read a weave from")
    h, w = band.shape
    n = int(2 ** math.ceil(math.log2(PAD * max(h, w))))
    win = np.outer(np.hanning(h), np.hanning(w))
    spec = np.abs(np.fft.fft2(band * win, s=(n, n)))
    f = np.fft.fftfreq(n) * 2 * math.pi
    kx, ky = np.meshgrid(f, f)   # spec[iy, ix] at (kx[iy, ix], ky[iy, ix])
    period = 2 * math.pi / np.maximum(np.hypot(kx, ky), 1e-12)
    allowed = (period >= MIN_PERIOD_PX) & (period <= MAX_PERIOD_PX) & ((ky > 0) | ((ky == 0) & (kx > 0)))
    s = np.where(allowed, spec, 0.0)
    radius = SUPPRESS * PAD
    picked: list[tuple[float, float]] = []
    while len(picked) < count:
        iy, ix = np.unravel_index(int(np.argmax(s)), s.shape)
        if s[iy, ix] <= 0:
            break
        picked.append((_refine(spec, iy, ix, 1, kx[iy, ix], n), _refine(spec, iy, ix, 0, ky[iy, ix], n)))
        for sy, sx in ((iy, ix), ((-iy) % n, (-ix) % n)):   # the peak and its conjugate twin
            ys = np.arange(sy - radius, sy + radius + 1) % n
            xs = np.arange(sx - radius, sx + radius + 1) % n
            s[np.ix_(ys, xs)] = 0.0
    if not picked:
        raise ValueError("weave waves: no spectral peak within the weave's periods")
    while len(picked) < count:
        picked.append(picked[0])
    return np.asarray(picked, np.float32)


def _refine(spec: np.ndarray, iy: int, ix: int, axis: int, at: float, n: int) -> float:
    """The peak's frequency along `axis` (1: x, 0: y), moved by the vertex of a parabola through log magnitudes."""
    step = 2 * math.pi / n
    if axis == 1:
        a, b, c = spec[iy, (ix - 1) % n], spec[iy, ix], spec[iy, (ix + 1) % n]
    else:
        a, b, c = spec[(iy - 1) % n, ix], spec[iy, ix], spec[(iy + 1) % n, ix]
    la, lb, lc = (math.log(max(v, 1e-300)) for v in (a, b, c))
    den = la - 2 * lb + lc
    shift = 0.5 * (la - lc) / den if den < 0 else 0.0
    return float(at + max(-0.5, min(0.5, shift)) * step)
