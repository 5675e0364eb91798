"""The photometric tactile loss: a relief that shades like the photo scores near 0 under a lamp from any side and
at any scale, a flat or misplaced one near 1, and it stays in [0, 1] and finite on any input."""
from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from trainer.models.shading_relief import BANDS, dog_bands
from trainer.recipe.shading import shading_loss, unexplained

torch.set_num_threads(2)
SIDE = 64


def _relief(shift: float = 0.0) -> torch.Tensor:
    """(1, 2, S, S) slopes of a two-wave weave (periods 4 and 5 px), both moved `shift` of a period."""
    y, x = torch.meshgrid(torch.arange(SIDE, dtype=torch.float32), torch.arange(SIDE, dtype=torch.float32),
                          indexing="ij")
    k1, k2 = 2 * math.pi / 4, 2 * math.pi / 5
    ph = k1 * (x + 0.3 * y) - 2 * math.pi * shift
    gx = 0.5 * k1 * torch.cos(ph)
    gy = 0.5 * k1 * 0.3 * torch.cos(ph) + 0.3 * k2 * torch.cos(k2 * y - 2 * math.pi * shift)
    return torch.stack([gx, gy])[None]


def _photo(slopes: torch.Tensor, azimuth: float, albedo: float = 0.6) -> torch.Tensor:
    """A Lambertian photo in [-1, 1] of the relief under a lamp from `azimuth`, 45 degrees up."""
    gx, gy = slopes[0, 0], slopes[0, 1]
    n = torch.stack([-gx, -gy, torch.ones_like(gx)])
    n = n / n.norm(dim=0)
    lamp = torch.tensor([math.cos(azimuth), math.sin(azimuth), 1.0]) / math.sqrt(2)
    shade = (n * lamp.view(3, 1, 1)).sum(0).clamp_min(0.05) * albedo
    return (shade * 2 - 1).expand(1, 3, SIDE, SIDE).clone()


def _mask() -> torch.Tensor:
    m = torch.zeros(1, 1, SIDE, SIDE)
    m[..., 10:-10, 10:-10] = 1
    return m


@pytest.mark.parametrize("azimuth", [0.3 + i * math.pi / 3 for i in range(6)])
def test_the_relief_that_shades_like_the_photo_explains_it_whatever_the_lamp(azimuth):
    s, m = _relief(), _mask()
    photo = _photo(s, azimuth)
    assert shading_loss(s, photo, m).item() < 0.1
    assert shading_loss(3 * s, photo, m).item() == pytest.approx(shading_loss(s, photo, m).item(), abs=1e-4)
    assert shading_loss(torch.zeros_like(s), photo, m).item() == pytest.approx(1.0)
    # the weave a quarter period off: the same texture at the wrong place explains little
    assert shading_loss(_relief(shift=0.25), photo, m).item() > 0.5


def test_bands_shape_and_the_empty_object():
    s = _relief()
    assert dog_bands(s).shape == (1, 2, len(BANDS), SIDE, SIDE)
    photo = _photo(s, 1.0)
    assert shading_loss(s, photo, torch.zeros(1, 1, SIDE, SIDE)).item() == 0.0      # no object: 0, not 0 / 0
    flat_photo = torch.full_like(photo, 0.2)                                          # no shading at all
    assert shading_loss(s, flat_photo, _mask()).item() < 0.01   # float noise is not shading to explain


def test_gradient_reaches_the_relief_on_and_near_the_object_only():
    s0, m = _relief(), _mask()
    photo = _photo(s0, 2.0)
    s = (0.3 * s0 + 0.1 * torch.randn_like(s0)).requires_grad_(True)
    shading_loss(s, photo, m).backward()
    g = s.grad.abs().sum(1)[0]
    assert torch.isfinite(g).all() and g[10:-10, 10:-10].sum() > 0
    assert g[:, :2].sum() == 0 and g[:2, :].sum() == 0    # the relief off the object is never asked to shade


@given(st.integers(0, 2**31 - 1), st.floats(0, 1e3), st.floats(-1, 1))
@settings(max_examples=40, deadline=None)
def test_in_unit_range_and_finite_on_any_input(seed, scale, level):
    gen = torch.Generator().manual_seed(seed)
    s = (torch.randn(2, 2, 24, 24, generator=gen) * scale).requires_grad_(True)
    photo = torch.rand(2, 3, 24, 24, generator=gen) * 2 - 1
    photo[0, :, :8] = level                        # saturated and black patches (the log's floor) included
    photo[1] = level                               # a photo with no shading
    m = (torch.rand(2, 1, 24, 24, generator=gen) > 0.3).float()
    u = unexplained(s, photo, m)
    assert u.shape == (2, len(BANDS)) and torch.isfinite(u).all() and (u >= 0).all() and (u <= 1).all()
    u.mean().backward()
    assert torch.isfinite(s.grad).all()
