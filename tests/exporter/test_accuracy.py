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


def _garment(h=32, w=32):
    mask = np.zeros((1, 1, h, w), np.float32)
    mask[..., 6:26, 6:26] = 1.0
    return NetworkInput(np.zeros_like(mask), mask)


def test_interior_errors_set_edges_aside_and_find_seams():
    from exporter.accuracy import interior_errors
    x = _garment()
    ref = np.zeros((1, 2, 32, 32), np.float32)
    ref[:, 0] = 0.3 * x.mask[0]          # a plain fabric: 66 levels at scale 1 in the calibrated mapping
    ref[0, 0, 8:13, 8:13] = 1.0          # a seam: saturated (255), its centre 2 px from the seam's own edge
    got = ref.copy()
    got[0, 0, 6, 6] = 1.0                # on the garment's outline: an edge's place, set aside
    got[0, 0, 18, 18] = 1.0              # plain interior: 189 levels off
    got[0, 0, 10, 10] = 0.3              # inside the seam: 189 levels off, on a saturated reference pixel
    got[0, 0, 8, 20] = 0.31              # interior too, but a few levels only
    e = interior_errors([{"tactile": ref}], [{"tactile": got}], [x], 1.0)
    assert e["friction_max_interior_levels"] == 189
    assert e["friction_interior_big_px"] == 2 and e["friction_interior_big_saturated"] == 0.5
    # the worst pixel found first in raster order is the seam's centre, among the garment's steepest slopes
    assert e["worst_interior_slope_percentile"] > 90
    assert np.isclose(e["worst_interior_slope_ratio"], 0.3) and e["garment_px"] == 400
    # with the interior pixels untouched only the outline's error is left, and it is not interior
    only_edge = ref.copy()
    only_edge[0, 0, 6, 6] = 1.0
    e = interior_errors([{"tactile": ref}], [{"tactile": only_edge}], [x], 1.0)
    assert e["friction_max_interior_levels"] == 0 and e["friction_interior_big_px"] == 0
    assert e["friction_interior_big_saturated"] == 0.0
    # no garment, or no tactile output: nothing to state, and nothing divided by zero
    blank = NetworkInput(np.zeros_like(x.mask), np.zeros_like(x.mask))
    assert interior_errors([{"tactile": ref}], [{"tactile": got}], [blank], 1.0) == {}
    assert interior_errors([{"visual": ref}], [{"visual": got}], [x], 1.0) == {}


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(1, 24), w=st.integers(1, 24), px=st.integers(1, 3))
def test_inner_and_spread_match_their_definitions(seed, h, w, px):
    from exporter.accuracy import _inner, _spread3
    rng = np.random.default_rng(seed)
    mask = rng.random((h, w)) < 0.8
    a = rng.integers(0, 256, (h, w)).astype(np.int16)
    inner, spread = _inner(mask, px), _spread3(a)
    for i in range(h):
        for j in range(w):
            want = all(0 <= i + di < h and 0 <= j + dj < w and mask[i + di, j + dj]
                       for di in range(-px, px + 1) for dj in range(-px, px + 1))
            assert inner[i, j] == want
            nb = a[max(i - 1, 0):i + 2, max(j - 1, 0):j + 2]
            assert spread[i, j] == nb.max() - nb.min()
