"""Error of a lower-precision graph against the fp32 graph, in the units that matter at the kiosk: visual PSNR
(dB), tactile mean absolute error (slope units), friction-map mean absolute error (uint8 levels), averaged over the
exporter's held-out sketches.

The per-input figures are `kiosk.contract.accuracy.deviation`, the same definition `engine: auto` holds another
engine to; the friction error is stated over the whole grid (`friction_mae_levels`, the figure export bounds) and
over the garment alone (`friction_mae_garment_levels`, what a finger on the garment feels), with the share of the
garment's pixels a just-noticeable step or more off (`friction_felt_garment_fraction`).

`interior_errors` asks where the largest friction errors sit once the place of an edge is set aside (a seam's
outline moved by one pixel is 255 levels at that pixel and nothing a fingertip tells apart)."""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import cv2
import numpy as np
import onnxruntime as ort

from kiosk.contract.accuracy import deviation
from kiosk.contract.haptics import friction_map
from kiosk.contract.graph import feeds
from kiosk.contract.sketch import NetworkInput


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
    return compare_tested(reference, reference_outputs(test, outputs, inputs), inputs, friction_scale,
                          normalization=normalization, constants=constants)


def compare_tested(reference: Sequence[dict[str, np.ndarray]], tested: Sequence[dict[str, np.ndarray]],
                   inputs: Sequence[NetworkInput], friction_scale: float, *, normalization: str = "calibrated",
                   constants: Mapping[str, float] | None = None) -> dict[str, float]:
    """Like `compare_outputs` with the tested graph's outputs given too (a caller measuring them twice runs it once)."""
    vis, tac, fric, fric_in, felt, fric_max = [], [], [], [], [], 0.0
    for a, b, x in zip(reference, tested, inputs):
        d = deviation(a, b, x.mask, friction_scale, normalization=normalization, constants=constants)
        if "visual_psnr_db" in d:
            vis.append(d["visual_psnr_db"])
        if "tactile_mae" in d:
            tac.append(d["tactile_mae"])
            fric.append(d["friction_mae_levels"])
            if "friction_mae_garment_levels" in d:  # a sketch without a garment has no garment error to state
                fric_in.append(d["friction_mae_garment_levels"])
                felt.append(d["friction_felt_garment_fraction"])
            fric_max = max(fric_max, d["friction_max_levels"])
    out: dict[str, float] = {}
    if vis:
        out["visual_psnr_db"] = float(np.mean(vis))
    if tac:
        out["tactile_mae"] = float(np.mean(tac))
        out["friction_mae_levels"] = float(np.mean(fric))
        if fric_in:
            out["friction_mae_garment_levels"] = float(np.mean(fric_in))
            out["friction_felt_garment_fraction"] = float(np.mean(felt))
        out["friction_max_levels"] = fric_max
    return out


EDGE_LEVELS = 64      # a reference pixel whose 3x3 neighbourhood spans this many levels is on an edge
OUTLINE_PX = 2        # garment pixels this close to the garment's outline are on its edge too
BIG_LEVELS = 64       # an interior error this large is counted (a quarter of the range; several JND steps)


def _spread3(a: np.ndarray) -> np.ndarray:
    """max - min over each pixel's 3x3 neighbourhood (the border repeats the edge)."""
    k = np.ones((3, 3), np.uint8)
    return cv2.dilate(a, k) - cv2.erode(a, k)


def _inner(mask: np.ndarray, px: int) -> np.ndarray:
    """Pixels of `mask` at least `px` pixels (chessboard distance) inside its outline."""
    k = np.ones((2 * px + 1, 2 * px + 1), np.uint8)
    return cv2.erode(mask.astype(np.uint8), k, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0


def interior_errors(reference: Sequence[dict[str, np.ndarray]], tested: Sequence[dict[str, np.ndarray]],
                    inputs: Sequence[NetworkInput],
                    friction_scale: float, *, normalization: str = "calibrated",
                    constants: Mapping[str, float] | None = None) -> dict[str, float]:
    """Friction errors off edges: garment pixels `OUTLINE_PX` inside the outline whose reference neighbourhood spans
    under `EDGE_LEVELS` levels. Returns the largest such error over `inputs` (levels), how many such pixels are
    `BIG_LEVELS` or more off (per input, mean) beside the garment's size in pixels (mean), the share of those where
    the reference is saturated (255: a seam or fold, `perceptual`'s top), and at the worst pixel the reference
    slope's percentile within the garment and the tested slope over the reference's.
    Inputs without a garment or without a tactile output add nothing; with none at all the dict is empty."""
    worst, worst_pct, worst_ratio, big, big_sat, size = -1.0, float("nan"), float("nan"), [], 0, []
    for a, b, x in zip(reference, tested, inputs):
        if "tactile" not in a:
            continue
        ta, tb = np.asarray(a["tactile"]), np.asarray(b["tactile"])
        fa, fb = (friction_map(t[0, 0], t[0, 1], friction_scale, normalization=normalization,
                               constants=constants).astype(np.int16) for t in (ta, tb))
        garment = np.asarray(x.mask).reshape(fa.shape) > 0.5
        inner = _inner(garment, OUTLINE_PX) & (_spread3(fa) < EDGE_LEVELS)
        if not inner.any():
            continue
        diff = np.abs(fa - fb)
        over = inner & (diff >= BIG_LEVELS)
        big.append(int(over.sum()))
        size.append(int(garment.sum()))
        big_sat += int((over & (fa >= 255)).sum())
        d = np.where(inner, diff, -1)
        j = np.unravel_index(int(np.argmax(d)), d.shape)
        if d[j] > worst:
            slope = np.hypot(ta[0, 0].astype(np.float64), ta[0, 1].astype(np.float64))
            got = float(np.hypot(float(tb[0, 0][j]), float(tb[0, 1][j])))
            worst, worst_pct = float(d[j]), 100.0 * float(np.mean(slope[garment] < slope[j]))
            worst_ratio = got / float(slope[j]) if slope[j] > 0 else float("nan")
    if not big:
        return {}
    total = sum(big)
    return {"friction_max_interior_levels": worst, "friction_interior_big_px": float(np.mean(big)),
            "garment_px": float(np.mean(size)),
            "friction_interior_big_saturated": (big_sat / total) if total else 0.0,
            "worst_interior_slope_percentile": worst_pct, "worst_interior_slope_ratio": worst_ratio}
