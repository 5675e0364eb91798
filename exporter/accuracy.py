"""Error of a lower-precision graph against the fp32 graph, in the units that matter at the kiosk:
visual PSNR (dB), tactile mean absolute error (slope units), friction-map mean absolute error (uint8 levels).

The friction error is stated twice: over the whole grid (`friction_mae_levels`, the figure export bounds) and over
the garment alone (`friction_mae_garment_levels`, what a finger on the garment feels). Outside the garment both
graphs output exactly 0 (the heads multiply by the mask), so the whole-grid mean is the garment's mean diluted by
the blank paper around it: about 3x smaller on a letterboxed canvas, and nearly equal where the planner frames the
garment to fill the grid. Comparing framings needs the garment figure."""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import onnxruntime as ort

from kiosk.contract.graph import feeds
from kiosk.contract.haptics import friction_map
from kiosk.contract.sketch import NetworkInput


def psnr(a: np.ndarray, b: np.ndarray, *, peak: float = 2.0) -> float:
    """PSNR of two images in [-1, 1] (peak-to-peak 2); identical images give +inf, reported as 99 dB."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 99.0 if mse <= 1e-12 else float(10 * np.log10(peak * peak / mse))


def compare_sessions(ref: ort.InferenceSession, test: ort.InferenceSession, outputs: list[str],
                     inputs: Sequence[NetworkInput], friction_scale: float, *, normalization: str = "calibrated",
                     constants: Mapping[str, float] | None = None) -> dict[str, float]:
    """Mean over `inputs` of each error; the worst friction-map error is reported too. Friction maps use the
    bundle's own mapping (`normalization`, `constants`): the error is in the levels the finger gets."""
    return compare_outputs(reference_outputs(ref, outputs, inputs), test, outputs, inputs, friction_scale,
                           normalization=normalization, constants=constants)


def reference_outputs(ref, outputs: list[str], inputs: Sequence[NetworkInput]) -> list[dict[str, np.ndarray]]:
    """The reference's outputs for each input, computed once (the benchmark compares many graphs against them)."""
    return [dict(zip(outputs, ref.run(outputs, feeds(x.sketch, x.mask)))) for x in inputs]


def compare_outputs(reference: Sequence[dict[str, np.ndarray]], test, outputs: list[str],
                    inputs: Sequence[NetworkInput], friction_scale: float, *, normalization: str = "calibrated",
                    constants: Mapping[str, float] | None = None) -> dict[str, float]:
    """Like `compare_sessions` with the reference outputs given; `test` is anything with ORT's `run(names, feed)`."""
    vis, tac, fric, fric_in, fric_max = [], [], [], [], 0.0
    for a, x in zip(reference, inputs):
        b = dict(zip(outputs, test.run(outputs, feeds(x.sketch, x.mask))))
        if "visual" in a:
            vis.append(psnr(a["visual"], b["visual"]))
        if "tactile" in a:
            tac.append(float(np.mean(np.abs(a["tactile"] - b["tactile"]))))
            fa = friction_map(a["tactile"][0, 0], a["tactile"][0, 1], friction_scale, normalization=normalization,
                              constants=constants).astype(np.int16)
            fb = friction_map(b["tactile"][0, 0], b["tactile"][0, 1], friction_scale, normalization=normalization,
                              constants=constants).astype(np.int16)
            diff = np.abs(fa - fb)
            fric.append(float(np.mean(diff)))
            inside = np.asarray(x.mask).reshape(diff.shape) > 0.5
            if inside.any():  # a sketch without a garment has no garment error to state
                fric_in.append(float(np.mean(diff[inside])))
            fric_max = max(fric_max, float(diff.max()))
    out: dict[str, float] = {}
    if vis:
        out["visual_psnr_db"] = float(np.mean(vis))
    if tac:
        out["tactile_mae"] = float(np.mean(tac))
        out["friction_mae_levels"] = float(np.mean(fric))
        if fric_in:
            out["friction_mae_garment_levels"] = float(np.mean(fric_in))
        out["friction_max_levels"] = fric_max
    return out
