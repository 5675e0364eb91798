"""The graph the exporter builds and the module the trainer trains are one code path: for every graph kind the
exported module is `GraphModule(generator, kind)` (the trainer's own forward), eager equals it bit for bit, and the
ONNX graph (with the export-only ConvTranspose rewrite) matches the trained module within the parity bound."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from exporter.export import PARITY_BOUND
from exporter.graphs import eager_module, export_graph, graph_module, parity
from kiosk.contract.graph import GRAPH_KINDS, GRAPH_OUTPUTS
from trainer.models.generator import GraphModule, TwoBranchUNet


@pytest.fixture(scope="module")
def generator():
    torch.manual_seed(7)
    return TwoBranchUNet(base=8).eval()


def _inputs(seed: int, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    mask = np.zeros((1, 1, h, w), np.float32)
    mask[..., h // 8: -h // 8, w // 6: -w // 6] = 1
    sketch = (np.where(rng.random((1, 1, h, w)) < 0.1, -1.0, 1.0) * mask).astype(np.float32)
    return sketch, mask


@pytest.mark.parametrize("kind", GRAPH_KINDS)
def test_eager_and_exported_modules_are_the_trainers_forward(generator, kind):
    s, m = (torch.from_numpy(a) for a in _inputs(0, 256, 256))
    with torch.no_grad():
        trained = generator(s, m)  # what training computes: both branches
        for module in (eager_module(generator, kind), graph_module(generator, kind, rewrite=False)):
            assert isinstance(module, GraphModule) and module.kind == kind
            out = module(s, m)
            out = out if isinstance(out, tuple) else (out,)
            want = [trained[("visual", "tactile").index(name)] for name in GRAPH_OUTPUTS[kind]]
            assert len(out) == len(want) and all(torch.equal(a, b) for a, b in zip(out, want))


@pytest.mark.parametrize("kind", GRAPH_KINDS)
def test_onnx_graph_matches_the_trained_module(generator, kind, tmp_path):
    path = export_graph(generator, kind, tmp_path / f"{kind}.onnx", size=(256, 256))
    worst = parity(generator, kind, path, [_inputs(1, 256, 256), _inputs(2, 512, 256)])
    assert worst < PARITY_BOUND


def test_a_wider_tactile_head_exports_within_the_parity_bound(tmp_path):
    torch.manual_seed(8)
    wide = TwoBranchUNet(base=8, tactile_mult=2).eval()
    path = export_graph(wide, "tactile", tmp_path / "tactile.onnx", size=(256, 256))
    assert parity(wide, "tactile", path, [_inputs(3, 256, 256)]) < PARITY_BOUND


@pytest.mark.parametrize("kind", ["tactile", "full"])
def test_a_tactile_head_that_reads_the_visual_head_exports_within_the_parity_bound(tmp_path, kind):
    torch.manual_seed(9)
    reads = TwoBranchUNet(base=8, tactile_reads_visual=True).eval()
    path = export_graph(reads, kind, tmp_path / f"{kind}.onnx", size=(256, 256))
    assert parity(reads, kind, path, [_inputs(4, 256, 256), _inputs(5, 512, 256)]) < PARITY_BOUND
