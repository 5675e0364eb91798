"""Multiply-accumulates of an ONNX graph at one input size, counted from its convolutions.

The count needs every convolution's static shapes, which ONNX's own shape inference does not give here (the
positional encoding is computed inside the graph from the input's size). OpenVINO's reader folds that and infers
every shape once the inputs are fixed, so it does the counting; without OpenVINO the count is None. QDQ graphs count
the same as their float graph: the (de)quantize nodes around a convolution are not multiply-adds of the network.

Counted: Convolution (out pixels x Cin x kh x kw per output channel), GroupConvolution, ConvolutionBackpropData
(transposed convolution: every input pixel scatters Cout x kh x kw products) and MatMul. Element-wise work (norms,
activations, shuffles) is memory traffic, not MACs, and is left out on purpose.
"""
from __future__ import annotations

import math
from pathlib import Path


def _prod(dims) -> int:
    return int(math.prod(int(d) for d in dims))


def graph_macs(path: Path, inputs: dict[str, tuple[int, ...]]) -> int | None:
    """MACs of one run of the ONNX graph at `path` with inputs of the given static shapes; None without OpenVINO
    or when a convolution's shape stays dynamic."""
    try:
        import openvino as ov
    except ImportError:
        return None
    model = ov.Core().read_model(str(path))
    model.reshape({name: list(shape) for name, shape in inputs.items()})
    total = 0
    for op in model.get_ordered_ops():
        kind = op.get_type_name()
        if kind not in ("Convolution", "GroupConvolution", "ConvolutionBackpropData", "MatMul"):
            continue
        shapes = [op.get_input_partial_shape(i) for i in range(2)] + [op.get_output_partial_shape(0)]
        if any(s.is_dynamic for s in shapes):
            return None
        x, w, y = ([int(d) for d in s.to_shape()] for s in shapes)
        if kind == "Convolution":            # w: (Cout, Cin, kh, kw)
            total += _prod(y) * _prod(w[1:])
        elif kind == "GroupConvolution":     # w: (G, Cout/G, Cin/G, kh, kw)
            total += _prod(y) * _prod(w[2:])
        elif kind == "ConvolutionBackpropData":  # w: (Cin, Cout, kh, kw)
            total += _prod(x) * _prod(w[1:])
        else:                                # MatMul: (..., M, K) x (..., K, N)
            total += _prod(y) * x[-1]
    return total
