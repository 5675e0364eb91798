"""Sketches for int8 calibration and for measuring quantization error: the garment's own sketch, augmented
variants and synthetic stroke edits, at the sizes the kiosk will run.

Calibrating at the resolution of use matters: activation ranges of this U-Net change with the input size
(calibrating at 512 and running at 1536 lost about 14 dB PSNR: the ranges seen at 512 clip the larger ones). The error set uses a different
seed than the calibration set, so quantization is judged on sketches it was not calibrated on.
"""
from __future__ import annotations

import cv2
import numpy as np

from kiosk.contract.sketch import INK, NetworkInput, letterbox, network_input, object_mask, rasterize


def _augment(sketch: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Scale 0.85-1.1, shift up to 8 %, optional mirror: the garment drawn a little differently."""
    h, w = sketch.shape
    s = rng.uniform(0.85, 1.1)
    tx, ty = rng.uniform(-0.08, 0.08) * w, rng.uniform(-0.08, 0.08) * h
    m = np.array([[s, 0, (1 - s) * w / 2 + tx], [0, s, (1 - s) * h / 2 + ty]], np.float32)
    out = cv2.warpAffine(sketch, m, (w, h), flags=cv2.INTER_NEAREST, borderValue=255)
    return out[:, ::-1].copy() if rng.random() < 0.5 else out


def _stroke_edit(sketch: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Add a few strokes inside the garment (a pocket, a seam, a doodle) and erase a short piece of line."""
    h, w = sketch.shape
    mask = object_mask(sketch)
    ys, xs = np.nonzero(mask)
    out = sketch.copy()
    if len(xs) == 0:
        return out
    strokes = []
    for _ in range(int(rng.integers(1, 4))):
        i = int(rng.integers(len(xs)))
        x0, y0 = xs[i], ys[i]
        n = int(rng.integers(2, 6))
        pts = np.cumsum(rng.normal(0, 0.05 * min(h, w), size=(n, 2)), axis=0) + (x0, y0)
        strokes.append(pts)
    out = rasterize(strokes, (w, h), base=out)
    ink_y, ink_x = np.nonzero(out == INK)
    if len(ink_x):
        j = int(rng.integers(len(ink_x)))
        r = max(2, int(0.015 * min(h, w)))
        inner = cv2.erode(mask.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
        if inner[ink_y[j], ink_x[j]]:  # never break the outline: the mask must survive
            cv2.circle(out, (int(ink_x[j]), int(ink_y[j])), r, 255, -1)
    return out


def sketch_variants(sketch: np.ndarray, sizes: list[tuple[int, int]], *, per_size: int, seed: int
                    ) -> list[NetworkInput]:
    """For each (width, height): the sketch itself, then `per_size - 1` variants alternating augment / edit."""
    rng = np.random.default_rng(seed)
    inputs = []
    for size in sizes:
        base, _ = letterbox(sketch, size)
        for k in range(per_size):
            s = base if k == 0 else (_augment(base, rng) if k % 2 else _stroke_edit(_augment(base, rng), rng))
            inputs.append(network_input(s, object_mask(s)))
    return inputs


HELD_OUT_SEED = 1000  # added to the calibration seed: errors are measured on sketches int8 was not calibrated on


def calibration_set(sketch: np.ndarray, sizes: list[tuple[int, int]], per_size: int, seed: int = 0
                    ) -> list[NetworkInput]:
    """int8 calibration sketches: the garment's own and its variants at every size the kiosk may run."""
    return sketch_variants(sketch, sizes, per_size=per_size, seed=seed)


def held_out_set(sketch: np.ndarray, sizes: list[tuple[int, int]], per_size: int, seed: int = 0
                 ) -> list[NetworkInput]:
    """Sketches for measuring error against fp32 (exporter and benchmark use the same ones)."""
    return sketch_variants(sketch, sizes, per_size=per_size, seed=seed + HELD_OUT_SEED)
