"""A graph's outputs against a reference's, in the units the kiosk states errors in: visual PSNR (dB) and mean colour
difference (8-bit levels), tactile mean absolute slope difference, and the friction map's mean absolute difference
in its levels, over the whole grid and over the garment alone.

One definition for both sides that state or check an error: the exporter (a lower precision against fp32, written
into the bundle's manifest) and `engine: auto` (another engine against ONNX Runtime, held to what the bundle
states). Outside the garment both graphs output exactly 0 (the heads multiply by the mask), so the whole-grid
friction figure is the garment's diluted by the blank paper around it: about 3x smaller on a letterboxed canvas,
and nearly equal where the planner frames the garment to fill the grid. Comparing framings needs the garment figure.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from kiosk.contract.haptics import JND_RATIO, THRESHOLD_LEVEL, friction_map, jnd_steps

LEVELS_PER_UNIT = 127.5  # 8-bit colour levels per unit of the visual's tanh output
IDENTICAL_DB = 99.0      # the PSNR stated for identical images (no division by a zero error)


def psnr(a: np.ndarray, b: np.ndarray, *, peak: float = 2.0) -> float:
    """PSNR of two images in [-1, 1] (peak-to-peak 2); identical images give IDENTICAL_DB."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return IDENTICAL_DB if mse <= 1e-12 else float(10 * np.log10(peak * peak / mse))


def deviation(ref: Mapping[str, np.ndarray], got: Mapping[str, np.ndarray], mask: np.ndarray,
              friction_scale: float, *, normalization: str = "calibrated",
              constants: Mapping[str, float] | None = None) -> dict[str, float]:
    """How far `got` is from `ref` (graph outputs by name, (1, C, H, W)) for one input whose object mask is `mask`.

    Friction maps use the bundle's own mapping (`friction_scale`, `normalization`, `constants`): the error is in the
    levels the finger gets. A mask with no garment states no garment figure rather than dividing by zero.

    `friction_felt_garment_fraction` is the share of garment pixels whose two levels are a just-noticeable step or
    more apart (`jnd_steps`, with the bundle's threshold and ratio where it states them). The mean hides where the
    error sits and the maximum is set by one pixel (a seam's edge moved by a pixel is 255 levels there); this says
    how much of the garment a finger could tell apart, pixel by pixel. A fingertip spans many model pixels, so it
    is an upper bound on what is felt.
    """
    out: dict[str, float] = {}
    if "visual" in ref:
        out["visual_psnr_db"] = psnr(ref["visual"], got["visual"])
        out["visual_mae_levels"] = LEVELS_PER_UNIT * float(np.mean(np.abs(
            np.asarray(ref["visual"], np.float64) - np.asarray(got["visual"], np.float64))))
    if "tactile" in ref:
        a, b = np.asarray(ref["tactile"]), np.asarray(got["tactile"])
        out["tactile_mae"] = float(np.mean(np.abs(a.astype(np.float64) - b.astype(np.float64))))
        fa, fb = (friction_map(t[0, 0], t[0, 1], friction_scale, normalization=normalization,
                               constants=constants).astype(np.int16) for t in (a, b))
        diff = np.abs(fa - fb)
        out["friction_mae_levels"] = float(np.mean(diff))
        inside = np.asarray(mask).reshape(diff.shape) > 0.5
        if inside.any():
            out["friction_mae_garment_levels"] = float(np.mean(diff[inside]))
            k = constants or {}
            steps = [jnd_steps(f[inside], threshold_level=k.get("threshold_level", THRESHOLD_LEVEL),
                               jnd_ratio=k.get("jnd_ratio", JND_RATIO)) for f in (fa, fb)]
            out["friction_felt_garment_fraction"] = float(np.mean(np.abs(steps[0] - steps[1]) >= 1.0))
        out["friction_max_levels"] = float(diff.max())
    return out
