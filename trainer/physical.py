"""What a trained model means physically: the pitch its pixels have, and its friction mapping's constants.

The model learns texture at the dataset's pixels, so its pitch is the dataset's: a synthetic garment records its
own (`synthetic.yaml`, `fullT/` files); the published TouchClothing capture resamples each 32 x 24 mm GelSight
touch to 104 x 78 pixels to match the camera image (paper Sec. 3, "about 300 micrometers per pixel"), i.e.
32 / 104 = 0.3077 mm/px (docs/data.md). The exporter writes both into the bundle.
"""
from __future__ import annotations

import numpy as np

from kiosk.contract.haptics import perceptual_constants
from trainer.data.touchclothing import DatasetError, Garment

# GelSight R1.5 sensing area 32 mm x 24 mm (H x W) resampled to 104 x 78 px to match the camera frame.
TOUCHCLOTHING_PITCH_MM = 32.0 / 104.0
# How far from a sketch stroke the relief it draws reaches: a seam's or an edge's ridge (Gaussian, 1-1.2 px at the
# synthetic renderer's 0.3 mm pitch) plus a stroke's offset from it (the sketch is an edge map of the photo). The
# evaluator's "by a line" region and test-time mirroring's `-lines` band are both this reach.
LINE_REACH_MM = 1.2


def dataset_pitch_mm(g: Garment) -> tuple[float, str]:
    """(mm per pixel, where it comes from) for one garment folder."""
    if g.full_tactile is not None and g.full_tactile.pixel_pitch_mm > 0:
        return float(g.full_tactile.pixel_pitch_mm), "synthetic full-field truth"
    v = g.pixel_pitch_mm  # synthetic.yaml's, when the garment states one
    if v is not None and np.isfinite(v) and v > 0:
        return float(v), "synthetic.yaml"
    return TOUCHCLOTHING_PITCH_MM, "TouchClothing capture (32 mm / 104 px)"


def friction_constants(g: Garment, normalization: str, split: str = "train") -> dict[str, float]:
    """The mapping's constants from the garment's measured contact pixels (the ones `friction_scale` uses);
    empty for mappings that have none beyond the scale."""
    if normalization != "perceptual":
        return {}
    touches = g.touches.get(split, [])
    if not touches:
        raise DatasetError(f"{g.name}: no {split} touches to calibrate the friction mapping from")
    gx = np.concatenate([t.gx[t.contact] for t in touches])[None, :]
    gy = np.concatenate([t.gy[t.contact] for t in touches])[None, :]
    return perceptual_constants(gx, gy)
