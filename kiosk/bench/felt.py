"""What a finger gets from a friction frame: the dominant texture period and the contrast in felt steps.

Shared by `vtkiosk bench haptics` and the tests. numpy only (runs on the kiosk side of the import rule).
"""
from __future__ import annotations

import numpy as np

from kiosk.contract.errors import InputError
from kiosk.contract.haptics import JND_RATIO, THRESHOLD_LEVEL, jnd_steps

FUNDAMENTAL = 0.5  # the lowest spectral peak with at least this share of the highest one is the period felt
PAD = 4          # zero-padding factor: samples the spectrum finely enough to place its peak between bins
MIN_CYCLES = 2.0  # periods longer than half the window are not a texture the window can show


def dominant_period_px(field: object, max_period_px: float | None = None) -> float:
    """The dominant period (pixels) of a 2-D texture: the peak of its radially averaged power spectrum.

    Mean removed, Hann-windowed, zero-padded FFT; the radial profile (mean power per |f| ring) is searched from
    MIN_CYCLES cycles per window (or `max_period_px`, whichever is shorter) to the Nyquist limit. A ridged
    texture has harmonics of similar power (a corduroy wale and its groove); the period is the fundamental: the
    lowest-frequency local peak with at least FUNDAMENTAL of the highest peak's power, refined by a parabola
    through the three samples around it.
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
    longest = min(h, w) / MIN_CYCLES
    if max_period_px is not None:
        longest = min(longest, float(max_period_px))
    lo = int(np.ceil(1.0 / longest / step))
    hi = min(len(profile) - 1, int(0.5 / step))
    if hi - lo < 3:
        return float("nan")
    band = profile[lo:hi]
    top = float(band.max())
    peaks = [i for i in range(1, len(band) - 1) if band[i] >= band[i - 1] and band[i] >= band[i + 1]
             and band[i] >= FUNDAMENTAL * top]
    k = lo + (peaks[0] if peaks else int(np.argmax(band)))
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


def radial_profile(field: object, pitch_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(frequencies in cycles/mm, mean power per ring) of a texture window, Hann-windowed and zero-padded."""
    a = np.asarray(field, dtype=np.float64)
    if a.ndim != 2 or min(a.shape) < 8:
        raise InputError(f"a texture window must be 2-D and at least 8x8 pixels; got shape {a.shape}")
    a = np.nan_to_num(a - a.mean())
    h, w = a.shape
    win = np.hanning(h)[:, None] * np.hanning(w)[None, :]
    ph, pw = PAD * h, PAD * w
    power = np.abs(np.fft.rfft2(a * win, s=(ph, pw))) ** 2
    radius = np.hypot(np.fft.rfftfreq(pw)[None, :], np.fft.fftfreq(ph)[:, None])
    step = 1.0 / (PAD * max(h, w))
    ring = np.rint(radius / step).astype(int).ravel()
    prof = np.bincount(ring, weights=power.ravel()) / np.maximum(np.bincount(ring), 1)
    freq = np.arange(prof.size) * step / pitch_mm
    keep = freq <= 0.5 / pitch_mm
    return freq[keep], prof[keep]


def felt_scale(device: object, device_pitch_mm: float, truth: object, truth_pitch_mm: float, *,
               max_period_mm: float = 8.0, lo: float = 0.3, hi: float = 3.0) -> float:
    """How much larger the device frame's texture is than the truth's (1.0 = true size): the scale s that best
    aligns the device's radial log-power spectrum P_dev(f) with the truth's P_true(f * s), over the periods both
    can show (from `max_period_mm` down to the coarser Nyquist limit). Uses the whole spectrum, so a texture
    whose harmonics have similar power (a wale and its groove) gives one stable answer where a single peak may
    jump between harmonics. NaN when the bands do not overlap or a field is constant."""
    fd, pd = radial_profile(device, device_pitch_mm)
    ft, pt = radial_profile(truth, truth_pitch_mm)
    if not (pd[1:].any() and pt[1:].any()):
        return float("nan")
    f_lo = 1.0 / max_period_mm
    f_hi = min(fd[-1], ft[-1] / hi)
    if f_hi <= f_lo * 1.5:
        return float("nan")
    grid = np.geomspace(f_lo, f_hi, 256)
    ld = np.log(np.interp(grid, fd, pd) + 1e-12)
    ld = (ld - ld.mean()) / (ld.std() + 1e-12)
    scales = np.geomspace(lo, hi, 481)  # 0.5 % steps
    lt = np.log(np.interp((scales[:, None] * grid[None, :]).ravel(), ft, pt).reshape(scales.size, -1) + 1e-12)
    lt = (lt - lt.mean(axis=1, keepdims=True)) / (lt.std(axis=1, keepdims=True) + 1e-12)
    return float(scales[int(np.argmax((lt * ld[None, :]).mean(axis=1)))])
