"""The error figures the exporter states: the garment's friction error is the grid's, undiluted by blank paper."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from exporter.accuracy import compare_outputs
from kiosk.contract.sketch import NetworkInput


class _Perturbed:
    """A stand-in for a quantized session: the reference's tactile plus `noise`, masked like the graph's heads."""

    def __init__(self, tactile: np.ndarray, noise: np.ndarray, mask: np.ndarray):
        self.out = (tactile + noise) * mask

    def run(self, names, feed):
        return [self.out for _ in names]


def _case(seed: int, h: int, w: int, frac: float):
    rng = np.random.default_rng(seed)
    mask = np.zeros((1, 1, h, w), np.float32)
    mask[..., : max(1, int(round(h * frac))), :] = 1.0
    tactile = rng.normal(0, 0.05, (1, 2, h, w)).astype(np.float32) * mask
    noise = rng.normal(0, 0.01, (1, 2, h, w)).astype(np.float32)
    x = NetworkInput(np.zeros((1, 1, h, w), np.float32), mask)
    return x, tactile, noise, mask


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(8, 40), w=st.integers(8, 40), frac=st.floats(0.05, 1.0))
def test_garment_error_is_the_grid_error_undiluted(seed, h, w, frac):
    x, tactile, noise, mask = _case(seed, h, w, frac)
    err = compare_outputs([{"tactile": tactile}], _Perturbed(tactile, noise, mask), ["tactile"], [x], 0.02)
    inside = float(mask.mean())
    assert np.isfinite(err["friction_mae_garment_levels"])
    # outside the garment both outputs are exactly 0, so the grid mean is the garment mean times its share
    assert np.isclose(err["friction_mae_levels"], err["friction_mae_garment_levels"] * inside, rtol=1e-6, atol=1e-9)
    assert err["friction_mae_garment_levels"] >= err["friction_mae_levels"] - 1e-9


def test_no_garment_states_no_garment_error():
    """An empty mask has no garment to measure: the figure is left out rather than divided by zero."""
    h = w = 16
    x = NetworkInput(np.zeros((1, 1, h, w), np.float32), np.zeros((1, 1, h, w), np.float32))
    zero = np.zeros((1, 2, h, w), np.float32)
    err = compare_outputs([{"tactile": zero}], _Perturbed(zero, zero, x.mask), ["tactile"], [x], 0.02)
    assert err["friction_mae_levels"] == 0.0
    assert "friction_mae_garment_levels" not in err
