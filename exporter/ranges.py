"""Calibrate once, quantize three graphs: int8 activation ranges moved between graphs by what a tensor computes.

The tactile and visual graphs are parts of the full graph, so every activation they have is computed, on the same
calibration sketches, by the full graph too, and its calibrated range is the same. Calibration was 70 % of an int8
export and ran once per graph; the demo's first start pays it for every catalogue garment.

Tensor names cannot carry the match: the exporter numbers nodes per graph, so `/generator/tactile/Concat_1` is a
different tensor in the tactile graph than in the full one (and the full graph shares one ReLU between branches).
A tensor's *structural key* is a hash of how it is computed: graph inputs by name, initializers by dtype, shape and
bytes, node outputs by op type, attributes, the keys of their inputs and the output index. Two tensors with one key
hold the same values on the same feeds. A graph whose every tensor has a match in the calibrated graph takes its
ranges from there; any other falls back to calibrating itself.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import onnx
from onnx import numpy_helper
from onnxruntime.quantization.calibrate import TensorsData, load_tensors_data, save_tensors_data


def _digest(*parts: bytes | str) -> str:
    h = hashlib.sha256()
    for p in parts:
        b = p.encode() if isinstance(p, str) else p
        h.update(len(b).to_bytes(8, "little"))
        h.update(b)
    return h.hexdigest()


def structural_keys(model: onnx.ModelProto) -> dict[str, str]:
    """tensor name -> structural key for every graph input, initializer and node output (nodes in graph order,
    which ONNX requires to be topological)."""
    g = model.graph
    keys: dict[str, str] = {i.name: _digest("input", i.name) for i in g.input}
    for init in g.initializer:
        arr = numpy_helper.to_array(init)
        keys[init.name] = _digest("init", str(arr.dtype), str(arr.shape), arr.tobytes())
    keys[""] = _digest("absent")   # an omitted optional input
    for node in g.node:
        attrs = sorted(a.SerializeToString(deterministic=True) for a in node.attribute)
        missing = [t for t in node.input if t not in keys]
        if missing:
            raise ValueError(f"node {node.name!r} reads {missing[0]!r}, which nothing before it produces "
                             "(subgraphs and unsorted graphs are not supported)")
        base = _digest("node", node.domain, node.op_type, *attrs, *(keys[t] for t in node.input))
        for i, out in enumerate(node.output):
            if out:
                keys[out] = _digest(base, str(i))
    del keys[""]
    return keys


def transfer(src_model: onnx.ModelProto, src_cache: Path, dst_model: onnx.ModelProto, dst_cache: Path) -> bool:
    """Write `dst_cache`: `src_cache`'s ranges under `dst_model`'s tensor names. False (nothing written) unless
    every tensor `dst_model` computes is computed by `src_model` too."""
    src_by_key: dict[str, str] = {}
    for name, key in structural_keys(src_model).items():
        src_by_key.setdefault(key, name)
    dst_keys = structural_keys(dst_model)
    produced = [o for n in dst_model.graph.node for o in n.output if o] + [i.name for i in dst_model.graph.input]
    if any(dst_keys[t] not in src_by_key for t in produced):
        return False
    src = load_tensors_data(src_cache)
    data = {t: src.data[src_by_key[dst_keys[t]]] for t in produced if src_by_key[dst_keys[t]] in src.data}
    save_tensors_data(TensorsData(src.calibration_method, data), dst_cache)
    return True
