"""Generator, positional encoding and discriminators: the exporter's contract."""
from __future__ import annotations

import math

import pytest
import torch

from trainer.models.discriminators import MultiScaleD
from trainer.models.generator import GraphModule, TwoBranchUNet
from trainer.models.pix2pix_generator import ResnetGenerator
from trainer.models.posenc import positional_encoding

torch.set_num_threads(2)


def test_positional_encoding_matches_published_definition():
    h, w = 5, 7
    pe = positional_encoding(torch.zeros(2, 1, h, w), dim=4)
    assert pe.shape == (2, 8, h, w)
    for r in range(h):
        for c in range(w):
            px, py = c + 1, r + 1   # 1-based index within the crop; x = column
            want = [math.sin(px), math.sin(1e-4 * px), math.cos(px), math.cos(1e-4 * px),
                    math.sin(py), math.sin(1e-4 * py), math.cos(py), math.cos(1e-4 * py)]
            assert pe[1, :, r, c].tolist() == pytest.approx(want, abs=1e-6)


def test_positional_encoding_follows_traced_input_size():
    """Built from the input's own shape: a graph traced at 256 px gives the right encoding at 512 px."""
    traced = torch.jit.trace(lambda x: positional_encoding(x), torch.zeros(1, 1, 256, 256))
    x = torch.zeros(1, 1, 512, 768)
    assert torch.allclose(traced(x), positional_encoding(x))


def test_generator_parameter_count_and_shapes():
    g = TwoBranchUNet()
    n = sum(p.numel() for p in g.parameters())
    assert n == 1_465_575 and round(n / 1e6, 2) == 1.47
    s = torch.rand(2, 1, 256, 512) * 2 - 1
    v, t = g(s, torch.ones_like(s))
    assert v.shape == (2, 3, 256, 512) and t.shape == (2, 2, 256, 512)
    assert v.abs().max() <= 1 and t.abs().max() <= 1


def test_wider_tactile_head_widens_only_the_tactile_layers_and_round_trips():
    g = TwoBranchUNet(tactile_mult=2).eval()
    plain = TwoBranchUNet().eval()
    count = lambda m: sum(p.numel() for p in m.parameters())   # noqa: E731
    assert count(g.visual) == count(plain.visual) and count(g.downs) == count(plain.downs)
    assert count(g.tactile) > 2 * count(plain.tactile)
    s = torch.rand(1, 1, 256, 256) * 2 - 1
    v, t = g(s, torch.ones_like(s))
    assert v.shape == (1, 3, 256, 256) and t.shape == (1, 2, 256, 256)
    again = TwoBranchUNet.from_config(g.model_config())
    again.load_state_dict(g.state_dict())
    assert torch.equal(again(s, torch.ones_like(s), "tactile"), t)
    # checkpoints written before the option (no tactile_mult in their model_config) rebuild as the paper's head
    old = {k: v for k, v in plain.model_config().items() if k != "tactile_mult"}
    TwoBranchUNet.from_config(old).load_state_dict(plain.state_dict())
    with pytest.raises(ValueError, match="tactile_mult"):
        TwoBranchUNet(tactile_mult=0)


def test_a_tactile_head_that_reads_the_visual_head_depends_on_it_and_round_trips():
    torch.manual_seed(3)
    g = TwoBranchUNet(tactile_reads_visual=True).eval()
    plain = TwoBranchUNet().eval()
    count = lambda m: sum(p.numel() for p in m.parameters())   # noqa: E731
    assert count(g.visual) == count(plain.visual) and count(g.tactile) > count(plain.tactile)
    s = torch.rand(1, 1, 256, 256) * 2 - 1
    m = torch.ones_like(s)
    v, t = g(s, m)
    # the tactile-only graph skips the visual head's last layer and still gives the full forward's tactile output
    assert torch.equal(g(s, m, "tactile"), t) and torch.equal(g(s, m, "visual"), v)
    calls = []
    hook = g.visual.up0.register_forward_hook(lambda *_: calls.append(1))
    g(s, m, "tactile")
    assert not calls
    g(s, m)
    assert calls
    hook.remove()
    # the tactile output changes when only the visual head's weights change: it does read them
    with torch.no_grad():
        g.visual.up2[1].weight.add_(0.5)
    assert not torch.allclose(g(s, m, "tactile"), t)
    again = TwoBranchUNet.from_config(g.model_config())
    again.load_state_dict(g.state_dict())
    assert torch.equal(again(s, m, "tactile"), g(s, m, "tactile"))
    # a checkpoint written before the option rebuilds as the paper's heads
    old = {k: val for k, val in plain.model_config().items() if k != "tactile_reads_visual"}
    TwoBranchUNet.from_config(old).load_state_dict(plain.state_dict())


def test_generator_outputs_are_masked_and_input_is_masked():
    torch.manual_seed(0)
    g = TwoBranchUNet().eval()
    s = torch.rand(1, 1, 256, 256) * 2 - 1
    m = torch.zeros_like(s)
    m[..., 64:192, 32:200] = 1
    v, t = g(s, m)
    assert (v * (1 - m)).abs().max() == 0 and (t * (1 - m)).abs().max() == 0
    assert v[..., 64:192, 32:200].abs().sum() > 0
    s2 = s.clone()
    s2[..., :10, :10] = 0.77   # outside the mask: must not change anything
    v2, t2 = g(s2, m)
    assert torch.equal(v, v2) and torch.equal(t, t2)


def test_single_branch_graphs_equal_combined_forward():
    torch.manual_seed(1)
    g = TwoBranchUNet().eval()
    s = torch.rand(1, 1, 256, 256) * 2 - 1
    m = torch.ones_like(s)
    v, t = g(s, m)
    assert torch.equal(g(s, m, "visual"), v) and torch.equal(g(s, m, "tactile"), t)
    assert torch.equal(GraphModule(g, "visual")(s, m), v) and torch.equal(GraphModule(g, "tactile")(s, m), t)
    full = GraphModule(g, "full")(s, m)
    assert torch.equal(full[0], v) and torch.equal(full[1], t)
    with pytest.raises(AssertionError, match="kind must be one of"):
        GraphModule(g, "both")


def test_bottleneck_at_256_is_not_degenerate():
    """At 256 px the 8th down reaches 1x1; it has no norm, so the bottleneck still carries the input."""
    torch.manual_seed(2)
    g = TwoBranchUNet().eval()
    m = torch.ones(1, 1, 256, 256)
    a = g.encode(torch.rand(1, 1, 256, 256), m)[1][7]
    b = g.encode(-torch.rand(1, 1, 256, 256), m)[1][7]
    assert a.shape[-2:] == (1, 1) and torch.isfinite(a).all() and not torch.allclose(a, b)


def test_generator_rejects_sizes_that_are_not_multiples_of_256():
    g = TwoBranchUNet()
    s = torch.zeros(1, 1, 300, 256)
    with pytest.raises(AssertionError, match="multiples of 256"):
        g(s, torch.ones_like(s))


def test_pix2pix_generator_same_interface():
    g = ResnetGenerator(ngf=8, n_blocks=2).eval()
    s = torch.rand(3, 1, 32, 32)
    m = torch.ones_like(s)
    v, t = g(s, m)
    assert v.shape == (3, 3, 32, 32) and t.shape == (3, 2, 32, 32)
    assert torch.equal(g(s, m, "tactile"), t) and torch.equal(g(s, m, "visual"), v)


def test_tactile_discriminator_handles_32px_patches_at_every_scale():
    d = MultiScaleD(in_ch=7, ndf=8, n_layers=3, num_D=3, min_input=32)
    out = d(torch.randn(4, 7, 32, 32))
    assert len(out) == 3 and all(o[-1].shape[0] == 4 and o[-1].shape[1] == 1 and o[-1].numel() >= 4 for o in out)


def test_discriminator_pools_the_standard_layout_whatever_it_is_given(monkeypatch):
    """CUDA's avg_pool2d got R1's double backward wrong on channels-last inputs (docs/training.md, "On a GPU"), so
    D hands its pooling a plain NCHW tensor; the scores do not depend on the input's layout."""
    import trainer.models.discriminators as disc
    seen = []
    pool = disc.F.avg_pool2d

    def checked(x, *args, **kwargs):
        seen.append(x.is_contiguous())
        return pool(x, *args, **kwargs)

    monkeypatch.setattr(disc.F, "avg_pool2d", checked)
    torch.manual_seed(0)
    d = MultiScaleD(in_ch=7, ndf=8, n_layers=3, num_D=3, min_input=32).double()
    x = torch.randn(6, 7, 32, 32, dtype=torch.float64)
    plain = d(x)
    seen.clear()
    cl = d(x.to(memory_format=torch.channels_last))
    assert seen == [True, True]
    for a, b in zip(plain, cl):
        assert torch.allclose(a[-1], b[-1], rtol=0, atol=1e-12)


def test_tactile_graph_exports_to_onnx_with_dynamic_size(tmp_path):
    """The exporter's path: traced at 256 px, run by ONNX Runtime at 512x256, same numbers as torch."""
    import onnxruntime as ort
    torch.manual_seed(3)
    g = TwoBranchUNet().eval()
    s = torch.zeros(1, 1, 256, 256)
    path = tmp_path / "tactile.onnx"
    torch.onnx.export(GraphModule(g, "tactile"), (s, torch.ones_like(s)), str(path),
                      input_names=["sketch", "mask"], output_names=["tactile"], dynamo=False,
                      dynamic_axes={"sketch": {2: "h", 3: "w"}, "mask": {2: "h", 3: "w"}})
    s2 = torch.rand(1, 1, 512, 256) * 2 - 1
    m2 = torch.ones_like(s2)
    out = ort.InferenceSession(str(path)).run(None, {"sketch": s2.numpy(), "mask": m2.numpy()})[0]
    with torch.no_grad():
        want = g(s2, m2, "tactile").numpy()
    assert out.shape == (1, 2, 512, 256) and abs(out - want).max() < 1e-4
