"""Error of a lower-precision graph against the fp32 graph, in the units that matter at the kiosk: visual PSNR
(dB), tactile mean absolute error (slope units), friction-map mean absolute error (uint8 levels), averaged over the
exporter's held-out sketches.

The per-input figures are `kiosk.contract.accuracy.deviation`, the same definition `engine: auto` holds another
engine to; the friction error is stated over the whole grid (`friction_mae_levels`, the figure export bounds) and
over the garment alone (`friction_mae_garment_levels`, what a finger on the garment feels), with the share of the
garment's pixels a just-noticeable step or more off (`friction_felt_garment_fraction`)."""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import onnxruntime as ort

from kiosk.contract.accuracy import deviation
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
    vis, tac, fric, fric_in, felt, fric_max = [], [], [], [], [], 0.0
    for a, x in zip(reference, inputs):
        b = dict(zip(outputs, test.run(outputs, feeds(x.sketch, x.mask))))
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
