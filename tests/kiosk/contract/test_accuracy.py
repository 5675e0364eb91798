"""One definition of a graph's error in the kiosk's units, for the exporter and for `engine: auto`: friction levels
over the grid and the garment (never dividing by an empty garment), visual PSNR and colour levels."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.contract.accuracy import IDENTICAL_DB, LEVELS_PER_UNIT, deviation, psnr
from kiosk.contract.haptics import JND_RATIO, friction_map

SCALE = 0.05


def test_friction_error_is_in_friction_levels_over_grid_and_garment():
    rng = np.random.default_rng(0)
    mask = np.zeros((1, 1, 64, 64), np.float32)
    mask[..., 16:48, 16:48] = 1.0
    ref = (rng.normal(0, 0.1, (1, 2, 64, 64)) * mask).astype(np.float32)
    got = ref.copy()
    got[..., 16:48, 16:48] *= 1.5  # the garment's slopes 1.5x steeper; outside both are 0
    d = deviation({"tactile": ref}, {"tactile": got}, mask, SCALE)
    fr, fg = (friction_map(t[0, 0], t[0, 1], SCALE).astype(int) for t in (ref, got))
    assert d["friction_mae_levels"] == pytest.approx(np.abs(fr - fg).mean())
    assert d["friction_max_levels"] == np.abs(fr - fg).max()
    # the grid figure is the garment's diluted by the blank three quarters of the grid
    assert d["friction_mae_garment_levels"] == pytest.approx(4 * d["friction_mae_levels"])
    assert d["friction_mae_levels"] > 1.0  # in friction levels, not 127.5 x the slope difference
    assert d["tactile_mae"] == pytest.approx(np.abs(ref.astype(np.float64) - got).mean())


def test_felt_fraction_counts_pixels_a_step_apart_not_a_moved_edge_s_size():
    mask = np.zeros((1, 1, 64, 64), np.float32)
    mask[..., 16:48, 16:48] = 1.0
    ref = np.zeros((1, 2, 64, 64), np.float32)
    ref[0, 0, 16:48, 16:48] = 0.04           # the fabric: a gentle slope, about 28 levels
    ref[0, 0, 16:48, 30] = 1.0               # a seam: saturated
    moved = ref.copy()
    moved[0, 0, 16:48, 30], moved[0, 0, 16:48, 31] = 0.04, 1.0   # the seam one pixel to the right
    d = deviation({"tactile": ref}, {"tactile": moved}, mask, SCALE)
    assert d["friction_max_levels"] == 255 - friction_map(ref[0, 0], ref[0, 1], SCALE)[20, 20]
    assert d["friction_felt_garment_fraction"] == pytest.approx(2 / 32)   # two of the garment's 32 columns
    level = float(friction_map(ref[0, 0], ref[0, 1], SCALE)[20, 20])
    for gain, felt in ((1.05, 0.0), (2.0, 1.0)):   # a 5 % steeper fabric is below a step; twice as steep is not
        steeper = ref.copy()
        steeper[0, 0, 16:48, 16:48] *= gain
        steeper[0, 0, 16:48, 30] = 1.0
        got = float(friction_map(steeper[0, 0], steeper[0, 1], SCALE)[20, 20])
        assert (got / level >= JND_RATIO) == bool(felt)
        assert deviation({"tactile": ref}, {"tactile": steeper}, mask, SCALE)["friction_felt_garment_fraction"] \
            == pytest.approx(felt * 31 / 32)   # the seam column is saturated in both


def test_identical_outputs_and_an_empty_garment():
    v = np.linspace(-1, 1, 3 * 16 * 16, dtype=np.float32).reshape(1, 3, 16, 16)
    t = np.zeros((1, 2, 16, 16), np.float32)
    d = deviation({"visual": v, "tactile": t}, {"visual": v, "tactile": t}, np.zeros((1, 1, 16, 16)), SCALE)
    assert d == {"visual_psnr_db": IDENTICAL_DB, "visual_mae_levels": 0.0, "tactile_mae": 0.0,
                 "friction_mae_levels": 0.0, "friction_max_levels": 0.0}  # no garment: no garment figure
    assert psnr(v, v + 0.02) == pytest.approx(10 * np.log10(4 / 0.02 ** 2), rel=1e-4)
    assert deviation({"visual": v}, {"visual": v + 0.02}, np.ones((1, 1, 16, 16)), SCALE)["visual_mae_levels"] \
        == pytest.approx(0.02 * LEVELS_PER_UNIT, rel=1e-4)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), side=st.integers(1, 24), gain=st.floats(0.0, 4.0))
def test_deviation_is_symmetric_finite_and_never_divides_by_zero(seed, side, gain):
    rng = np.random.default_rng(seed)
    mask = (rng.random((1, 1, side, side)) > 0.5).astype(np.float32)  # may be empty
    ref = np.tanh(rng.normal(0, 0.2, (1, 2, side, side))).astype(np.float32) * mask
    got = np.clip(ref * np.float32(gain), -1, 1)
    a = {"visual": ref[:, :1], "tactile": ref}
    b = {"visual": got[:, :1], "tactile": got}
    one, two = deviation(a, b, mask, SCALE), deviation(b, a, mask, SCALE)
    assert one == two and all(np.isfinite(v) and v >= 0 for v in one.values())
    assert ("friction_mae_garment_levels" in one) == ("friction_felt_garment_fraction" in one) == bool(mask.any())
    if mask.any():
        assert 0.0 <= one["friction_felt_garment_fraction"] <= 1.0
        if gain == 1.0:
            assert one["friction_felt_garment_fraction"] == 0.0
    if mask.any():  # outside the garment both are 0, so the grid figure is the garment's diluted, never larger
        assert one["friction_mae_levels"] <= one["friction_mae_garment_levels"] + 1e-9
    assert one["friction_max_levels"] >= one["friction_mae_levels"]
