"""Lower-precision graphs: int8 (ONNX Runtime static QDQ quantization, calibrated) and fp16.

int8 targets the CPU kiosk. fp16 targets GPU execution providers; on the CPU provider it mostly halves the file
(ORT runs many fp16 ops through casts), which the benchmark shows rather than assumes.
"""
from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

import onnx
from onnxruntime.quantization import (CalibrationDataReader, CalibrationMethod, QuantFormat, QuantType,
                                      quantize_static)
from onnxruntime.quantization.shape_inference import quant_pre_process
from onnxruntime.transformers.float16 import convert_float_to_float16

from kiosk.sketch import NetworkInput


class _Reader(CalibrationDataReader):
    def __init__(self, inputs: Sequence[NetworkInput]):
        self._it = iter([{"sketch": x.sketch, "mask": x.mask} for x in inputs])

    def get_next(self):
        return next(self._it, None)


def quantize_int8(src: Path, dst: Path, calibration: Sequence[NetworkInput], *,
                  method: str = "minmax") -> Path:
    """Static QDQ int8: uint8 activations, int8 per-channel weights, ranges from `calibration` sketches."""
    if not calibration:
        raise ValueError("int8 quantization needs at least one calibration sketch")
    methods = {"minmax": CalibrationMethod.MinMax, "percentile": CalibrationMethod.Percentile,
               "entropy": CalibrationMethod.Entropy}
    if method not in methods:
        raise ValueError(f"calibration method must be one of {', '.join(methods)}; got {method!r}")
    with tempfile.TemporaryDirectory(prefix="vtkiosk-quant-") as tmp:
        pre = Path(tmp) / "pre.onnx"
        quant_pre_process(str(src), str(pre), skip_symbolic_shape=True)
        extra = {"ActivationSymmetric": False, "WeightSymmetric": True}
        if method == "percentile":
            extra["CalibPercentile"] = 99.999
        quantize_static(str(pre), str(dst), _Reader(calibration), quant_format=QuantFormat.QDQ,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, per_channel=True,
                        calibrate_method=methods[method], extra_options=extra)
    return Path(dst)


def convert_fp16(src: Path, dst: Path) -> Path:
    """fp16 weights and activations; inputs and outputs stay float32 so callers do not change."""
    model = convert_float_to_float16(onnx.load(str(src)), keep_io_types=True)
    onnx.save(model, str(dst))
    return Path(dst)
