"""FB-SIFID: the weight-free SIFID fallback (trainer.texture_distance)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy import linalg, ndimage

from trainer.texture_distance import fb_sifid, fb_sifid_channels, filter_bank, frechet


def _frechet_scipy(xa, xb):
    """The usual FID formula with scipy's sqrtm (what our eigen form must equal on well-conditioned data)."""
    mu1, mu2 = xa.mean(0), xb.mean(0)
    s1, s2 = np.cov(xa, rowvar=False), np.cov(xb, rowvar=False)
    covmean = np.real(linalg.sqrtm(s1 @ s2))
    return float(((mu1 - mu2) ** 2).sum() + np.trace(s1 + s2 - 2 * covmean))


def test_frechet_matches_the_sqrtm_formula():
    rng = np.random.default_rng(0)
    xa = rng.normal(size=(400, 6)) @ rng.normal(size=(6, 6))
    xb = rng.normal(0.3, 1.5, size=(300, 6)) @ rng.normal(size=(6, 6))
    assert frechet(xa, xb) == pytest.approx(_frechet_scipy(xa, xb), rel=1e-6)
    assert frechet(xa, xa) == pytest.approx(0.0, abs=1e-9)


def test_flat_images_are_exact_not_nan():
    # zero covariance on both sides (a flat prediction, flat truth): the distance is the squared mean difference
    a, b = np.full((16, 16), 0.2), np.full((16, 16), -0.1)
    f = filter_bank(a)
    assert np.isfinite(fb_sifid(a, b))
    assert fb_sifid(a, b) == pytest.approx(float(((filter_bank(a) - filter_bank(b)) ** 2)[0, 0].sum()))
    assert f.shape == (16, 16, 18)
    assert np.isnan(fb_sifid(a, b, np.zeros((16, 16), bool)))     # no pixel to compare: NaN, said, not 0


def test_shifted_texture_scores_better_than_blurred_texture():
    # What the metric is for: the same weave at another phase is the same fabric (per-pixel error calls it far),
    # the blurred weave is a different, smoother fabric (per-pixel error calls it close).
    rng = np.random.default_rng(1)
    tex = ndimage.gaussian_filter(rng.normal(size=(128, 128)), 1.0)
    shifted = np.roll(tex, (7, 5), (0, 1))
    blurred = ndimage.gaussian_filter(tex, 2.0)
    assert ((shifted - tex) ** 2).mean() > ((blurred - tex) ** 2).mean()
    assert fb_sifid(shifted, tex) < 0.1 * fb_sifid(blurred, tex)


def test_channels_are_averaged():
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(2, 24, 24)), rng.normal(size=(2, 24, 24))
    assert fb_sifid_channels(a, b) == pytest.approx((fb_sifid(a[0], b[0]) + fb_sifid(a[1], b[1])) / 2)


def test_filter_bank_refuses_non_images():
    with pytest.raises(ValueError, match="2-D image"):
        filter_bank(np.zeros((2, 8, 8)))


samples = arrays(np.float64, st.tuples(st.integers(2, 40), st.integers(1, 4)),
                 elements=st.floats(-1e3, 1e3, allow_nan=False))


@settings(max_examples=60, deadline=None)
@given(samples, samples)
def test_frechet_is_finite_nonnegative_and_symmetric(xa, xb):
    if xa.shape[1] != xb.shape[1]:
        xb = np.resize(xb, (xb.shape[0], xa.shape[1]))
    d = frechet(xa, xb)
    assert np.isfinite(d) and d >= 0
    assert d == pytest.approx(frechet(xb, xa), rel=1e-6, abs=1e-6 * (1 + np.abs(xa).max() + np.abs(xb).max()) ** 2)
