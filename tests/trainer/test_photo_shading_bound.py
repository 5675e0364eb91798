"""scripts/photo_shading_bound.py: a run's relief with the shading relief read from its own photo and from the real
one, and with a free linear filter of either, scored against the truth beside the reference rows; a folder that is no
run and a filter of even width are clear errors."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from tests.scripts_module import load_script
from trainer.evaluate import Prediction


@pytest.fixture(scope="module")
def pb():
    return load_script("photo_shading_bound")


@pytest.fixture(scope="module")
def run(hard_tiny_run):
    return hard_tiny_run


def test_own_and_real_photo_are_scored_beside_the_references(pb, run, tmp_path, capsys):
    out = tmp_path / "bound.json"
    assert pb.main([str(run), "--linear", "3", "--json", str(out)]) == 0
    got = json.loads(out.read_text())[0]
    rows = got["rows"]
    assert len(got["photo_band_correlation"]) == 2 and all(-1 <= c <= 1 for c in got["photo_band_correlation"])
    assert {"as given", "shade, own photo", "shade, real photo", "shade-lift, real photo", "flat", "oracle"} <= set(rows)
    assert {f"linear 3, {p}, fit on {w}" for p in ("own photo", "real photo") for w in pb.FITS} <= set(rows)
    assert rows["flat"]["gap_closed"] == pytest.approx(0) and rows["oracle"]["gap_closed"] == pytest.approx(1)
    real = rows["shade, real photo"]
    assert "refused" not in real and math.isfinite(real["full_angle_deg_outside"])
    # the real photo differs from a 30-step model's: the reading changes the relief
    assert real["full_angle_deg_outside"] != pytest.approx(rows["shade, own photo"]["full_angle_deg_outside"])
    assert rows["shade-lift, real photo"]["model_weight"] >= 1.0
    assert all(math.isfinite(r["full_angle_deg_outside"]) for k, r in rows.items() if k.startswith("linear"))
    assert "linear 3, real photo, fit on truth everywhere" in capsys.readouterr().out


def test_the_fit_on_the_truth_everywhere_is_the_closest_in_squares(pb, run):
    """Least squares over the whole object: no filter fitted on fewer pixels comes closer to the truth there (up to
    the small ridge), so the row bounds every linear reading of that photo."""
    p = Prediction(run, "latest", unseen=False)
    ctx = p.ctx
    tx, ty = (torch.from_numpy(t) for t in ctx.truth())
    obj = torch.from_numpy(ctx.obj)
    for vis in (p.vis, ctx.visual):
        got = pb.linear_reliefs(ctx, p.tac, vis, 5)
        assert set(got) == set(pb.FITS)
        err = {w: float(((t[0, 0] - tx)[obj] ** 2 + (t[0, 1] - ty)[obj] ** 2).mean()) for w, t in got.items()}
        assert all(np.isfinite(list(err.values())))
        assert err["truth everywhere"] <= min(err.values()) * 1.01
        # off the object the reading leaves nothing
        assert all(float(t[0][:, ~obj].abs().max()) == 0.0 for t in got.values())


@pytest.mark.parametrize("k", ["4", "0", "-3"])
def test_an_even_or_empty_filter_width_is_refused(pb, run, k, capsys):
    with pytest.raises(SystemExit) as e:
        pb.main([str(run), "--linear", k])
    assert e.value.code == 2 and "odd widths" in capsys.readouterr().err


def test_a_folder_that_is_no_run_is_refused(pb, tmp_path, capsys):
    assert pb.main([str(tmp_path)]) == 2
    assert str(tmp_path) in capsys.readouterr().err


def test_no_touch_in_the_crop_refuses_the_linear_rows(pb, run, monkeypatch):
    monkeypatch.setattr(pb, "touch_pixels", lambda *a, **k: [])
    rows = pb.bound(run, linear=(3,))["rows"]
    assert "no training touch" in rows["linear 3, real photo"]["refused"]
    assert not any(k.startswith("linear 3, real photo, fit on") for k in rows)
