"""The haptic math of the runtime contract: analytic surfaces, inverses, and the hard cases."""
import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from kiosk.contract.errors import InputError
from kiosk.contract.haptics import (MIN_FRICTION_SCALE, NonFiniteCounter, calibrate_scale, friction_map,
                           gradients_from_normals, height_from_gradients, normals_from_gradients)

H, W = 96, 128
Y, X = np.mgrid[0:H, 0:W].astype(np.float64)


def rel_rms(a, b):
    a = a - a.mean()
    b = b - b.mean()
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b ** 2)))


# ---------------------------------------------------------------- height
def test_height_sinusoid():
    h = 0.4 * np.sin(2 * np.pi * X / 32) * np.cos(2 * np.pi * Y / 40)
    gx = 0.4 * 2 * np.pi / 32 * np.cos(2 * np.pi * X / 32) * np.cos(2 * np.pi * Y / 40)
    gy = -0.4 * 2 * np.pi / 40 * np.sin(2 * np.pi * X / 32) * np.sin(2 * np.pi * Y / 40)
    rec = height_from_gradients(gx, gy)
    assert rec.dtype == np.float32 and rec.shape == (H, W)
    assert abs(float(rec.mean())) < 1e-5
    assert rel_rms(rec, h) < 0.01


def test_height_paraboloid_and_pixel_pitch():
    h = ((X - 60) ** 2 + (Y - 40) ** 2) / 200.0
    gx, gy = 2 * (X - 60) / 200.0, 2 * (Y - 40) / 200.0
    assert rel_rms(height_from_gradients(gx, gy), h) < 0.005
    # Slopes are dimensionless: a pitch of 0.3 mm/px gives heights in mm, 0.3 times the pixel-unit height.
    assert rel_rms(height_from_gradients(gx, gy, pixel_pitch=0.3), 0.3 * h) < 0.005


def test_height_step_from_central_differences():
    h = np.where(X >= 64, 2.0, 0.0)
    gy, gx = np.gradient(h)
    rec = height_from_gradients(gx, gy)
    plateau_hi, plateau_lo = rec[:, 70:], rec[:, :58]
    assert abs((plateau_hi.mean() - plateau_lo.mean()) - 2.0) < 0.02
    assert rec.max() - plateau_hi.mean() < 0.04 and plateau_lo.mean() - rec.min() < 0.04


def test_height_discards_the_non_integrable_part():
    # A divergence-free field tangential at the border (from a stream function vanishing there) has no
    # integrable component: the least-squares height is flat.
    psi_y = np.pi / H * np.sin(np.pi * X / W) * np.cos(np.pi * Y / H)
    psi_x = np.pi / W * np.cos(np.pi * X / W) * np.sin(np.pi * Y / H)
    rotational = height_from_gradients(psi_y, -psi_x)
    # The same magnitudes arranged as a true gradient (of psi, amplitude 1) integrate to amplitude ~1.
    integrable = height_from_gradients(psi_x, psi_y)
    assert np.ptp(integrable) > 0.9
    assert np.ptp(rotational) < 0.07


@settings(max_examples=40, deadline=None)
@given(hnp.arrays(np.float64, st.tuples(st.integers(1, 12), st.integers(1, 12)),
                  elements=st.floats(allow_nan=True, allow_infinity=True, width=64)))
def test_height_always_finite(field):
    rec = height_from_gradients(field, field.T.copy().T)
    assert rec.shape == field.shape and np.isfinite(rec).all()


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), "1"])
def test_height_rejects_bad_pitch(bad):
    with pytest.raises(InputError, match="pixel_pitch"):
        height_from_gradients(np.zeros((3, 3)), np.zeros((3, 3)), pixel_pitch=bad)


# ---------------------------------------------------------------- normals
@settings(max_examples=60, deadline=None)
@given(hnp.arrays(np.float64, (4, 5), elements=st.floats(-50, 50)),
       hnp.arrays(np.float64, (4, 5), elements=st.floats(-50, 50)))
def test_normals_round_trip(gx, gy):
    n = normals_from_gradients(gx, gy)
    assert n.dtype == np.float32 and n.shape == (4, 5, 3)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, rtol=1e-5)
    assert (n[..., 2] < 0).all()
    rx, ry = gradients_from_normals(n)
    np.testing.assert_allclose(rx, gx, rtol=2e-3, atol=2e-4)
    np.testing.assert_allclose(ry, gy, rtol=2e-3, atol=2e-4)


def test_flat_normal_points_down_z():
    assert normals_from_gradients(np.zeros((1, 1)), np.zeros((1, 1)))[0, 0].tolist() == [0.0, 0.0, -1.0]


def test_gradients_safe_where_nz_vanishes():
    n = np.array([[[1.0, 0.0, 0.0], [0.0, -1.0, 1e-300], [0.0, 0.0, 0.0], [3e300, 0, -3e300]]])
    gx, gy = gradients_from_normals(n, max_slope=50.0)
    assert np.isfinite(gx).all() and np.isfinite(gy).all()
    assert gx[0, 0] == pytest.approx(50.0) and gy[0, 1] == pytest.approx(50.0)
    assert gx[0, 2] == 0 and gy[0, 2] == 0
    assert gx[0, 3] == pytest.approx(1.0)


def test_normals_of_huge_slopes_are_finite():
    n = normals_from_gradients(np.array([[1e30, -1e300]]), np.array([[0.0, 0.0]]))
    assert np.isfinite(n).all()
    np.testing.assert_allclose(n[0, :, 0], [1.0, -1.0])


def test_normals_bad_shapes():
    with pytest.raises(InputError, match="same shape"):
        normals_from_gradients(np.zeros((2, 3)), np.zeros((3, 2)))
    with pytest.raises(InputError, match="2-D"):
        normals_from_gradients(np.zeros(3), np.zeros(3))
    with pytest.raises(InputError, match=r"\(H, W, 3\)"):
        gradients_from_normals(np.zeros((2, 2, 2)))
    with pytest.raises(InputError, match="numeric"):
        normals_from_gradients(np.array([["a"]]), np.array([["b"]]))


# ---------------------------------------------------------------- friction map
def test_friction_formula():
    gx = np.array([[0.0, 0.1, 0.2, 1.0]])
    gy = np.zeros_like(gx)
    scale = 0.04
    z = np.clip((gx ** 2 + gy ** 2) / scale, 0, 1)
    expect = np.rint(np.log10(9 * z + 1) * 255).astype(np.uint8)
    np.testing.assert_array_equal(friction_map(gx, gy, scale), expect)


def test_flat_garment_stays_low_friction_but_quantile_stretches_it():
    rng = np.random.default_rng(0)
    gx, gy = (1e-3 * rng.standard_normal((64, 64)) for _ in range(2))
    calibrated = friction_map(gx, gy, scale=0.05)
    stretched = friction_map(gx, gy, None, normalization="quantile")
    assert calibrated.max() <= 2
    assert stretched.max() == 255


def test_friction_hard_cases_never_leak_nonfinite():
    gx = np.array([[np.nan, np.inf, -np.inf, 1e30, 0.0]])
    gy = np.array([[0.0, 0.0, 0.0, 0.0, 1e-30]])
    counter = NonFiniteCounter()
    out = friction_map(gx, gy, 0.05, counter=counter)
    assert out.tolist() == [[0, 0, 0, 255, 0]]
    assert counter.count == 3
    out = friction_map(gx, gy, None, normalization="quantile")
    assert out.dtype == np.uint8


def test_friction_does_not_modify_input():
    gx = np.full((3, 3), 5.0, np.float32)
    gy = np.full((3, 3), np.nan, np.float32)
    friction_map(gx, gy, 0.05)
    assert (gx == 5).all() and np.isnan(gy).all()


@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64, np.int16])
def test_friction_dtypes(dtype):
    gx = np.ones((3, 5), dtype=dtype)
    out = friction_map(gx, np.zeros((3, 5), dtype=dtype), 2.0)
    assert out.dtype == np.uint8 and (out == np.rint(np.log10(9 * 0.5 + 1) * 255)).all()


def test_friction_non_contiguous_and_tiny_sizes():
    big = np.arange(60, dtype=np.float64).reshape(6, 10) / 100
    view = big[::2, ::3]
    assert not view.flags["C_CONTIGUOUS"]
    np.testing.assert_array_equal(friction_map(view, view, 0.1), friction_map(view.copy(), view.copy(), 0.1))
    for shape in [(1, 1), (1, 9), (9, 1), (3, 5)]:
        out = friction_map(np.ones(shape), np.zeros(shape), 0.5, size=(7, 2))
        assert out.shape == (2, 7)
    assert friction_map(np.ones((1, 1)), np.ones((1, 1)), 0.5).shape == (1, 1)


def test_friction_resize_to_panel():
    gx = np.zeros((96, 128))
    gx[:, 64:] = 1.0
    out = friction_map(gx, np.zeros_like(gx), 0.5, size=(1280, 800))
    assert out.shape == (800, 1280)
    assert out[:, :600].max() == 0 and out[:, 700:].min() == 255


@pytest.mark.parametrize("scale", [0.0, -1.0, float("nan"), float("inf"), None, "0.1"])
def test_friction_rejects_bad_scale(scale):
    with pytest.raises(InputError, match="scale"):
        friction_map(np.zeros((2, 2)), np.zeros((2, 2)), scale)


@pytest.mark.parametrize("size", [(0, 5), (5, -1), "ab", (1, 2, 3), (20000, 10)])
def test_friction_rejects_bad_size(size):
    with pytest.raises(InputError, match="size"):
        friction_map(np.zeros((2, 2)), np.zeros((2, 2)), 0.1, size=size)


def test_friction_rejects_unknown_normalization():
    with pytest.raises(InputError, match="normalization"):
        friction_map(np.zeros((2, 2)), np.zeros((2, 2)), 0.1, normalization="minmax")  # type: ignore[arg-type]


@settings(max_examples=80, deadline=None)
@given(hnp.arrays(st.sampled_from([np.float16, np.float32, np.float64]),
                  st.tuples(st.integers(1, 9), st.integers(1, 9)),
                  elements=st.floats(allow_nan=True, allow_infinity=True, width=16)),
       st.floats(1e-6, 1e6), st.sampled_from(["calibrated", "quantile"]))
def test_friction_property_always_valid_uint8(field, scale, normalization):
    out = friction_map(field, field[::-1].copy(), scale, size=(5, 3), normalization=normalization)
    assert out.dtype == np.uint8 and out.shape == (3, 5)


@settings(max_examples=40, deadline=None)
@given(hnp.arrays(np.float64, (5, 5), elements=st.floats(-2, 2)), st.floats(1e-3, 10))
def test_friction_is_monotone_in_slope(field, scale):
    a = friction_map(field, np.zeros_like(field), scale).astype(int)
    b = friction_map(field * 1.5, np.zeros_like(field), scale).astype(int)
    assert (b >= a).all()


# ---------------------------------------------------------------- calibration
def test_calibrate_scale():
    gx = np.linspace(0, 1, 101)[None, :].repeat(3, 0)
    assert calibrate_scale(gx, np.zeros_like(gx), quantile=1.0) == pytest.approx(1.0)
    assert calibrate_scale(np.zeros((4, 4)), np.zeros((4, 4))) == MIN_FRICTION_SCALE
    mask = np.zeros((3, 101), bool)
    assert calibrate_scale(gx, np.zeros_like(gx), mask) == MIN_FRICTION_SCALE
    mask[:, :11] = True
    assert calibrate_scale(gx, np.zeros_like(gx), mask, quantile=1.0) == pytest.approx(0.01)
    with pytest.raises(InputError):
        calibrate_scale(gx, gx, quantile=0.0)
    with pytest.raises(InputError, match="mask"):
        calibrate_scale(gx, gx, np.ones((2, 2), bool))


def _mean_friction_per_pixel(gx, gy, scale, k=16):
    """Reference device frame: the surface mapped 16x finer than the model's pixels, averaged over each pixel."""
    h, w = gx.shape
    fine = friction_map(gx, gy, scale, size=(w * k, h * k), supersample=1).astype(np.float32)
    return cv2.resize(fine, (w, h), interpolation=cv2.INTER_AREA)


@pytest.mark.parametrize("period_px", [3.0, 4.3])
def test_panel_at_model_pitch_gets_the_mean_friction_not_an_alias(period_px):
    # Twill-like diagonal ribs (a fundamental and a sharpening second harmonic) on a panel of the model's own pitch.
    # Squaring the slope doubles its frequencies past what the model's pixels hold; mapping at those pixels folds
    # them back into a false coarser texture. Each panel pixel must carry the mean friction of the surface under it.
    n = 96
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    t = 2 * np.pi * ((xx + yy) / np.sqrt(2)) / period_px
    g = 0.05 * (-np.sin(t) - 0.5 * np.sin(2 * t + 0.6)) / np.sqrt(2)
    ref = _mean_friction_per_pixel(g, g, 0.003)
    inner = (slice(4, -4), slice(4, -4))
    err = np.abs(friction_map(g, g, 0.003, size=(n, n)).astype(float) - ref)[inner].mean()
    point = np.abs(friction_map(g, g, 0.003, size=(n, n), supersample=1).astype(float) - ref)[inner].mean()
    assert err < 8.0 and point > 4 * err  # levels of 255; mapping at the model's pixels is off by 40-60


@pytest.mark.parametrize("bad", [0, 9, 1.5, True, "2"])
def test_friction_rejects_bad_supersample(bad):
    with pytest.raises(InputError, match="supersample"):
        friction_map(np.zeros((2, 2)), np.zeros((2, 2)), 0.1, size=(2, 2), supersample=bad)
