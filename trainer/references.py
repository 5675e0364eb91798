"""Reference rows of every comparison: what a trivial answer scores and what the best possible model would score.

- `flat`: gx = gy = 0 everywhere (a garment that feels like glass). Tactile only.
- `mean-colour`: the object painted in its mean colour (from the ground-truth photo, inside the mask). Visual only.
- `oracle`: the full-field tactile ground truth (synthetic garments) degraded the way our pipeline must degrade it,
  so no model could beat it: (1) low-passed by the tactile sensor's transfer, measured on the training touches as
  the Gaussian blur of the ground truth that best explains the recorded patches (a model learns from those patches
  and cannot know detail the sensor never recorded; sensor noise averages out, gel blur and registration jitter
  do not); (2) clipped to the tanh range (-1, 1) the generator's tactile head can emit and set to 0 off the object,
  as the exported graph does; (3) cast to the precision of the exported graph's tactile head (float32: int8 bundles
  keep their output heads in fp32; "fp16" for fp16 bundles). The friction map's 8-bit quantisation is applied by
  the friction metric to every row alike. The visual oracle would be the photo itself (PSNR inf, SSIM 1), so the
  oracle row has tactile columns only.
- `shape-oracle`: the oracle with the fabric's weave removed (Gaussian low-pass at half the weave period, which leaves
  < 1 % of the weave's fundamental): everything a model could know about folds, seams and stitching, nothing about
  where the weave's ridges sit. The best a model can do where it never saw the weave's phase and renders none.
- `texture-oracle`: the shape-oracle plus the oracle's own weave with its Fourier phases randomised: the weave's
  spectrum exactly right, its position unknown. On average over phases this is what a perfect texture model (a GAN
  at its best) scores off the touches: a wrongly placed ridge costs more on a per-pixel angle than no ridge, so this
  row can sit above flat. Both need the weave period (synthetic.yaml's fabric.period_mm and pixel_pitch_mm).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trainer.data.touchclothing import Garment

REFERENCE_ROWS = ("flat", "mean-colour", "oracle", "shape-oracle", "texture-oracle")
BLUR_SIGMAS = tuple(np.round(np.arange(0.0, 4.01, 0.25), 2))   # px; candidates for the sensor's transfer
FIT_TOLERANCE = 0.01   # relative MSE within which a smaller blur is preferred
HEAD_RANGE = 1.0   # tanh
WEAVE_CUTOFF = 0.5   # shape-oracle's low-pass sigma, in weave periods
PHASE_SEED = 0       # texture-oracle's random phases: fixed, so the row is reproducible


@dataclass
class Oracle:
    gx: np.ndarray          # (P, P) float32, padded frame
    gy: np.ndarray
    sigma_px: float         # the fitted sensor blur
    fit_mse: float          # its mean squared error against the training touches' contact pixels
    precision: str


def _blur(a: np.ndarray, sigma: float) -> np.ndarray:
    if sigma <= 0:
        return a.astype(np.float32)
    return cv2.GaussianBlur(a.astype(np.float32), (0, 0), sigma, borderType=cv2.BORDER_REFLECT)


def fit_sensor_blur(g: Garment, split: str = "train", sigmas=BLUR_SIGMAS) -> tuple[float, float]:
    """(sigma px, mse): the Gaussian blur of the full-field truth closest to `split`'s recorded touches, over their
    contact pixels. Sensor noise is independent of the surface, so it adds the same constant to every candidate's
    error and does not bias the choice; of the blurs within FIT_TOLERANCE of the best fit, the least is taken."""
    ft = g.full_tactile
    if ft is None:
        raise ValueError(f"{g.name}: no full-field tactile ground truth; the oracle needs a synthetic garment")
    touches = g.touches.get(split, [])
    if not touches:
        raise ValueError(f"{g.name}: no {split} touches to measure the sensor's blur on")
    mses = []
    for s in sigmas:
        bx, by = _blur(ft.gx, s), _blur(ft.gy, s)
        sse, n = 0.0, 0
        for t in touches:
            r = t.rect
            sl = (slice(r.y, r.y + r.h), slice(r.x, r.x + r.w))
            c = t.contact
            sse += float(((bx[sl][c] - t.gx[c]) ** 2).sum() + ((by[sl][c] - t.gy[c]) ** 2).sum())
            n += int(c.sum())
        mses.append(sse / (2 * n) if n else float("inf"))
    # the least blur within FIT_TOLERANCE of the best: with noisy touches a blur that merely fits the noise's
    # sample correlation by chance must not count as the sensor's
    floor = min(mses) * (1.0 + FIT_TOLERANCE)
    i = next(i for i, m in enumerate(mses) if m <= floor)
    return float(sigmas[i]), float(mses[i])


def exported_head(a: np.ndarray, mask: np.ndarray, precision: str = "float32") -> np.ndarray:
    """What the exported graph's tactile head can emit for a wished-for field `a`: tanh range, 0 off the object,
    rounded to the head's precision."""
    if precision not in ("float32", "fp16"):
        raise ValueError(f"precision must be 'float32' or 'fp16'; got {precision!r}")
    out = np.clip(a, -HEAD_RANGE, HEAD_RANGE) * mask
    return out.astype(np.float16).astype(np.float32) if precision == "fp16" else out.astype(np.float32)


def oracle(g: Garment, precision: str = "float32") -> Oracle | None:
    """The degraded ground truth over the padded frame; None for a garment without full-field truth."""
    ft = g.full_tactile
    if ft is None or not g.touches.get("train"):
        return None
    sigma, mse = fit_sensor_blur(g)
    gx = exported_head(_blur(ft.gx, sigma), g.mask, precision)
    gy = exported_head(_blur(ft.gy, sigma), g.mask, precision)
    return Oracle(gx, gy, sigma, mse, precision)


def weave_period_px(g: Garment) -> float | None:
    """The fabric's weave period in padded-frame pixels, when the garment states it; None otherwise."""
    pitch = g.pixel_pitch_mm
    fabric = g.meta.get("fabric")
    period = fabric.get("period_mm") if isinstance(fabric, dict) else None
    try:
        period = float(period)
    except (TypeError, ValueError):
        return None
    if pitch is None or not (np.isfinite(period) and np.isfinite(pitch) and period > 0 and pitch > 0):
        return None
    return period / pitch


def _random_phase(a: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """`a` with its amplitude spectrum kept and every Fourier phase drawn uniformly (a real field again)."""
    f = np.fft.rfft2(a.astype(np.float64))
    return np.fft.irfft2(np.abs(f) * np.exp(1j * rng.uniform(0.0, 2.0 * np.pi, f.shape)), s=a.shape)


def weave_split(g: Garment, o: Oracle) -> tuple[Oracle, Oracle] | None:
    """(shape-oracle, texture-oracle) from the oracle `o`; None when the garment states no weave period."""
    period = weave_period_px(g)
    if period is None:
        return None
    sigma = WEAVE_CUTOFF * period
    rng = np.random.default_rng(PHASE_SEED)
    m = g.mask.astype(np.float32)
    shape, texture = [], []
    for a in (o.gx, o.gy):
        low = _blur(a, sigma)
        weave = (a - low) * m
        placed = _random_phase(weave, rng)
        # a new phase spreads the weave over the whole frame; keep its energy on the object what it was
        want, got = float((weave ** 2).sum()), float((placed[g.mask] ** 2).sum())
        weave = placed * (np.sqrt(want / got) if got > 0.0 else 0.0)
        shape.append(exported_head(low, g.mask, o.precision))
        texture.append(exported_head(low + weave, g.mask, o.precision))
    return (Oracle(shape[0], shape[1], o.sigma_px, o.fit_mse, o.precision),
            Oracle(texture[0], texture[1], o.sigma_px, o.fit_mse, o.precision))


def paint(colour: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(3, H, W): `colour` (3,) inside `mask` (H, W), 0 (the network's background) outside."""
    m = np.asarray(mask, bool)
    out = np.zeros((3,) + m.shape, np.float32)
    out[:, m] = np.asarray(colour, np.float32)[:, None]
    return out


def object_colour(visual: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(3,) mean of `visual` (3, H, W) inside `mask`; black for an empty mask (nothing to average)."""
    m = np.asarray(mask, bool)
    return visual[:, m].mean(1) if m.any() else np.zeros(3, np.float32)


def mean_colour(visual: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(3, H, W) in [-1, 1]: the object painted with its mean colour inside `mask`, 0 outside."""
    return paint(object_colour(visual, mask), mask)
