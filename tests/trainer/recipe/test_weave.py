"""The weave-scale visual loss: it sees the fine shading bands and nothing coarser, and stays finite on any image."""
from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from trainer.models.shading_relief import BANDS
from trainer.recipe.weave import fine_bands, weave_loss

torch.set_num_threads(2)
SIDE = 48


def _cloth(period: float = 4.0, phase: float = 0.0, base: float = 0.4, lamp: float = 0.2) -> torch.Tensor:
    """A grey cloth with a fine weave (a few percent of contrast) on a slow lamp falloff, in [-1, 1]."""
    y, x = torch.meshgrid(torch.arange(SIDE, dtype=torch.float32), torch.arange(SIDE, dtype=torch.float32),
                          indexing="ij")
    lum = base * (1 + lamp * (x + y) / SIDE) * (1 + 0.06 * torch.sin(2 * math.pi * x / period + phase))
    return (lum * 2 - 1).expand(1, 3, SIDE, SIDE).clone()


def _mask() -> torch.Tensor:
    m = torch.zeros(1, 1, SIDE, SIDE)
    m[..., 12:-12, 12:-12] = 1   # 12 px of background: beyond the bands' reach (3 sigma of 3 px)
    return m


def test_the_loss_sees_the_weave_not_the_brightness_nor_the_lamp():
    real, m = _cloth(), _mask()
    assert weave_loss(real, real, m).item() == 0.0
    dimmer = ((real + 1) * 0.8) - 1            # the same cloth under a weaker lamp: the same log-contrast
    assert weave_loss(dimmer, real, m).item() < 1e-5
    no_lamp = _cloth(lamp=0.0)                 # the same weave without the lamp's falloff
    assert weave_loss(no_lamp, real, m).item() < 0.1 * weave_loss(torch.zeros_like(real), real, m).item()
    plain = torch.full_like(real, real.mean().item())   # the weave's blurred average: what an L1 rewards
    shifted = _cloth(phase=math.pi)                     # the weave painted half a period off
    l_plain, l_shift = weave_loss(plain, real, m).item(), weave_loss(shifted, real, m).item()
    assert 0 < l_plain < l_shift


def test_bands_are_the_shading_reliefs_and_only_the_object_counts():
    real = _cloth()
    assert fine_bands(real).shape == (1, len(BANDS), SIDE, SIDE)
    m = _mask()
    off = real.clone()
    off[..., :3, :] = -1                       # scribble on the background, well away from the object
    assert weave_loss(off, real, m).item() == pytest.approx(0.0, abs=1e-6)
    assert weave_loss(off, real, torch.zeros_like(m)).item() == 0.0   # no object: defined, no division by 0


def test_gradient_reaches_the_fake_only_on_and_near_the_object():
    real, m = _cloth(), _mask()
    fake = torch.zeros_like(real, requires_grad=True)
    weave_loss(fake, real, m).backward()
    g = fake.grad.abs().sum(1)[0]
    assert torch.isfinite(g).all() and g[12:-12, 12:-12].sum() > 0
    assert g[0, :].sum() == 0                  # beyond the bands' reach of the object


@given(st.lists(st.floats(-1, 1), min_size=6, max_size=6), st.integers(0, 2**31 - 1))
@settings(max_examples=40, deadline=None)
def test_finite_and_non_negative_on_any_image(levels, seed):
    gen = torch.Generator().manual_seed(seed)
    a = torch.rand(1, 3, 24, 24, generator=gen) * 2 - 1
    b = torch.rand(1, 3, 24, 24, generator=gen) * 2 - 1
    a[..., :8, :] = levels[0]                  # saturated and black regions (the log's floor) included
    b[..., 8:12, :] = levels[3]
    a[..., :, :4] = -1
    b[..., :, :4] = 1
    m = (torch.rand(1, 1, 24, 24, generator=gen) > 0.3).float()
    a.requires_grad_(True)
    loss = weave_loss(a, b, m)
    loss.backward()
    assert math.isfinite(loss.item()) and loss.item() >= 0
    assert torch.isfinite(a.grad).all()
