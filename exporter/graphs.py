"""Trained generator -> ONNX graphs (full, tactile, visual) with dynamic spatial size, and their parity check.

Separate graphs because asking a two-output graph for one output still runs both branches in ONNX Runtime; the
kiosk picks the graph a scene needs. Each graph takes exactly `kiosk.contract.sketch.network_input`'s tensors (`sketch`,
`mask`, (1, 1, H, W) float32) and computes the positional encoding inside.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch
from torch import nn

from exporter.rewrite import rewrite_conv_transpose
from trainer.models.posenc import frequencies
from kiosk.contract.graph import GRAPH_OUTPUTS, INPUT_NAMES, feeds
from kiosk.bundle.probe import session_options

OPSET = 17


def first_layer_input(generator: nn.Module, sketch: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """cat(sketch, positional encoding) * mask, the generator's first-layer input, in fewer passes over memory.

    `TwoBranchUNet.encode` materialises the PE planes, expands them to the batch, concatenates and then masks (about
    40 full-resolution plane writes; 15 % of the int8 graph's time at 1536 px in an ONNX Runtime profile). Here each
    PE block is one broadcast multiply of a row or column vector by the mask, then one concat: the same values
    (x * 1 * m == x * m exactly), so parity with PyTorch is unchanged; `parity` checks it on every export.
    """
    d = generator.pe_dim
    xs = torch.cumsum(torch.ones_like(sketch[0, 0, 0, :]), 0)   # 1..W, from the input so H and W stay symbolic
    ys = torch.cumsum(torch.ones_like(sketch[0, 0, :, 0]), 0)   # 1..H
    f = frequencies(d, device=sketch.device, dtype=sketch.dtype)
    ax, ay = xs[:, None] * f[None, :], ys[:, None] * f[None, :]
    ex = torch.cat([torch.sin(ax), torch.cos(ax)], 1).t()       # (d, W)
    ey = torch.cat([torch.sin(ay), torch.cos(ay)], 1).t()       # (d, H)
    return torch.cat([sketch * mask, ex[None, :, None, :] * mask, ey[None, :, :, None] * mask], 1)


def _encode(generator: nn.Module, sketch: torch.Tensor, mask: torch.Tensor):
    """`TwoBranchUNet.encode` with `first_layer_input` as its first step."""
    return generator.encode_input(first_layer_input(generator, sketch, mask))


class _Single(nn.Module):
    """One branch only: the other branch's work is not in the graph at all."""

    def __init__(self, generator: nn.Module, kind: str):
        super().__init__()
        self.generator, self.kind = generator, kind

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        trunk, skips = _encode(self.generator, sketch, mask)
        return getattr(self.generator, self.kind)(trunk, skips) * mask


class _Full(nn.Module):
    """Shared encoder and trunk once, then both branches."""

    def __init__(self, generator: nn.Module):
        super().__init__()
        self.generator = generator

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor):
        trunk, skips = _encode(self.generator, sketch, mask)
        return self.generator.visual(trunk, skips) * mask, self.generator.tactile(trunk, skips) * mask


def graph_module(generator: nn.Module, kind: str, *, rewrite: bool = True) -> nn.Module:
    """The module that is exported for `kind` (with the exact ConvTranspose rewrite unless `rewrite` is off)."""
    if kind not in GRAPH_OUTPUTS:
        raise ValueError(f"graph kind must be one of {', '.join(GRAPH_OUTPUTS)}; got {kind!r}")
    gen = rewrite_conv_transpose(generator)[0] if rewrite else generator
    module = _Full(gen) if kind == "full" else _Single(gen, kind)
    return module.eval()


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


class _Eager(nn.Module):
    """The trainer's own forward for `kind` (what parity is checked against and PyTorch eager is timed with)."""

    def __init__(self, generator: nn.Module, kind: str):
        super().__init__()
        self.generator, self.kind = generator, kind

    def forward(self, sketch: torch.Tensor, mask: torch.Tensor):
        g = self.generator
        if self.kind == "visual":
            return g.forward_visual(sketch, mask)
        if self.kind == "tactile":
            return g.forward_tactile(sketch, mask)
        trunk, skips = g.encode(sketch, mask)
        return g.visual(trunk, skips) * mask, g.tactile(trunk, skips) * mask


def eager_module(generator: nn.Module, kind: str) -> nn.Module:
    """PyTorch eager for `kind` through the model's own methods (no export-side rewrites), in eval mode."""
    if kind not in GRAPH_OUTPUTS:
        raise ValueError(f"graph kind must be one of {', '.join(GRAPH_OUTPUTS)}; got {kind!r}")
    return _Eager(generator, kind).eval()


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
