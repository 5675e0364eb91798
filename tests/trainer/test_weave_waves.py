"""Weave waves (trainer/models/weave_waves.py): the photo's weave frequencies found, coordinates that follow the
object and a mirrored crop's pixels, and a generator that mixes the waves and still exports."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from trainer.models.generator import GraphModule, TwoBranchUNet
from trainer.models.weave_waves import object_coords, wave_mix, weave_frequencies
from trainer.recipe.mirror import flip_batch, transpose_batch
from trainer.sampling import Batch

torch.set_num_threads(2)


def _photo(period: float, angle_deg: float, shape=(200, 240), noise=0.0, seed=0):
    """A grey photo whose shading is one plane wave, on an elliptic object."""
    h, w = shape
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    t = math.radians(angle_deg)
    k = 2 * math.pi / period
    lum = 0.5 + 0.15 * np.sin(k * (x * math.cos(t) + y * math.sin(t)) + 0.3)
    lum += noise * np.random.default_rng(seed).standard_normal(lum.shape)
    mask = (((x - w / 2) / (0.4 * w)) ** 2 + ((y - h / 2) / (0.4 * h)) ** 2 <= 1).astype(np.uint8)
    photo = np.repeat(np.clip(lum * 255, 0, 255)[..., None], 3, 2).astype(np.uint8)
    return photo, mask


@given(period=st.floats(4.0, 30.0), angle=st.floats(0.0, 179.0))
@settings(max_examples=25, deadline=None)
def test_the_strongest_peak_is_the_planted_wave(period, angle):
    photo, mask = _photo(period, angle)
    k = weave_frequencies(photo, mask, 1)[0]
    found = 2 * math.pi / math.hypot(*k)
    assert abs(found - period) / period < 0.03
    # the direction up to the conjugate pair's sign
    d = math.degrees(math.atan2(k[1], k[0])) % 180
    assert min(abs(d - angle % 180), 180 - abs(d - angle % 180)) < 3.0


def test_frequencies_pad_refuse_and_stay_in_the_weave_band():
    photo, mask = _photo(8.0, 30.0)
    k = weave_frequencies(photo, mask, 4)
    assert k.shape == (4, 2) and np.isfinite(k).all()
    periods = 2 * math.pi / np.hypot(k[:, 0], k[:, 1])
    assert (periods >= 2.5 - 1e-6).all() and (periods <= 40.0 + 1e-6).all()
    with pytest.raises(ValueError, match="no fine shading"):
        weave_frequencies(np.full_like(photo, 128), mask, 2)
    with pytest.raises(ValueError, match="no object"):
        weave_frequencies(photo, np.zeros_like(mask), 2)
    with pytest.raises(ValueError, match="count"):
        weave_frequencies(photo, mask, 0)


@given(dx=st.integers(0, 40), dy=st.integers(0, 30))
@settings(max_examples=30, deadline=None)
def test_coordinates_follow_the_object_not_the_crop(dx, dy):
    base = torch.zeros(1, 1, 64, 96)
    base[..., 10:30, 5:50] = 1
    moved = torch.roll(base, shifts=(dy, dx), dims=(2, 3))
    a, b = object_coords(base), object_coords(moved)
    on = base[0, 0] > 0
    on_moved = moved[0, 0] > 0
    assert torch.equal(a[0][:, on], b[0][:, on_moved])
    assert a[0, 0, 10, 5] == 0 and a[0, 1, 10, 5] == 0


def test_an_empty_mask_gives_the_crop_grid():
    c = object_coords(torch.zeros(2, 1, 8, 12))
    assert c.shape == (2, 2, 8, 12)
    assert torch.equal(c[0, 0, 0], torch.arange(12.0)) and torch.equal(c[1, 1, :, 0], torch.arange(8.0))


def test_wave_mix_is_the_weighted_sum_of_the_waves():
    coords = object_coords(torch.ones(1, 1, 16, 16))
    k = torch.tensor([[0.5, 0.0], [0.0, 1.0]])
    w = torch.zeros(1, 2 * 4, 16, 16)   # 2 channels x (2 sin + 2 cos)
    w[:, 0] = 2.0    # channel 0: 2 sin(k0 . p)
    w[:, 7] = -1.0   # channel 1: -cos(k1 . p)
    out = wave_mix(w, coords, k, 2)
    assert torch.allclose(out[0, 0], 2 * torch.sin(0.5 * coords[0, 0]), atol=1e-6)
    assert torch.allclose(out[0, 1], -torch.cos(coords[0, 1]), atol=1e-6)


def _batch():
    m = torch.zeros(1, 1, 32, 32)
    m[..., 4:20, 9:30] = 1
    z = torch.zeros(0, 1, 32, 32)
    return Batch(m * 0.5, m, torch.zeros(1, 3, 32, 32), z, z, z, np.zeros((0, 2), int), np.zeros((0, 2), int), (0, 0))


def test_a_mirrored_crop_carries_its_pixels_own_coordinates():
    b = _batch()
    plain = b.wave_coords()
    t = transpose_batch(b).wave_coords()
    f = flip_batch(b).wave_coords()
    assert torch.equal(t, plain.transpose(-1, -2))
    assert torch.equal(f, torch.flip(plain, dims=(-1,)))
    assert torch.equal(transpose_batch(transpose_batch(b)).wave_coords(), plain)


def test_a_generator_with_waves_trains_its_weights_and_traces():
    g = TwoBranchUNet(base=4, weave_waves=3)
    assert g.model_config()["weave_waves"] == 3
    g.set_waves(np.array([[0.5, 0.1], [0.0, 0.9], [1.2, -0.3]], np.float32))
    with pytest.raises(AssertionError):
        g.set_waves(np.zeros((2, 2), np.float32))
    sk = torch.rand(1, 1, 256, 256) * 2 - 1
    mk = torch.zeros_like(sk)
    mk[..., 40:200, 30:220] = 1
    vis, tac = g(sk * mk, mk)
    assert vis.shape == (1, 3, 256, 256) and tac.shape == (1, 2, 256, 256)
    assert torch.isfinite(vis).all() and vis.abs().max() <= 1 and (tac * (1 - mk)).abs().max() == 0
    # coordinates given explicitly (training) and computed from the mask agree for a plain crop
    assert torch.equal(g(sk * mk, mk, "tactile", coords=object_coords(mk)), tac)
    tac.sum().backward()
    assert g.tactile.up0[1].weight.grad.abs().sum() > 0
    rebuilt = TwoBranchUNet.from_config(g.model_config())
    rebuilt.load_state_dict(g.state_dict())
    assert torch.equal(rebuilt.wave_k, g.wave_k)
    # a traced graph takes only the sketch and the mask: the coordinates are computed in it, for any object place
    with torch.no_grad():
        traced = torch.jit.trace(GraphModule(g.eval(), "tactile"), (sk * mk, mk))
        mk2 = torch.roll(mk, shifts=(8, 16), dims=(2, 3))
        assert torch.allclose(traced(sk * mk2, mk2), g(sk * mk2, mk2, "tactile"), atol=1e-6)


def test_an_exported_graph_places_the_waves_from_its_mask(tmp_path):
    """The ONNX graph computes the coordinates from the mask it is given, not from the export's all-ones dummy."""
    from exporter.graphs import export_graph, ort_session, torch_outputs
    g = TwoBranchUNet(base=4, weave_waves=2).eval()
    g.set_waves(np.array([[0.7, 0.2], [0.1, 1.1]], np.float32))
    with torch.no_grad():   # weights that make the waves visible in the output
        g.tactile.up0[1].bias[2:] = 0.5
    path = export_graph(g, "tactile", tmp_path / "t.onnx", size=(256, 256))
    mk = np.zeros((1, 1, 256, 256), np.float32)
    mk[..., 60:230, 37:200] = 1
    sk = (np.random.default_rng(0).random(mk.shape, dtype=np.float32) * 2 - 1) * mk
    (ort_out,) = ort_session(path).run(None, {"sketch": sk, "mask": mk})
    (ref,) = torch_outputs(g, "tactile", sk, mk)
    assert np.abs(ort_out - ref).max() < 1e-4


def test_visual_only_waves_leave_the_tactile_head_as_published():
    g = TwoBranchUNet(base=4, weave_waves=3, weave_waves_heads="visual")
    plain = TwoBranchUNet(base=4)
    assert g.visual.up0[1].out_channels == 3 * 7 and g.tactile.up0[1].out_channels == 2
    assert {k: v.shape for k, v in g.tactile.state_dict().items()} == {
        k: v.shape for k, v in plain.tactile.state_dict().items()}
    assert TwoBranchUNet.from_config(g.model_config()).config == g.config
    with pytest.raises(ValueError, match="weave_waves_heads"):
        TwoBranchUNet(base=4, weave_waves=1, weave_waves_heads="tactile")
