"""The protocol's config keys (kind, release, consent, demographics, familiarisation), the familiarisation
textures at their physical size, the report's plot wording and its visible 0 % bar, and the live view's text."""
from __future__ import annotations

import hashlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.contract.errors import InputError
from kiosk.study.config import StudyConfigError, Texture, load_study_config
from kiosk.study.familiarise import texture_pixels
from kiosk.study.report import _bars, default_title
from kiosk.study.watch import format_status

from .helpers import write_config

FAM = {"screen_mm": [200, 100]}


def test_protocol_keys_load_with_their_defaults(tmp_path):
    cfg = load_study_config(write_config(tmp_path))
    assert (cfg.kind, cfg.release, cfg.consent, cfg.demographics, cfg.familiarisation) == \
        ("haptic", "each_trial", None, None, None)
    assert "60 seconds per pair" in cfg.instructions
    consent = tmp_path / "consent.txt"
    consent.write_text("I agree.\n")
    cfg = load_study_config(write_config(tmp_path, kind="visual", consent={"version": 3, "file": "consent.txt"},
                                         demographics={"age_band": ["18-24", "25+"]}, time_limit_s=None))
    assert cfg.kind == "visual" and cfg.release == "none" and cfg.time_limit_s is None
    assert cfg.question == "Which image do you think is more realistic?" and "no time limit" in cfg.instructions
    assert cfg.consent.version == "3" and cfg.consent.sha256 == hashlib.sha256(b"I agree.").hexdigest()
    cfg = load_study_config(write_config(tmp_path, familiarisation=FAM))
    assert [t.kind for t in cfg.familiarisation.textures] == ["uniform", "uniform", "grating", "grating", "bump",
                                                              "ridge"]


@pytest.mark.parametrize("change, message", [
    ({"kind": "smell"}, "kind must be one of haptic, visual"),
    ({"release": "sometimes"}, "release must be one of each_trial, new_garment, none"),
    ({"time_limit_s": 0}, "time_limit_s must be between 1 and 3600"),
    ({"consent": {"version": "1"}}, "consent needs exactly one of 'text'"),
    ({"consent": {"text": "ok"}}, "consent.version must be"),
    ({"consent": {"version": "1", "file": "missing.txt"}}, "cannot read consent.file"),
    ({"demographics": {"Name": ["a", "b"]}}, "must be a lower-case name"),
    ({"demographics": {"age": ["18"]}}, "must list 2 to 20 distinct choices"),
    ({"familiarisation": {"textures": []}}, "screen_mm must be the haptic screen's"),
    ({"familiarisation": {**FAM, "textures": [{"kind": "wave"}]}}, "kind must be one of uniform"),
    ({"familiarisation": {**FAM, "textures": [{"kind": "grating"}]}}, "period_mm must be a number"),
    ({"familiarisation": {**FAM, "textures": [{"kind": "uniform", "level": 2}]}}, "level must be between 0 and 1"),
    ({"familiarisation": {**FAM, "textures": [{"kind": "bump", "period_mm": 2}]}}, "unknown key(s)"),
    ({"kind": "visual", "familiarisation": FAM}, "familiarisation is for haptic studies"),
    ({"kiosk_name": "a b"}, "kiosk_name 'a b' must be"),
])
def test_bad_protocol_keys_name_the_key(tmp_path, change, message):
    with pytest.raises(StudyConfigError) as err:
        load_study_config(write_config(tmp_path, **change))
    assert message in str(err.value)


@settings(max_examples=40, deadline=None)
@given(period=st.floats(2.0, 40.0), width_px=st.integers(300, 1600), mm=st.floats(100.0, 400.0))
def test_grating_has_its_period_in_millimetres(period, width_px, mm):
    pitch = mm / width_px
    if period < 4 * pitch:
        return
    row = texture_pixels(Texture("grating", level=1.0, period_mm=period), (width_px, 2), (width_px, 400),
                         (mm, 100.0))[0].astype(float)
    spectrum = np.abs(np.fft.rfft(row - row.mean(), n=16 * width_px))
    measured = 16 * width_px / np.argmax(spectrum) * pitch
    assert measured == pytest.approx(period, rel=0.05)
    if period / pitch >= 16:                                      # sampled finely enough to reach both extremes
        assert row.max() >= 250 and row.min() <= 5


def test_bump_ridge_and_uniform_sizes():
    screen, mm = (400, 200), (200.0, 100.0)                      # 0.5 mm per pixel
    bump = texture_pixels(Texture("bump", level=1.0, diameter_mm=20), (400, 200), screen, mm)
    assert (bump[100] > 0).sum() == pytest.approx(40, abs=2)     # 20 mm across = 40 px
    ridge = texture_pixels(Texture("ridge", level=0.5, width_mm=6), (400, 200), screen, mm)
    assert (ridge[0] > 0).sum() == pytest.approx(12, abs=2) and 120 <= ridge.max() <= 128
    assert (texture_pixels(Texture("uniform", level=0.25), (7, 3), screen, mm) == 64).all()
    with pytest.raises(InputError, match="finer than this screen"):
        texture_pixels(Texture("grating", period_mm=0.6), (400, 200), screen, mm)


def test_plot_says_one_participant_and_draws_a_zero_bar():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    comp = {"baseline": "pix2pix", "rate": 0.0, "n": 5, "wilson95": [0.0, 0.43]}
    rep = {"reference": "ours", "participants": 1, "kind": "haptic", "comparisons": [comp]}
    assert default_title(rep).endswith("(1 participant)")
    assert default_title({**rep, "participants": 2}).endswith("(2 participants)")
    fig, ax = plt.subplots()
    _bars(ax, rep, default_title(rep))
    zero = [ln for ln in ax.lines if list(ln.get_ydata()) == [0, 0]]
    assert zero and zero[0].get_linewidth() >= 2                  # a visible mark at 0 %
    assert any(t.get_text() == "0.0%" for t in ax.texts)
    plt.close(fig)


def test_live_view_hides_counts_unless_asked():
    base = {"study_id": "s", "kind": "haptic", "sessions": 1, "responses": 3, "withdrawn": [],
            "participants_done": [], "counts": None,
            "active": {"participant": "P01", "session": 1, "stage": "wait", "test_answered": 2, "test_trials": 15,
                       "answered": 3, "trials": 16, "put_garment_on_table": "wool-coat", "trial": 3,
                       "block": "test", "comparison": "gaugan", "waiting_for_release": True, "time_left_s": None,
                       "error": None, "familiarisation": None}}
    text = format_status(base)
    assert "hidden" in text and "wool-coat" in text and "2/15 test trials" in text
    shown = format_status({**base, "counts": [{"reference": "ours", "comparison": "gaugan", "prefer_reference": 2,
                                               "n": 2, "timeouts": 0}]})
    assert "ours vs gaugan" in shown and "2/2" in shown
