"""The felt-texture measures: spectral period of known textures, whole-spectrum scale, contrast in steps."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.bench.felt import contrast_steps, dominant_period_px, felt_scale
from kiosk.contract.errors import InputError
from kiosk.contract.haptics import JND_RATIO, THRESHOLD_LEVEL


def grating(period, shape=(160, 200), angle=0.0, harmonic=0.0):
    y, x = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    u = x * np.cos(angle) + y * np.sin(angle)
    return np.cos(2 * np.pi * u / period) + harmonic * np.cos(4 * np.pi * u / period + 0.3)


@settings(max_examples=40, deadline=None)
@given(period=st.floats(3.0, 16.0), angle=st.floats(0, np.pi))  # at least 10 periods in the window
def test_period_of_a_grating_at_any_orientation(period, angle):
    assert dominant_period_px(grating(period, angle=angle)) == pytest.approx(period, rel=0.04)


def test_fundamental_wins_over_a_strong_harmonic():
    assert dominant_period_px(grating(20.0, harmonic=0.9)) == pytest.approx(20.0, rel=0.04)


def test_period_band_and_bad_input():
    assert np.isnan(dominant_period_px(np.ones((32, 32))))
    slow_fast = grating(60.0, (240, 240)) + 0.5 * grating(6.0, (240, 240))
    assert dominant_period_px(slow_fast, max_period_px=20) == pytest.approx(6.0, rel=0.04)
    with pytest.raises(InputError, match="at least 8x8"):
        dominant_period_px(np.zeros((4, 40)))


@pytest.mark.parametrize("stretch", [0.57, 1.0, 1.6])
def test_felt_scale_recovers_a_resampling(stretch):
    import cv2
    rng = np.random.default_rng(0)
    truth = cv2.GaussianBlur(rng.normal(size=(300, 300)), (0, 0), 3) + grating(11.0, (300, 300), 0.4)
    # the device frame shows the truth stretched by `stretch` at the same pitch
    big = cv2.resize(truth, None, fx=stretch, fy=stretch, interpolation=cv2.INTER_LINEAR)
    device = big[:200, :200]
    assert felt_scale(device, 0.2, truth, 0.2, max_period_mm=8.0) == pytest.approx(stretch, rel=0.03)


def test_contrast_in_steps():
    lv = np.array([THRESHOLD_LEVEL * JND_RATIO ** 2] * 50 + [THRESHOLD_LEVEL * JND_RATIO ** 7] * 50)
    assert contrast_steps(lv) == pytest.approx(5.0, abs=0.01)
    assert contrast_steps(np.zeros(10)) == 0.0  # below the detection threshold: nothing felt
    with pytest.raises(InputError, match="no pixels"):
        contrast_steps(np.zeros(4), np.zeros(4, bool))
