"""Trained generator -> ONNX graphs (full, tactile, visual) with dynamic spatial size, and their parity check.

Separate graphs because asking a two-output graph for one output still runs both branches in ONNX Runtime; the
kiosk picks the graph a scene needs. Each graph is `trainer.models.generator.GraphModule`, the trainer's own forward
for that kind, so what is exported is what was trained (the only export-side change is the exact ConvTranspose
rewrite, and `parity` checks every export against the eager module). Each graph takes exactly
`kiosk.contract.sketch.network_input`'s tensors (`sketch`, `mask`, (1, 1, H, W) float32) and computes the positional
encoding inside.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch
from torch import nn

from exporter.rewrite import rewrite_conv_transpose
from trainer.models.generator import GraphModule
from kiosk.contract.graph import GRAPH_OUTPUTS, INPUT_NAMES, feeds
from kiosk.bundle.probe import session_options

OPSET = 17


def graph_module(generator: nn.Module, kind: str, *, rewrite: bool = True) -> nn.Module:
    """The module that is exported for `kind` (with the exact ConvTranspose rewrite unless `rewrite` is off)."""
    if kind not in GRAPH_OUTPUTS:
        raise ValueError(f"graph kind must be one of {', '.join(GRAPH_OUTPUTS)}; got {kind!r}")
    gen = rewrite_conv_transpose(generator)[0] if rewrite else generator
    return GraphModule(gen, kind).eval()


def export_graph(generator: nn.Module, kind: str, path: Path, *, size: tuple[int, int] = (512, 512),
                 rewrite: bool = True) -> Path:
    """Write one graph; H and W stay symbolic ("H", "W"), so one file serves every declared size."""
    module = graph_module(generator, kind, rewrite=rewrite)
    w, h = size
    dummy = (torch.zeros(1, 1, h, w), torch.ones(1, 1, h, w))
    outputs = GRAPH_OUTPUTS[kind]
    axes = {name: {2: "H", 3: "W"} for name in INPUT_NAMES}
    axes.update({o: {2: "H", 3: "W"} for o in outputs})
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation and InstanceNorm notices
        torch.onnx.export(module, dummy, str(path), input_names=list(INPUT_NAMES), output_names=outputs,
                          dynamic_axes=axes, opset_version=OPSET, dynamo=False, do_constant_folding=True)
    return path


def eager_module(generator: nn.Module, kind: str) -> nn.Module:
    """PyTorch eager for `kind`: the exported module without the export-side ConvTranspose rewrite, in eval mode."""
    return graph_module(generator, kind, rewrite=False)


def torch_outputs(generator: nn.Module, kind: str, sketch: np.ndarray, mask: np.ndarray) -> list[np.ndarray]:
    """PyTorch eager outputs of the generator's own forward for `kind`, as numpy, in the graph's output order."""
    module = eager_module(generator, kind)
    with torch.no_grad():
        out = module(torch.from_numpy(sketch), torch.from_numpy(mask))
    out = out if isinstance(out, tuple) else (out,)
    return [o.numpy() for o in out]


def ort_session(path: Path, *, threads: int = 2, providers: list[str] | None = None) -> ort.InferenceSession:
    return ort.InferenceSession(str(path), session_options(threads),
                                providers=providers or ["CPUExecutionProvider"])


def parity(generator: nn.Module, kind: str, path: Path, inputs: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """Max |ONNX fp32 - PyTorch| over `inputs` ((sketch, mask) pairs of (1, 1, H, W) float32)."""
    sess = ort_session(path)
    worst = 0.0
    for sketch, mask in inputs:
        ref = torch_outputs(generator, kind, sketch, mask)
        got = sess.run(GRAPH_OUTPUTS[kind], feeds(sketch, mask))
        worst = max(worst, *(float(np.abs(a - b).max()) for a, b in zip(ref, got)))
    return worst
