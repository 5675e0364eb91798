"""Lower-precision graphs: int8 (ONNX Runtime static QDQ quantization, calibrated) and fp16.

int8 targets the CPU kiosk. fp16 targets GPU execution providers; on the CPU provider it mostly halves the file
(ORT runs many fp16 ops through casts), which the benchmark shows rather than assumes.

int8 keeps a few parts of the graph in fp32 ("fp32 islands"), because measuring each part's contribution showed
where 8-bit activations lose what the kiosk needs (docs/performance.md, "int8 accuracy"):
- `pe`: the positional-encoding subgraph. Quantizing it quantizes the pixel index (1..W) itself, so sin(p) is
  evaluated at p rounded to steps of W/128 pixels: garbage, and worse the larger the input (this alone was most of
  the error, 31 dB -> 50 dB visual PSNR at 1536 px when kept fp32).
- `first-conv`: the first convolution, whose input holds the slow PE channels (sin(1e-4 p) spans ~0.05 of a
  [-1, 1] range, i.e. a few 8-bit steps).
- `heads`: each output's last convolution, tanh and mask multiply: 8-bit steps of the tanh output are visible in
  the friction map, which amplifies small slopes (log of the squared slope).
- `tactile-branch`: the whole tactile decoder branch (optional; halves the friction-map error again, costs speed).
Activation ranges: the 99.999th percentile of calibration activations (measured better than min-max and entropy).
"""
from __future__ import annotations

import logging
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import onnx
from onnxruntime.quantization import (CalibrationDataReader, CalibrationMethod, QuantFormat, QuantType,
                                      quantize_static)
from onnxruntime.quantization.shape_inference import quant_pre_process
from onnxruntime.transformers.float16 import convert_float_to_float16

from exporter.ranges import transfer
from exporter.shared_weights import embedded
from kiosk.contract.graph import feeds
from kiosk.contract.sketch import NetworkInput

FP32_ISLANDS = ("pe", "first-conv", "heads", "tactile-branch")
DEFAULT_FP32_ISLANDS = ("pe", "first-conv", "heads")
log = logging.getLogger(__name__)
CALIBRATION_METHODS = {"minmax": CalibrationMethod.MinMax, "percentile": CalibrationMethod.Percentile,
                       "entropy": CalibrationMethod.Entropy}


class _Reader(CalibrationDataReader):
    """Feeds calibration sketches; `set_range` lets ORT calibrate in chunks of one size each (below)."""

    def __init__(self, inputs: Sequence[NetworkInput]):
        self._feeds = [feeds(x.sketch, x.mask) for x in inputs]
        self._it = iter(self._feeds)

    def __len__(self) -> int:
        return len(self._feeds)

    def set_range(self, start_index: int, end_index: int) -> None:
        self._it = iter(self._feeds[start_index:end_index])

    def get_next(self):
        return next(self._it, None)


def _same_size_chunk(calibration: Sequence[NetworkInput]) -> int | None:
    """Length of the runs of equal-size inputs if the set is several such runs of one length, else None.

    ORT's histogram calibrators (percentile, entropy) stack each batch of activations into one array, which fails
    for inputs of several sizes; fed one size at a time (ORT's strided calibration), they merge histograms instead.
    """
    shapes = [x.sketch.shape for x in calibration]
    runs, n = [], 1
    for a, b in zip(shapes, shapes[1:]):
        if a == b:
            n += 1
        else:
            runs.append(n)
            n = 1
    runs.append(n)
    return runs[0] if len(runs) > 1 and len(set(runs)) == 1 else None


def _ancestors(graph: onnx.GraphProto, tensor: str) -> list[str]:
    """Names of the nodes that (transitively) produce `tensor`."""
    producer = {out: node for node in graph.node for out in node.output}
    seen: dict[str, None] = {}
    stack = [tensor]
    while stack:
        node = producer.get(stack.pop())
        if node is None or node.name in seen:
            continue
        seen[node.name] = None
        stack.extend(node.input)
    return list(seen)


def _head(graph: onnx.GraphProto, output: str) -> list[str]:
    """The nodes from a graph output back to (and including) the nearest Conv: Mul(mask), Tanh, DepthToSpace, Conv."""
    producer = {out: node for node in graph.node for out in node.output}
    inputs = {i.name for i in graph.input} | {i.name for i in graph.initializer}
    names, tensor = [], output
    while tensor in producer:
        node = producer[tensor]
        names.append(node.name)
        if node.op_type in ("Conv", "ConvTranspose"):
            return names
        data = [t for t in node.input if t and t not in inputs and t in producer]
        if not data:
            break
        tensor = data[0]
    raise ValueError(f"no convolution found behind output {output!r}; is this a vtkiosk generator graph?")


def fp32_island_nodes(model: onnx.ModelProto, islands: Iterable[str]) -> list[str]:
    """Node names to leave in fp32 for the named islands (see the module docstring), found from the graph's
    structure (the PE subgraph is everything the first Conv's input depends on; a head is the chain from an output
    back to its last Conv), except `tactile-branch`, which is the exported module path `/tactile/`."""
    islands = list(islands)
    unknown = sorted(set(islands) - set(FP32_ISLANDS))
    if unknown:
        raise ValueError(f"unknown fp32 island(s) {', '.join(unknown)}; known: {', '.join(FP32_ISLANDS)}")
    graph = model.graph
    convs = [n for n in graph.node if n.op_type == "Conv"]
    if not convs:
        raise ValueError("the graph has no convolution")
    first = convs[0]
    names: dict[str, None] = {}
    if "pe" in islands:
        names.update(dict.fromkeys(_ancestors(graph, first.input[0])))
    if "first-conv" in islands:
        names[first.name] = None
    if "heads" in islands:
        for out in graph.output:
            names.update(dict.fromkeys(_head(graph, out.name)))
    if "tactile-branch" in islands:
        outs = [o.name for o in graph.output if o.name == "tactile"]
        names.update(dict.fromkeys(n.name for n in graph.node if "/tactile/" in n.name))
        for out in outs:
            names.update(dict.fromkeys(_head(graph, out)))
    return list(names)


@dataclass(frozen=True)
class Calibrated:
    """A graph as calibrated (after ORT's pre-processing) and its ranges: what another graph can take ranges from."""

    model: Path
    cache: Path

    @classmethod
    def beside(cls, cache: Path) -> "Calibrated":
        """The record quantize_int8(..., cache=cache) leaves: the pre-processed graph is kept next to the cache."""
        return cls(Path(cache).with_suffix(".pre.onnx"), Path(cache))


def quantize_int8(src: Path, dst: Path, calibration: Sequence[NetworkInput], *, method: str = "percentile",
                  fp32_islands: Iterable[str] = DEFAULT_FP32_ISLANDS, cache: Path | None = None,
                  ranges_from: Calibrated | None = None) -> Path:
    """Static QDQ int8: uint8 activations, int8 per-channel weights, ranges from `calibration` sketches; the
    `fp32_islands` stay float32. `cache` (a JSON file) keeps the calibrated ranges of this graph, method and
    calibration set, so variants that differ only in their islands calibrate once (the int8 study).
    `ranges_from`: a graph calibrated on the same sketches with the same method; where it computes every tensor
    this one does (exporter.ranges), its ranges are used instead of calibrating again (needs `cache`). With
    `cache`, `Calibrated.beside(cache)` is this graph's record for the next one."""
    if not calibration:
        raise ValueError("int8 quantization needs at least one calibration sketch")
    if method not in CALIBRATION_METHODS:
        raise ValueError(f"calibration method must be one of {', '.join(CALIBRATION_METHODS)}; got {method!r}")
    with tempfile.TemporaryDirectory(prefix="vtkiosk-quant-") as tmp:
        pre = Calibrated.beside(cache).model if cache else Path(tmp) / "pre.onnx"
        src = embedded(Path(src), Path(tmp) / "src.onnx")   # a bundle's graph may read a shared weights file
        quant_pre_process(str(src), str(pre), skip_symbolic_shape=True)
        if ranges_from is not None and cache is not None and not Path(cache).exists():
            if not transfer(onnx.load(str(ranges_from.model)), ranges_from.cache, onnx.load(str(pre)), Path(cache)):
                log.info("int8: %s computes tensors %s does not; calibrating it on its own", Path(src).name,
                         ranges_from.model.name)
        exclude = fp32_island_nodes(onnx.load(str(pre)), fp32_islands)
        extra = {"ActivationSymmetric": False, "WeightSymmetric": True}
        if method == "percentile":
            extra["CalibPercentile"] = 99.999
        chunk = _same_size_chunk(calibration)
        if method != "minmax" and len({x.sketch.shape for x in calibration}) > 1:
            if chunk is None:
                raise ValueError(f"{method} calibration over several sizes needs the same number of sketches per "
                                 "size, grouped by size (exporter.calibration.calibration_set makes them so)")
            extra["CalibStridedMinMax"] = chunk
        quantize_static(str(pre), str(dst), _Reader(calibration), quant_format=QuantFormat.QDQ,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, per_channel=True,
                        calibrate_method=CALIBRATION_METHODS[method], nodes_to_exclude=exclude,
                        extra_options=extra, calibration_cache_path=str(cache) if cache else None)
    return Path(dst)


def convert_fp16(src: Path, dst: Path) -> Path:
    """fp16 weights and activations; inputs and outputs stay float32 so callers do not change."""
    model = convert_float_to_float16(onnx.load(str(src)), keep_io_types=True)
    onnx.save(model, str(dst))
    return Path(dst)
