"""Haptic math of the runtime contract: gradients <-> normals, height, friction map.

Defined once here (numpy/opencv only) and imported by the trainer and exporter, so that what a model is trained and
evaluated on is exactly what the kiosk renders.

Conventions
-----------
- `gx`, `gy` are surface gradients (slopes dh/dx, dh/dy; dimensionless), x = column (to the right), y = row (down),
  shape (H, W). Any real float or integer dtype is accepted; outputs are float32 unless stated.
- Non-finite input (NaN, +-Inf) is treated as 0 (a flat surface), never propagated. Pass a `NonFiniteCounter` to
  learn how many values were replaced; the kiosk exports that count as a metric.
- Paper Eq. 1: n = (gx, gy, -1) / sqrt(gx^2 + gy^2 + 1). The printed inverse "gx = n_x / n_z" contradicts the forward
  formula (with n_z = -1/s it gives -gx); we use gx = -n_x / n_z, gy = -n_y / n_z so the two functions invert each other.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from kiosk.contract.errors import InputError
from kiosk.contract.validate import check_size

# Below this, a calibrated friction scale would turn sensor noise into full friction; see `calibrate_scale`.
MIN_FRICTION_SCALE = 1e-4
# Largest |slope| `gradients_from_normals` returns where the normal lies (almost) in the image plane.
DEFAULT_MAX_SLOPE = 100.0
# A device frame is mapped on a grid at least this many times finer than the model's (per axis), then averaged over
# each panel pixel: squaring a slope doubles its highest frequency, so 2 is the least that keeps it from aliasing.
SUPERSAMPLE = 2

# Steps per unit of log(gz) beyond which the perceptual mapping is computed in float64: float32's log error
# (about 1e-6 at |log gz| ~ 20) times this stays far below one level. Garment quartiles (`perceptual_constants`
# keeps gz_high >= 1.01 gz_low) give at most steps_span / log(1.01), about 700 at the default span.
MAX_FLOAT32_STEPS_PER_LOG = 1000.0

# Largest |slope| the map keeps, per working dtype (squares, and sums of two, stay finite), and the multiple of a
# mapping's saturating slope it clips at (see `friction_map`).
SATURATION_MARGIN = 1e5
SLOPE_LIMIT = {"float32": 1e18, "float64": 1e153}

Normalization = Literal["calibrated", "quantile", "perceptual"]
NORMALIZATIONS: tuple[str, ...] = ("calibrated", "quantile", "perceptual")
Precision = Literal["float32", "float64"]
PRECISIONS: tuple[str, ...] = ("float32", "float64")

# -- the perceptual friction scale (docs/haptics.md has the sources and the reasoning) -------------------------------
# Electroadhesion adds a normal force that grows with the square of the drive voltage, and the vendor defines a
# friction level as proportional added friction (0 = natural, 255 = the most the hardware adds). A difference
# threshold of 1.21 dB in drive amplitude (Ryu et al. 2018, Sci. Rep. 8:4555) is therefore a factor
# 10^(2 * 1.21 / 20) = 1.32 in friction level: one just-noticeable step (Weber's law above the threshold).
JND_VOLTAGE_DB = 1.21
JND_RATIO = float(10.0 ** (2.0 * JND_VOLTAGE_DB / 20.0))
# The lowest level a finger tells from natural friction. No TanvasTouch figure is published; 10/255 (-28 dB of the
# force range) is our stated assumption, stored in every perceptual bundle so a measured value can replace it.
THRESHOLD_LEVEL = 10.0
PERCEPTUAL_DEFAULTS: dict[str, float] = {
    "threshold_level": THRESHOLD_LEVEL,  # level of the first felt step (detection threshold)
    "jnd_ratio": JND_RATIO,              # level ratio of one just-noticeable step
    "steps_low": 3.0,                    # the fabric's lower quartile sits this many steps above the threshold
    "steps_span": 7.0,                   # ... and its upper quartile this many steps higher
    "floor_slope": 0.002,                # slopes below this are flat: natural friction, never stretched
    "steps_per_octave": 4.5,             # at most this many steps per doubling of slope above the floor
}


@dataclass
class NonFiniteCounter:
    """Accumulates how many non-finite input values were replaced by 0 (for health metrics and tests)."""

    count: int = 0


def _field(name: str, a: object) -> np.ndarray:
    """Validate one 2-D numeric field; return it as a float32 array (a view when possible)."""
    arr = np.asarray(a)
    if arr.ndim != 2:
        raise InputError(f"{name} must be a 2-D array (H, W); got shape {arr.shape}")
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise InputError(f"{name} must have at least one pixel; got shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer) or arr.dtype == bool):
        raise InputError(f"{name} must be a real numeric array; got dtype {arr.dtype}")
    return arr


def _finite(arr: np.ndarray, dtype: type, counter: NonFiniteCounter | None) -> np.ndarray:
    """`arr` as `dtype` with non-finite values replaced by 0 (the input is never modified)."""
    if np.issubdtype(arr.dtype, np.floating):
        bad = ~np.isfinite(arr)
        if bad.any():
            if counter is not None:
                counter.count += int(bad.sum())
            arr = np.where(bad, 0, arr)
        big = np.finfo(dtype).max if np.issubdtype(dtype, np.floating) else None
        if big is not None and np.finfo(arr.dtype).max > big:
            arr = np.clip(arr, -big, big)  # a finite float64 beyond float32's range must not become Inf
    return np.ascontiguousarray(arr, dtype=dtype)


def sanitize_gradients(gx: object, gy: object, *, counter: NonFiniteCounter | None = None,
                       dtype: type = np.float32) -> tuple[np.ndarray, np.ndarray]:
    """Check a gradient pair and return finite, contiguous copies.

    Shape: gx, gy: (H, W), equal shapes -> two (H, W) arrays of `dtype`.
    Raises InputError on wrong rank, empty or mismatched shapes, non-numeric dtype.
    """
    ax, ay = _field("gx", gx), _field("gy", gy)
    if ax.shape != ay.shape:
        raise InputError(f"gx and gy must have the same shape; got {ax.shape} and {ay.shape}")
    return _finite(ax, dtype, counter), _finite(ay, dtype, counter)


def normals_from_gradients(gx: object, gy: object, *, counter: NonFiniteCounter | None = None) -> np.ndarray:
    """Unit surface normals from gradients (paper Eq. 1).

    Shape: gx, gy: (H, W) -> (H, W, 3) float32 (n_x, n_y, n_z), n_z < 0, |n| = 1.
    Overflow-safe: the norm is computed with hypot, so slopes of 1e30 give (+-1, 0, ~0), not NaN.

    Example:
        >>> n = normals_from_gradients(np.zeros((2, 2)), np.zeros((2, 2)))
        >>> n[0, 0].tolist()
        [0.0, 0.0, -1.0]
    """
    ax, ay = sanitize_gradients(gx, gy, counter=counter, dtype=np.float64)
    norm = np.hypot(np.hypot(ax, ay), 1.0)
    out = np.empty(ax.shape + (3,), dtype=np.float32)
    out[..., 0] = ax / norm
    out[..., 1] = ay / norm
    out[..., 2] = -1.0 / norm
    return out


def gradients_from_normals(n: object, *, max_slope: float = DEFAULT_MAX_SLOPE,
                           counter: NonFiniteCounter | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Gradients from normals, the inverse of `normals_from_gradients`.

    Shape: n: (H, W, 3), need not be unit length -> gx, gy: (H, W) float32.
    Where n_z -> 0 (a wall seen edge-on) the slope is unbounded; it is clipped to +-`max_slope` with the sign of the
    in-plane component, so the result is always finite. A zero vector gives a flat surface (0, 0).
    """
    arr = np.asarray(n)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise InputError(f"normals must have shape (H, W, 3); got {arr.shape}")
    if not (max_slope > 0 and np.isfinite(max_slope)):
        raise InputError(f"max_slope must be a positive finite number; got {max_slope}")
    nx, ny, nz = (_finite(arr[..., i], np.float64, counter) for i in range(3))
    # Normalise by the largest component first so that tiny or huge vectors behave alike.
    big = np.maximum(np.maximum(np.abs(nx), np.abs(ny)), np.abs(nz))
    big = np.where(big > 0, big, 1.0)
    nx, ny, nz = nx / big, ny / big, nz / big
    # |n_z| is floored at 1/max_slope: beyond that slope the answer would be clipped anyway.
    floor = 1.0 / max_slope
    nz_safe = np.where(np.abs(nz) >= floor, nz, np.where(nz > 0, floor, -floor))
    gx = np.clip(-nx / nz_safe, -max_slope, max_slope)
    gy = np.clip(-ny / nz_safe, -max_slope, max_slope)
    return gx.astype(np.float32), gy.astype(np.float32)


def height_from_gradients(gx: object, gy: object, pixel_pitch: float = 1.0, *,
                          counter: NonFiniteCounter | None = None) -> np.ndarray:
    """Height map by least-squares Poisson integration of a gradient field.

    Solves min_h sum (h[i, j+1] - h[i, j] - p*gx~)^2 + (h[i+1, j] - h[i, j] - p*gy~)^2, where gx~, gy~ are the
    gradients averaged onto the half-pixel between the two samples and p = `pixel_pitch`. The normal equations are a
    Neumann Poisson problem, diagonalised by the DCT; we solve it with an FFT of the mirror-extended divergence
    (equivalent to the DCT-II, no SciPy needed). Non-integrable parts of the field (curl) are discarded, which is the
    least-squares answer, so noisy or inconsistent fields give a finite, smooth best fit.

    Shape: gx, gy: (H, W) slopes -> (H, W) float32 height in the unit of `pixel_pitch`, zero mean.

    Accuracy (tests/kiosk/contract/test_haptics.py, analytic gradients sampled at pixel centres, 128x96 px):
    sinusoid with a 32 px period: relative RMS error < 1 %; paraboloid: < 0.5 %; a height step given as
    central-difference gradients: plateau difference within 1 % of the step, no overshoot beyond 2 %.
    Cost: two real FFTs of (2H, 2W), O(HW log HW); it is not on the kiosk's hot path (docs/performance.md).
    """
    if not (isinstance(pixel_pitch, (int, float, np.floating, np.integer))
            and np.isfinite(pixel_pitch) and pixel_pitch > 0):
        raise InputError(f"pixel_pitch must be a positive finite number; got {pixel_pitch!r}")
    ax, ay = sanitize_gradients(gx, gy, counter=counter, dtype=np.float64)
    h, w = ax.shape
    # Slopes above this are clipped: they are non-physical and would overflow the squared sums below.
    ax = np.clip(ax, -1e12, 1e12) * pixel_pitch
    ay = np.clip(ay, -1e12, 1e12) * pixel_pitch
    # Half-pixel differences: fx[:, j] links column j and j+1; fy[i, :] links row i and i+1.
    fx = 0.5 * (ax[:, :-1] + ax[:, 1:])
    fy = 0.5 * (ay[:-1, :] + ay[1:, :])
    # Divergence (normal-equation right-hand side) with Neumann boundary: A^T f.
    div = np.zeros((h, w), dtype=np.float64)
    div[:, :-1] -= fx
    div[:, 1:] += fx
    div[:-1, :] -= fy
    div[1:, :] += fy
    # Mirror-extend to (2H, 2W): the periodic Laplacian there equals the Neumann Laplacian here.
    ext = np.concatenate([div, div[::-1, :]], axis=0)
    ext = np.concatenate([ext, ext[:, ::-1]], axis=1)
    spec = np.fft.rfft2(ext)
    # Eigenvalues of A^T A (the negative Laplacian) on the periodic (2H, 2W) grid; >= 0, zero only at DC.
    ky = 2.0 - 2.0 * np.cos(np.pi * np.arange(2 * h) / h)
    kx = 2.0 - 2.0 * np.cos(np.pi * np.arange(spec.shape[1]) / w)
    lam = ky[:, None] + kx[None, :]
    lam[0, 0] = 1.0  # the mean is free; fixed to zero below
    spec = spec / lam
    spec[0, 0] = 0.0
    height = np.fft.irfft2(spec, s=ext.shape)[:h, :w]
    height -= height.mean()
    return height.astype(np.float32)


def calibrate_scale(gx: object, gy: object, mask: object | None = None, *, quantile: float = 0.98) -> float:
    """The friction `scale` for a garment: a high quantile of gx^2 + gy^2 over its (masked) training gradients.

    Computed once from training data and stored in the bundle, so every frame of a garment uses the same mapping
    and a flat garment stays low-friction. Floored at MIN_FRICTION_SCALE (a slope of 0.01) so that an all-flat
    calibration set cannot make sensor noise feel like a ridge.
    """
    if not 0.0 < quantile <= 1.0:
        raise InputError(f"quantile must be in (0, 1]; got {quantile}")
    gz = _contact_energy(gx, gy, mask)
    if gz.size == 0:
        return MIN_FRICTION_SCALE
    return float(max(np.quantile(gz, quantile), MIN_FRICTION_SCALE))


def _contact_energy(gx: object, gy: object, mask: object | None) -> np.ndarray:
    """gx^2 + gy^2 at the contact pixels, finite, as one flat array: what both calibrations take quantiles of."""
    ax, ay = sanitize_gradients(gx, gy, dtype=np.float64)
    gz = ax * ax + ay * ay
    if mask is not None:
        m = np.asarray(mask)
        if m.shape != gz.shape:
            raise InputError(f"mask must have the gradients' shape {gz.shape}; got {m.shape}")
        gz = gz[m.astype(bool)]
    return gz[np.isfinite(gz)]


def _min_max(a: np.ndarray) -> np.ndarray:
    """Stretch to [0, 1]; a constant array maps to 0 instead of dividing by a zero range."""
    lo, hi = float(a.min()), float(a.max())
    rng = hi - lo
    if not rng > 1e-12:
        return np.zeros_like(a)
    return (a - lo) / rng


def jnd_steps(levels: object, *, threshold_level: float = THRESHOLD_LEVEL,
              jnd_ratio: float = JND_RATIO) -> np.ndarray:
    """Friction levels (0..255) -> just-noticeable steps above natural friction: 0 at or below the detection
    threshold, then log(level / threshold) / log(jnd_ratio) (Weber's law). Shape: any -> same, float64."""
    if not (threshold_level > 0 and jnd_ratio > 1 and np.isfinite(threshold_level) and np.isfinite(jnd_ratio)):
        raise InputError(f"threshold_level must be > 0 and jnd_ratio > 1; got {threshold_level}, {jnd_ratio}")
    lv = np.nan_to_num(np.asarray(levels, dtype=np.float64), nan=0.0, posinf=255.0, neginf=0.0)
    return np.log(np.maximum(lv, threshold_level) / threshold_level) / np.log(jnd_ratio)


def perceptual_constants(gx: object, gy: object, mask: object | None = None,
                         **overrides: float) -> dict[str, float]:
    """The `perceptual` mapping's constants for one garment, from its training gradients (contact pixels).

    The lower and upper quartiles of gx^2 + gy^2 describe the plain fabric: seams, pockets and edges cover a few
    per cent of a garment, so they move the quartiles little and are left to saturate. Quartiles below the flat
    floor are lifted to it, so a flat garment keeps its noise at natural friction. Stored in the bundle.
    """
    c = dict(PERCEPTUAL_DEFAULTS)
    for k, v in overrides.items():
        if k not in c:
            raise InputError(f"unknown perceptual constant {k!r} (known: {', '.join(sorted(c))})")
        c[k] = float(v)
    gz = _contact_energy(gx, gy, mask)
    floor = c["floor_slope"] ** 2
    lo, hi = (np.quantile(gz, (0.25, 0.75)) if gz.size else (floor, floor))
    c["gz_low"] = float(max(lo, floor))
    c["gz_high"] = float(max(hi, c["gz_low"] * 1.01))
    return _check_perceptual(c)


def check_constants(normalization: str, constants: Mapping[str, float]) -> None:
    """Raise InputError unless `constants` fit `normalization` (a bundle's stored mapping)."""
    if normalization not in NORMALIZATIONS:
        raise InputError(f"normalization must be one of {', '.join(NORMALIZATIONS)}; got {normalization!r}")
    if normalization == "perceptual":
        _check_perceptual(constants)
    elif constants:
        raise InputError(f"the {normalization} mapping takes no constants beyond friction_scale; "
                         f"got {', '.join(sorted(constants))}")


def _check_perceptual(c: Mapping[str, float]) -> dict[str, float]:
    need = set(PERCEPTUAL_DEFAULTS) | {"gz_low", "gz_high"}
    missing = sorted(need - set(c))
    if missing:
        raise InputError(f"perceptual friction constants are missing {', '.join(missing)}")
    out = {k: float(c[k]) for k in need}
    if not all(np.isfinite(v) for v in out.values()):
        raise InputError("perceptual friction constants must be finite")
    if not (out["threshold_level"] > 0 and out["jnd_ratio"] > 1 and out["floor_slope"] > 0
            and out["steps_per_octave"] > 0 and out["steps_span"] > 0 and out["gz_low"] > 0
            and out["gz_high"] > out["gz_low"] and np.log(out["gz_high"] / out["gz_low"]) > 0):
        raise InputError(f"perceptual friction constants are out of range: {out}")
    return out


def _perceptual(gz: np.ndarray, c: Mapping[str, float]) -> np.ndarray:
    """gx^2 + gy^2 -> friction in [0, 1] on the just-noticeable-step scale (see `friction_map`), in place in `gz`."""
    k = _check_perceptual(c)
    dt = gz.dtype.type
    floor = k["floor_slope"] ** 2
    # The fabric's quartiles land on fixed steps; log slope is the compressive curve between and beyond them:
    # rel = steps_low + steps_span * (log gz - log gz_low) / log(gz_high / gz_low).
    rel_a = k["steps_span"] / np.log(k["gz_high"] / k["gz_low"])
    rel_b = k["steps_low"] - rel_a * np.log(k["gz_low"])
    # Never more steps than the slope itself grants above the flat floor (a doubling of |slope| is a factor 4 in
    # gz): however the garment was calibrated, a flat one cannot be stretched into texture.
    abs_a = k["steps_per_octave"] / np.log(4.0)
    abs_b = -abs_a * np.log(floor)
    # Felt (steps > 0) where both lines are above 0; decided on gz itself, before the log's rounding (about 1e-6
    # in log gz in float32), so float32 and float64 disagree only within float32's rounding of the threshold slope.
    felt = gz > dt(max(floor, k["gz_low"] * np.exp(-k["steps_low"] / rel_a)))
    lg = np.log(np.maximum(gz, dt(max(floor * 1e-12, np.finfo(dt).tiny)), out=gz), out=gz)  # +Inf stays +Inf
    absolute = lg * dt(abs_a)
    absolute += dt(abs_b)
    steps = np.multiply(lg, dt(rel_a), out=lg)
    steps += dt(rel_b)
    np.minimum(steps, absolute, out=steps)
    # Level = threshold * jnd_ratio^steps; beyond `top` steps it exceeds 255 and saturates, so clip there first.
    top = np.log(255.0 / k["threshold_level"]) / np.log(k["jnd_ratio"])
    np.clip(steps, 0.0, dt(max(top, 0.0)), out=steps)
    steps *= dt(np.log(k["jnd_ratio"]))
    steps += dt(np.log(k["threshold_level"] / 255.0))
    level = np.exp(steps, out=steps)
    level *= felt
    return np.minimum(level, dt(1.0), out=level)


def friction_map(gx: object, gy: object, scale: float | None, size: tuple[int, int] | None = None, *,
                 normalization: Normalization = "calibrated", quantile: float = 0.98,
                 constants: Mapping[str, float] | None = None, supersample: int = SUPERSAMPLE,
                 precision: Precision = "float32", counter: NonFiniteCounter | None = None) -> np.ndarray:
    """The 8-bit friction map the haptic screen renders (paper Sec. 4.4).

    calibrated (default): z = clip((gx^2 + gy^2) / scale, 0, 1), z' = log10(9 z + 1), where `scale` is the garment's
    calibrated constant (`calibrate_scale`, stored in the bundle). The same surface always feels the same.
    quantile: the published per-frame mapping, for comparison: gz clipped at its `quantile`, min-max to [0, 1],
    log10(9 gz + 1), min-max again. It stretches a nearly flat garment to full friction; `scale` is ignored.
    perceptual: friction levels on the just-noticeable-step scale (`constants`, from `perceptual_constants`,
    stored in the bundle): the fabric's lower/upper gz quartiles land `steps_low` and `steps_low + steps_span` steps
    above the detection threshold, log(gz) is linear in steps between and beyond them, seams saturate at 255, and
    no pixel gets more than `steps_per_octave` steps per doubling of its slope above `floor_slope` (below it:
    natural friction). `scale` is ignored. Level = threshold_level * jnd_ratio^steps.

    If `size` = (width, height) is given, the result has the device panel's pixels, each the mean friction over its
    area of the surface the slopes describe (interpolated linearly between model pixels): the slopes are
    interpolated to a grid at least as fine as the panel and `supersample` times finer than the input, mapped
    there, then area-averaged to the panel. The map is nonlinear (a squared slope doubles a ridge's frequency), so
    mapping at the model's own pixels aliases its fine ridges into a false coarser texture, and interpolating the
    friction instead would blur away the fine texture the finger should feel. `supersample=1` maps at the finer
    of the two grids per axis, as kiosks did before. Quantised: 0 = natural friction, 255 = maximum added friction.

    `precision`: float32 (the kiosk's) computes every pass in float32, in place; float64 is the reference it is
    tested against (docs/haptics.md states the largest level difference between them). The quantile mapping, and
    constants that float32 cannot carry precisely (see `_working_dtype`), are computed in float64 either way.

    Shape: gx, gy: (H, W) -> (H, W) uint8, or (height, width) uint8 when `size` is given.

    Example:
        >>> friction_map(np.zeros((4, 4)), np.zeros((4, 4)), scale=0.05).max()
        0
    """
    if precision not in PRECISIONS:
        raise InputError(f"precision must be one of {', '.join(PRECISIONS)}; got {precision!r}")
    dt = np.float32 if precision == "float32" else np.float64
    if normalization == "calibrated":
        if scale is None or isinstance(scale, bool) or not isinstance(scale, (int, float, np.floating, np.integer)) \
                or not np.isfinite(scale) or scale <= 0:
            raise InputError(f"friction scale must be a positive finite number (from the bundle's calibration); "
                             f"got {scale!r}")
    elif normalization == "perceptual":
        if constants is None:
            raise InputError("the perceptual friction mapping needs its constants (from the bundle)")
        _check_perceptual(constants)
    elif normalization == "quantile":
        if not 0.0 < quantile <= 1.0:
            raise InputError(f"quantile must be in (0, 1]; got {quantile}")
    else:
        raise InputError(f"normalization must be one of {', '.join(NORMALIZATIONS)}; got {normalization!r}")
    saturation = _saturation_gz(normalization, scale, constants)
    dt = _working_dtype(dt, normalization, saturation, constants)
    ax, ay = sanitize_gradients(gx, gy, counter=counter, dtype=dt)
    # Slopes far beyond saturation are clipped before interpolation: squares cannot overflow, and +Inf and -Inf
    # neighbours cannot interpolate to NaN. SATURATION_MARGIN times the saturating slope keeps every interpolated
    # value that saturated unclipped saturated (no interpolation weight is below 1 / (2 MAX_SIDE)), and keeps the
    # float32 cancellation between huge opposite slopes far below a level. New arrays: the caller's input is never
    # modified, and every later pass works in place.
    limit = dt(min(SATURATION_MARGIN * np.sqrt(saturation), SLOPE_LIMIT[np.dtype(dt).name]))
    ax, ay = np.clip(ax, -limit, limit), np.clip(ay, -limit, limit)
    out_size = None
    if size is not None:
        w, h = check_size(size, "device pixels")
        if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) \
                or not 1 <= supersample <= 8:
            raise InputError(f"supersample must be an integer from 1 to 8; got {supersample!r}")
        fine = (max(w, int(supersample) * ax.shape[1]), max(h, int(supersample) * ax.shape[0]))
        if fine != (ax.shape[1], ax.shape[0]):
            ax = _resize(ax, fine, cv2.INTER_LINEAR)
            ay = _resize(ay, fine, cv2.INTER_LINEAR)
        if fine != (w, h):
            out_size = (w, h)
    gain = 255.0
    if normalization == "calibrated":
        # z' = log10(9 min(gz / scale, 1) + 1); the 1/ln 10 of log10 is applied after the (linear) area average.
        gz = _squared_slope(ax, ay)
        with np.errstate(over="ignore"):  # a product beyond the range is +Inf, which saturates below
            factor = dt(9.0 / scale)
            if np.isfinite(factor):
                gz *= factor  # factor > 0: 9 / a finite scale does not underflow in the working dtype, no Inf * 0
                np.minimum(gz, dt(9.0), out=gz)  # also turns an overflowed square (+Inf) into full friction
            else:  # a subnormal scale: any slope at all saturates (and 0 * Inf would be NaN)
                np.multiply(gz > 0, dt(9.0), out=gz)
        gz += dt(1.0)
        zp = np.log(gz, out=gz)
        gain = 255.0 / np.log(10.0)
    elif normalization == "perceptual":
        zp = _perceptual(_squared_slope(ax, ay), constants)
    else:  # per-frame quantile and min-max: the comparison mapping, always in float64
        with np.errstate(over="ignore"):
            g64 = np.minimum(ax * ax + ay * ay, 1e300)
        g64 = np.minimum(g64, np.quantile(g64, quantile))
        zp = _min_max(np.log10(9.0 * _min_max(g64) + 1.0)).astype(dt)
    if out_size is not None:
        # The mean friction over each panel pixel: the pixel-constant frame closest to the mapped surface.
        zp = _resize(zp, out_size, cv2.INTER_AREA)
    zp *= dt(gain)
    np.clip(zp, 0.0, 255.0, out=zp)
    return np.rint(zp, out=zp).astype(np.uint8)


def _saturation_gz(normalization: str, scale: float | None, constants: Mapping[str, float] | None) -> float:
    """The gx^2 + gy^2 beyond which the mapping gives full friction (+Inf for the per-frame quantile mapping)."""
    if normalization == "calibrated":
        return float(scale)
    if normalization == "perceptual":
        k = _check_perceptual(constants)
        rel_a = k["steps_span"] / np.log(k["gz_high"] / k["gz_low"])
        abs_a = k["steps_per_octave"] / np.log(4.0)
        top = max(np.log(255.0 / k["threshold_level"]) / np.log(k["jnd_ratio"]), 0.0)
        # where both lines (see `_perceptual`) reach the step whose level is 255
        log_gz = max(np.log(k["gz_low"]) + (top - k["steps_low"]) / rel_a, np.log(k["floor_slope"] ** 2) + top / abs_a)
        return float(np.exp(min(log_gz, 700.0)))
    return float("inf")


def _working_dtype(dt: type, normalization: str, saturation_gz: float, constants: Mapping[str, float] | None) -> type:
    """float64 where float32 would be imprecise: the quantile mapping (its min-max stretches a rounding to the full
    range), a saturation point near float32's range limits, or perceptual quartiles so close that a step is a cliff
    in log(gz)."""
    if dt is np.float64 or normalization == "quantile":
        return np.float64
    if not 1e-30 <= saturation_gz <= 1e26:  # SATURATION_MARGIN * its root must stay within SLOPE_LIMIT
        return np.float64
    if normalization == "perceptual":
        k = _check_perceptual(constants)
        if k["steps_span"] / np.log(k["gz_high"] / k["gz_low"]) > MAX_FLOAT32_STEPS_PER_LOG:
            return np.float64
    return dt


def _squared_slope(ax: np.ndarray, ay: np.ndarray) -> np.ndarray:
    """ax^2 + ay^2, in place in `ax` (both are the map's own arrays)."""
    gz = np.multiply(ax, ax, out=ax)
    gz += np.multiply(ay, ay, out=ay)
    return gz


def _resize(a: np.ndarray, size: tuple[int, int], interpolation: int) -> np.ndarray:
    w, h = size
    out = cv2.resize(a, (w, h), interpolation=interpolation)
    return out.reshape(h, w)  # cv2 drops a unit axis for 1-pixel-high results
