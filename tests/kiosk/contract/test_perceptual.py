"""The perceptual friction mapping: fabric quartiles on stated just-noticeable steps, seams saturate, a flat garment
stays at natural friction, every input gives a valid map; and slopes are interpolated before mapping on enlarge."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from kiosk.contract.errors import InputError
from kiosk.contract.haptics import (JND_RATIO, PERCEPTUAL_DEFAULTS, THRESHOLD_LEVEL, check_constants, friction_map,
                                    jnd_steps, perceptual_constants)


def fabric(seed=0, n=128, slope=0.08):
    rng = np.random.default_rng(seed)
    return rng.normal(0, slope, (n, n)), rng.normal(0, slope, (n, n))


def test_jnd_ratio_follows_the_cited_voltage_threshold():
    # 1.21 dB of drive amplitude, force ~ V^2: a factor 10^(2.42/20) in friction level
    assert JND_RATIO == pytest.approx(1.3212, abs=1e-4)
    assert jnd_steps([0, THRESHOLD_LEVEL, THRESHOLD_LEVEL * JND_RATIO ** 3]).tolist() == pytest.approx([0, 0, 3])


def test_fabric_quartiles_land_on_the_stated_steps_and_seams_saturate():
    gx, gy = fabric()
    gx[60:63, :] = 3.0  # a seam: a few per cent of pixels, far steeper than the cloth
    c = perceptual_constants(gx, gy)
    steps = jnd_steps(friction_map(gx, gy, None, normalization="perceptual", constants=c).astype(float))
    plain = np.ones(gx.shape, bool)
    plain[58:65, :] = False
    q25, q75 = np.quantile(steps[plain], (0.25, 0.75))
    assert q25 == pytest.approx(c["steps_low"], abs=0.6)
    assert q75 - q25 == pytest.approx(c["steps_span"], abs=0.8)
    assert friction_map(gx, gy, None, normalization="perceptual", constants=c)[61].min() == 255


def test_flat_garment_is_not_stretched_but_the_paper_mapping_is():
    rng = np.random.default_rng(1)
    gx, gy = rng.normal(0, 0.0006, (96, 96)), rng.normal(0, 0.0006, (96, 96))
    c = perceptual_constants(gx, gy)
    steps = jnd_steps(friction_map(gx, gy, None, normalization="perceptual", constants=c).astype(float))
    assert np.quantile(steps, 0.95) <= 1.0
    assert friction_map(gx, gy, None, normalization="quantile").max() == 255


def test_the_same_fabric_feels_the_same_at_any_amplitude_ratio_above_the_floor():
    gx, gy = fabric(slope=0.05)
    c = perceptual_constants(gx, gy)
    rougher = perceptual_constants(3 * gx, 3 * gy)
    a = friction_map(gx, gy, None, normalization="perceptual", constants=c)
    b = friction_map(3 * gx, 3 * gy, None, normalization="perceptual", constants=rougher)
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 1  # calibration is per garment: same relative texture


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(st.sampled_from([np.float32, np.float64]), st.tuples(st.integers(1, 9), st.integers(1, 9)),
                  elements=st.floats(allow_nan=True, allow_infinity=True, width=32)),
       st.floats(1e-6, 10.0), st.floats(1.01, 100.0))
def test_perceptual_always_valid_and_monotone(field, low, ratio):
    c = dict(PERCEPTUAL_DEFAULTS, gz_low=low, gz_high=low * ratio)
    out = friction_map(field, field.T.copy() if field.shape[0] == field.shape[1] else np.zeros_like(field), None,
                       size=(5, 3), normalization="perceptual", constants=c)
    assert out.dtype == np.uint8 and out.shape == (3, 5)
    f = np.nan_to_num(np.asarray(field, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    a = friction_map(f, np.zeros_like(f), None, normalization="perceptual", constants=c).astype(int)
    b = friction_map(2 * f, np.zeros_like(f), None, normalization="perceptual", constants=c).astype(int)
    assert (b >= a).all()


@pytest.mark.parametrize("bad, match", [
    ({}, "missing"),
    ({**PERCEPTUAL_DEFAULTS, "gz_low": 1.0, "gz_high": 0.5}, "out of range"),
    ({**PERCEPTUAL_DEFAULTS, "gz_low": float("nan"), "gz_high": 1.0}, "finite"),
    ({**PERCEPTUAL_DEFAULTS, "gz_low": 0.1, "gz_high": 1.0, "jnd_ratio": 1.0}, "out of range"),
])
def test_bad_constants_are_refused(bad, match):
    with pytest.raises(InputError, match=match):
        friction_map(np.zeros((2, 2)), np.zeros((2, 2)), None, normalization="perceptual", constants=bad)


def test_constants_fit_their_mapping():
    check_constants("calibrated", {})
    with pytest.raises(InputError, match="takes no constants"):
        check_constants("quantile", {"gz_low": 1.0})
    with pytest.raises(InputError, match="needs its constants"):
        friction_map(np.zeros((2, 2)), np.zeros((2, 2)), None, normalization="perceptual")
    with pytest.raises(InputError, match="unknown perceptual constant"):
        perceptual_constants(np.zeros((2, 2)), np.zeros((2, 2)), loudness=3)


def test_enlarging_keeps_a_fine_ridge_period():
    # A slope sinusoid of 4 px gives friction ridges every 2 px (squared slope). Enlarged 1.75x, interpolating the
    # slopes first keeps ridges every 3.5 px; interpolating the friction map would have smeared them away.
    x = np.arange(64)
    gx = np.tile(0.1 * np.cos(2 * np.pi * x / 4.0), (64, 1))
    out = friction_map(gx, np.zeros_like(gx), 0.01, size=(112, 112)).astype(float)
    spec = np.abs(np.fft.rfft(out[56] - out[56].mean()))
    assert 112 / (np.argmax(spec[1:]) + 1) == pytest.approx(3.5, rel=0.05)
