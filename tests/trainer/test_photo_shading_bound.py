"""scripts/photo_shading_bound.py: a run's relief with the shading relief read from its own photo and from the real
one, scored against the truth beside the reference rows; a folder that is no run is a clear error."""
from __future__ import annotations

import json
import math

import pytest

from tests.scripts_module import load_script
from trainer.config import load_config
from trainer.loop import Trainer


@pytest.fixture(scope="module")
def pb():
    return load_script("photo_shading_bound")


def test_own_and_real_photo_are_scored_beside_the_references(pb, hard_one, tmp_path, capsys):
    run = tmp_path / "run"
    Trainer(load_config("tiny", overrides=["train.steps=30", "train.threads=1"]), next(
        p for p in hard_one.iterdir() if p.is_dir()), run).run()
    out = tmp_path / "bound.json"
    assert pb.main([str(run), "--json", str(out)]) == 0
    got = json.loads(out.read_text())[0]
    rows = got["rows"]
    assert len(got["photo_band_correlation"]) == 2 and all(-1 <= c <= 1 for c in got["photo_band_correlation"])
    assert {"as given", "shade, own photo", "shade, real photo", "shade-lift, real photo", "flat", "oracle"} <= set(rows)
    assert rows["flat"]["gap_closed"] == pytest.approx(0) and rows["oracle"]["gap_closed"] == pytest.approx(1)
    real = rows["shade, real photo"]
    assert "refused" not in real and math.isfinite(real["full_angle_deg_outside"])
    # the real photo differs from a 30-step model's: the reading changes the relief
    assert real["full_angle_deg_outside"] != pytest.approx(rows["shade, own photo"]["full_angle_deg_outside"])
    assert rows["shade-lift, real photo"]["model_weight"] >= 1.0
    assert "real photo" in capsys.readouterr().out


def test_a_folder_that_is_no_run_is_refused(pb, tmp_path, capsys):
    assert pb.main([str(tmp_path)]) == 2
    assert str(tmp_path) in capsys.readouterr().err
