"""What a finger gets from a friction frame: the dominant texture period and the contrast in felt steps.

Shared by `vtkiosk bench haptics` and the tests. numpy only (runs on the kiosk side of the import rule).
"""
from __future__ import annotations

import numpy as np

from kiosk.contract.errors import InputError
from kiosk.contract.haptics import JND_RATIO, THRESHOLD_LEVEL, jnd_steps

PAD = 4          # zero-padding factor: samples the spectrum finely enough to place its peak between bins
MIN_CYCLES = 2.0  # periods longer than half the window are not a texture the window can show


def dominant_period_px(field: object) -> float:
    """The dominant period (pixels) of a 2-D texture: the peak of its radially averaged power spectrum.

    Mean removed, Hann-windowed, zero-padded FFT; the radial profile (mean power per |f| ring) is searched from
    MIN_CYCLES cycles per window up, and its peak is refined by a parabola through the three samples around it.
    Radial averaging makes the answer independent of the texture's orientation (twill at 45 degrees, cord across
    the grain) and stable for band-limited noise (fleece). NaN for a constant field.
    Shape: (H, W), H, W >= 8 -> float.
    """
    a = np.asarray(field, dtype=np.float64)
    if a.ndim != 2 or min(a.shape) < 8:
        raise InputError(f"a texture window must be 2-D and at least 8x8 pixels; got shape {a.shape}")
    a = np.nan_to_num(a - a.mean())
    if not np.any(a):
        return float("nan")
    h, w = a.shape
    win = np.hanning(h)[:, None] * np.hanning(w)[None, :]
    ph, pw = PAD * h, PAD * w
    power = np.abs(np.fft.rfft2(a * win, s=(ph, pw))) ** 2
    fy = np.fft.fftfreq(ph)[:, None]
    fx = np.fft.rfftfreq(pw)[None, :]
    radius = np.hypot(fx, fy)
    step = 1.0 / (PAD * max(h, w))
    ring = np.rint(radius / step).astype(int)
    counts = np.bincount(ring.ravel())
    sums = np.bincount(ring.ravel(), weights=power.ravel())
    profile = sums / np.maximum(counts, 1)
    lo = int(np.ceil(MIN_CYCLES / min(h, w) / step))
    hi = min(len(profile) - 1, int(0.5 / step))
    if hi - lo < 3:
        return float("nan")
    k = lo + int(np.argmax(profile[lo:hi]))
    f = k * step
    if lo < k < hi - 1:
        y0, y1, y2 = profile[k - 1], profile[k], profile[k + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            f = (k + 0.5 * (y0 - y2) / den) * step
    return float(1.0 / f) if f > 0 else float("nan")


def contrast_steps(levels: object, mask: object | None = None, *, threshold_level: float = THRESHOLD_LEVEL,
                   jnd_ratio: float = JND_RATIO) -> float:
    """Interquartile range of friction levels in just-noticeable steps (`kiosk.contract.haptics.jnd_steps`)."""
    lv = np.asarray(levels, dtype=np.float64)
    if mask is not None:
        lv = lv[np.asarray(mask, dtype=bool)]
    if lv.size == 0:
        raise InputError("no pixels to measure the contrast over")
    q25, q75 = np.quantile(lv, (0.25, 0.75))
    s = jnd_steps(np.array([q25, q75]), threshold_level=threshold_level, jnd_ratio=jnd_ratio)
    return float(s[1] - s[0])
