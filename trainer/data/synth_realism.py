"""The `hard` profile's camera-side realism: what makes a photo of cloth more than a shading of its touch field.

A real photograph of a garment is not a function of the slopes a GelSight measures: prints and dye vary the colour
with no relief, seams in matching thread have relief and no colour, a fixed lamp lights the frame unevenly, folds
shade the cloth over centimetres without changing its weave, and the camera blurs and adds noise. Each effect is a
small function here; `render` applies them only when it is given a `Realism` (the `easy` profile gets none, so its
output stays bit-identical to the generator before profiles). docs/data.md says what each models and why.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from trainer.data.synth_fabrics import band_noise


@dataclass(frozen=True)
class Realism:
    """One garment's draw of the hard-profile effects (lengths in mm unless named _px).

    folds: (x0, y0, x1, y1, width_mm, amplitude_mm) per fold, a crease along a segment in frame px.
    wrinkle_mm: std of the centimetre-scale wrinkle height. print_kind: "dots" | "check" | "blotch" | "none";
    print_period_mm; print_rgb: colour of the print. mottle: std of the relative dye variation.
    lamp_xy_mm: lamp position over the table (frame origin = top-left corner), lamp_height_mm above it.
    blur_px: Gaussian sigma of the lens + sensor MTF. read_noise, shot_gain: sensor noise (0..1 intensity units).
    """

    folds: tuple[tuple[float, float, float, float, float, float], ...]
    wrinkle_mm: float
    print_kind: str
    print_period_mm: float
    print_rgb: tuple[float, float, float]
    mottle: float
    lamp_xy_mm: tuple[float, float]
    lamp_height_mm: float
    blur_px: float
    read_noise: float
    shot_gain: float
    seed: int


PRINTS = ("dots", "check", "blotch", "none")


def sample_realism(rng: np.random.Generator, *, frame: tuple[int, int], pitch_mm: float,
                   bbox: tuple[float, float, float, float], base_rgb: tuple[float, float, float]) -> Realism:
    """Draw one garment's effects: 2-5 folds across the garment (bbox x0, y0, x1, y1 in frame px), a print (or
    none), a lamp off to one side."""
    w, h = frame
    folds = []
    x0, y0, x1, y1 = (float(v) for v in bbox)
    if x1 > x0 and y1 > y0:
        for _ in range(int(rng.integers(2, 6))):
            cx, cy = rng.uniform(x0, x1), rng.uniform(y0, y1)
            ang = rng.uniform(0, np.pi)
            half = rng.uniform(0.15, 0.45) * max(x1 - x0, y1 - y0)
            dx, dy = half * np.cos(ang), half * np.sin(ang)
            folds.append((float(cx - dx), float(cy - dy), float(cx + dx), float(cy + dy),
                          float(rng.uniform(8.0, 25.0)), float(rng.uniform(2.0, 6.0) * rng.choice([-1.0, 1.0]))))
    kind = str(rng.choice(PRINTS, p=[0.3, 0.25, 0.25, 0.2]))
    lum = 0.3 * base_rgb[0] + 0.59 * base_rgb[1] + 0.11 * base_rgb[2]
    # a print in a colour of its own, halfway to the cloth's, lighter on dark cloth and darker on light cloth
    hue = rng.uniform(0.15, 0.95, 3) * (1.0 if lum < 0.45 else 0.5)
    print_rgb = tuple(float(c) for c in 0.5 * (hue + np.asarray(base_rgb)))
    side = rng.choice([-1.0, 1.0])
    w_mm, h_mm = w * pitch_mm, h * pitch_mm
    return Realism(folds=tuple(folds), wrinkle_mm=float(rng.uniform(0.2, 0.5)), print_kind=kind,
                   print_period_mm=float(rng.uniform(8.0, 25.0)), print_rgb=print_rgb,
                   mottle=float(rng.uniform(0.03, 0.07)),
                   # off to one side and above the top edge, about as high as the frame is wide: light at
                   # 35-55 deg elevation, so folds shade, and an irradiance falling off across the frame
                   lamp_xy_mm=(float(w_mm * (0.5 + side * rng.uniform(0.6, 1.0))),
                               float(h_mm * rng.uniform(-0.5, 0.1))),
                   lamp_height_mm=float(w_mm * rng.uniform(0.9, 1.3)), blur_px=float(rng.uniform(0.9, 1.4)),
                   read_noise=float(rng.uniform(1.5, 3.0) / 255), shot_gain=float(rng.uniform(2e-5, 6e-5)),
                   seed=int(rng.integers(2**31)))


def fold_height(shape: tuple[int, int], mask: np.ndarray, real: Realism, pitch_mm: float) -> np.ndarray:
    """Low-frequency height (mm) of folds and wrinkles over the garment, zero on the table.

    Each fold is a Gaussian crease across a segment, fading towards the segment's ends; wrinkles are band-limited
    noise at 10-20 mm. Nothing here is finer than about 5 mm, so the weave keeps its own slopes.
    """
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    out = np.zeros(shape, np.float32)
    for x0, y0, x1, y1, width_mm, amp in real.folds:
        d = np.array([x1 - x0, y1 - y0], np.float32)
        length = float(np.hypot(*d)) or 1.0
        t = ((xx - x0) * d[0] + (yy - y0) * d[1]) / np.float32(length * length)
        px, py = x0 + t * d[0], y0 + t * d[1]
        dist_mm = np.hypot(xx - px, yy - py) * np.float32(pitch_mm)
        along = np.clip(1.0 - np.abs(2.0 * t - 1.0), 0.0, 1.0)
        out += np.float32(amp) * np.exp(-(dist_mm / np.float32(width_mm)) ** 2) * np.sin(np.pi / 2 * along) ** 2
    rng = np.random.default_rng(real.seed)
    out += np.float32(real.wrinkle_mm) * band_noise(rng, shape, 12.0 / pitch_mm)
    # fade to the edge over ~5 mm so the silhouette stays where the mask says
    dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5) * np.float32(pitch_mm)
    return (out * np.clip(dist / 5.0, 0.0, 1.0)).astype(np.float32)


def print_alpha(shape: tuple[int, int], real: Realism, pitch_mm: float, u_map: np.ndarray) -> np.ndarray:
    """Coverage (0..1) of a flat print: dots, a check along the grain, or soft dye blotches. No relief."""
    h, w = shape
    p = np.float32(real.print_period_mm / pitch_mm)
    if real.print_kind == "none":
        return np.zeros(shape, np.float32)
    if real.print_kind == "blotch":
        rng = np.random.default_rng(real.seed + 1)
        n = band_noise(rng, shape, float(p) / 3)
        return np.clip((n - 0.6) * 3.0, 0.0, 1.0).astype(np.float32)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    if real.print_kind == "dots":
        # a half-drop dot grid: every other row shifted by half a period
        row = np.floor(yy / p)
        fx = np.mod(xx / p + 0.5 * np.mod(row, 2), 1.0) - 0.5
        fy = np.mod(yy / p, 1.0) - 0.5
        r = np.hypot(fx, fy) * p
        return np.clip(0.22 * p - r + 0.5, 0.0, 1.0).astype(np.float32)
    # check: two sets of bands along and across the grain (u_map in mm across the grain)
    v = yy * np.float32(pitch_mm)
    a = (np.mod(u_map / real.print_period_mm, 1.0) < 0.25).astype(np.float32)
    b = (np.mod(v / real.print_period_mm, 1.0) < 0.25).astype(np.float32)
    return cv2.GaussianBlur(np.maximum(a, b) * 0.7, (0, 0), 0.7)


def mottle(shape: tuple[int, int], real: Realism, pitch_mm: float) -> np.ndarray:
    """Relative dye variation (H, W, 3) around 1, at 20-40 mm, slightly different per channel."""
    rng = np.random.default_rng(real.seed + 2)
    lum = band_noise(rng, shape, 25.0 / pitch_mm)
    tint = band_noise(rng, shape, 40.0 / pitch_mm)
    m = 1.0 + real.mottle * lum
    return np.stack([m + 0.3 * real.mottle * tint, m, m - 0.3 * real.mottle * tint], -1).astype(np.float32)


def lamp(shape: tuple[int, int], real: Realism, pitch_mm: float, height_mm: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel unit light direction (H, W, 3; x right, y down, z to camera) and inverse-square falloff,
    scaled so a flat patch at the frame centre receives 1 (falloff x cos of the light's zenith angle there)."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    lx, ly = real.lamp_xy_mm
    vx = np.float32(lx) - xx * np.float32(pitch_mm)
    vy = np.float32(ly) - yy * np.float32(pitch_mm)
    vz = np.float32(real.lamp_height_mm) - height_mm
    r2 = vx * vx + vy * vy + vz * vz
    inv = 1.0 / np.sqrt(r2)
    direction = np.stack([vx * inv, vy * inv, vz * inv], -1).astype(np.float32)
    cx, cy = w * pitch_mm / 2, h * pitch_mm / 2
    r2c = (lx - cx) ** 2 + (ly - cy) ** 2 + real.lamp_height_mm ** 2
    cos_c = real.lamp_height_mm / np.sqrt(r2c)
    return direction, (np.float32(r2c / cos_c) / r2).astype(np.float32)


def camera(img: np.ndarray, real: Realism) -> np.ndarray:
    """Lens + sensor MTF (Gaussian) and signal-dependent noise (shot + read), on an (H, W, 3) image in 0..1."""
    rng = np.random.default_rng(real.seed + 3)
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), real.blur_px)
    sigma = np.sqrt(np.clip(img, 0, None) * np.float32(real.shot_gain) + np.float32(real.read_noise) ** 2)
    return img + rng.standard_normal(img.shape, dtype=np.float32) * sigma
