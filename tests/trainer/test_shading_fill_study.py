"""scripts/shading_fill_study.py: a run scored under each background fill of the shading relief, side by side; the
module's own fill goes through the evaluation cache and no other does; the module is left as it was found."""
from __future__ import annotations

import json

import pytest

from tests.scripts_module import load_script
from trainer.config import load_config
from trainer.loop import Trainer
from trainer.models import shading_relief as sr


@pytest.fixture(scope="module")
def fs():
    return load_script("shading_fill_study")


def test_each_fill_is_scored_beside_the_modules_own(fs, easy_garment, tmp_path):
    run = tmp_path / "run"
    Trainer(load_config("tiny", overrides=["train.steps=1", "train.threads=1"]), easy_garment.root, run).run()
    own, own_fill = sr.FILL_SIGMA, sr.log_luminance
    out = tmp_path / "study"
    first = f"{own:g}"
    assert fs.main([str(run), "--fills", first, "mean", "1", "--which", "best", "--out", str(out)]) == 0
    assert (sr.FILL_SIGMA, sr.log_luminance) == (own, own_fill)
    data = json.loads((out / "compare.json").read_text())
    assert [r["method"] for r in data["runs"]] == [f"fill-{first}", "fill-mean", "fill-1"]
    assert set(data["slopes_ms"]) == {f"fill-{first}", "fill-mean", "fill-1"} and "load_average" in data
    assert all(r["relief"]["rule"] == "shade-lift" for r in data["runs"])
    angles = [r["full_angle_deg"] for r in data["runs"]]
    assert angles[1] != pytest.approx(angles[0]) and angles[2] != pytest.approx(angles[0])   # the fill changed
    assert f"fill-{first} − X, paired bootstrap" in (out / "compare.md").read_text()
    stored = list((run / "eval").glob("compare-best-shade-lift*.json"))
    assert len(stored) == 1 and json.loads(stored[0].read_text())["result"]["full_angle_deg"] == pytest.approx(
        angles[0])   # only the module's own fill is stored, for `eval --compare` to reuse


def test_a_fill_that_is_no_sigma_is_refused(fs, tmp_path):
    for bad in ("0", "-2", "wide"):
        with pytest.raises(SystemExit):
            fs.main([str(tmp_path), "--fills", bad, "--out", str(tmp_path / "o")])
