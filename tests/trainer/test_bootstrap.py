"""The paired hierarchical bootstrap on cases with a known answer."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trainer.bootstrap import Units, mse_to_psnr, paired_bootstrap, reduce, value


def _u(values, keys=None, den=None):
    values = np.asarray(values, float)
    keys = np.arange(len(values)) if keys is None else keys
    den = np.ones(len(values)) if den is None else den
    return Units(keys, values * np.asarray(den, float), den)


def test_constant_paired_difference_has_a_zero_width_interval():
    # every unit differs by exactly 0.5, whatever its level: pairing removes the between-unit spread entirely
    base = np.random.default_rng(0).normal(10, 3, 200)
    d = paired_bootstrap("m", {"g": [_u(base + 0.5)]}, {"g": [_u(base)]}, n_boot=500)
    assert d.diff == pytest.approx(0.5) and d.lo == pytest.approx(0.5) and d.hi == pytest.approx(0.5)
    assert (d.garments, d.units) == (1, 200)


def test_two_garments_interval_is_the_exact_percentiles_of_the_garment_resample():
    # garment differences 0 and 1 (units constant within a garment): resampled means are 0, 0.5, 1 with
    # probabilities 1/4, 1/2, 1/4, so the 95 % percentile interval is [0, 1] and the point estimate 0.5
    a = {"g0": [_u(np.zeros(50))], "g1": [_u(np.ones(50))]}
    b = {"g0": [_u(np.zeros(50))], "g1": [_u(np.zeros(50))]}
    d = paired_bootstrap("m", a, b, n_boot=4000, seed=1)
    assert (d.diff, d.lo, d.hi, d.garments) == (0.5, 0.0, 1.0, 2)


def test_unit_level_interval_matches_the_normal_theory_width():
    # one garment, one seed each, paired differences iid N(0.3, 1): the 95 % interval of the mean difference is
    # about 0.3 +- 1.96 / sqrt(n)
    rng = np.random.default_rng(2)
    n = 400
    base, noise = rng.normal(0, 5, n), rng.normal(0.3, 1.0, n)
    d = paired_bootstrap("m", {"g": [_u(base + noise)]}, {"g": [_u(base)]}, n_boot=4000, seed=3)
    half = 1.96 * noise.std(ddof=1) / np.sqrt(n)
    assert d.diff == pytest.approx(noise.mean())
    assert (d.hi - d.lo) / 2 == pytest.approx(half, rel=0.12)
    assert d.lo < 0.3 < d.hi


def test_seed_spread_widens_the_interval_and_unpaired_units_are_dropped():
    base = np.arange(30.0)
    one = paired_bootstrap("m", {"g": [_u(base + 1)]}, {"g": [_u(base)]}, n_boot=1000)
    seeds = paired_bootstrap("m", {"g": [_u(base + 0), _u(base + 2)]}, {"g": [_u(base)]}, n_boot=1000)
    assert one.hi - one.lo == pytest.approx(0.0) and seeds.diff == pytest.approx(1.0)
    assert seeds.lo == pytest.approx(0.0) and seeds.hi == pytest.approx(2.0)
    # B lacks units 0..9: only the 20 common units are compared
    part = paired_bootstrap("m", {"g": [_u(base + 1)]}, {"g": [_u(base[10:], keys=np.arange(10, 30))]}, n_boot=200)
    assert part.units == 20 and part.diff == pytest.approx(1.0)


def test_ratio_metrics_and_psnr_reduce_from_sums_without_dividing_by_zero():
    u = Units([0, 1, 2], [1.0, 3.0, 0.0], [1.0, 1.0, 0.0])
    assert len(u) == 2 and value("m", u) == pytest.approx(2.0)   # the zero-weight unit is dropped
    assert np.isnan(reduce("m", 1.0, 0.0))
    assert value("visual_psnr", Units([0], [0.01], [1.0])) == pytest.approx(20.0)
    assert mse_to_psnr(0.0) == pytest.approx(120.0)
    # PSNR differences are taken between PSNRs (of resampled MSEs), not PSNR of an MSE difference
    d = paired_bootstrap("visual_psnr", {"g": [_u(np.full(10, 0.001))]}, {"g": [_u(np.full(10, 0.01))]},
                         n_boot=200)
    assert d.diff == pytest.approx(10.0)


def test_no_common_garment_or_bad_input_is_reported():
    assert paired_bootstrap("m", {"a": [_u([1.0])]}, {"b": [_u([1.0])]}) is None
    with pytest.raises(ValueError, match="unique"):
        Units([0, 0], [1, 1], [1, 1])
    with pytest.raises(ValueError, match="one length"):
        Units([0, 1], [1], [1, 1])
    with pytest.raises(ValueError, match="level"):
        paired_bootstrap("m", {}, {}, level=1.0)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-100, 100), min_size=3, max_size=40), st.floats(-10, 10), st.integers(0, 2 ** 31))
def test_shifting_every_unit_of_a_shifts_point_and_interval_by_the_same(vals, shift, seed):
    a, b = np.array(vals), np.array(vals[::-1])
    d0 = paired_bootstrap("m", {"g": [_u(a)]}, {"g": [_u(b)]}, n_boot=200, seed=seed % 1000)
    d1 = paired_bootstrap("m", {"g": [_u(a + shift)]}, {"g": [_u(b)]}, n_boot=200, seed=seed % 1000)
    assert d1.diff == pytest.approx(d0.diff + shift, abs=1e-6)
    assert d1.lo == pytest.approx(d0.lo + shift, abs=1e-6) and d1.hi == pytest.approx(d0.hi + shift, abs=1e-6)
    assert d0.lo <= d0.hi
