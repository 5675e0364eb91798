"""scripts/offsets_found.py: the truth places the touches where they were pressed, the recorded corners only where
the offset is 0, a run is scored beside them, and garments without a recorded registration are refused."""
from __future__ import annotations

import json

import pytest
import yaml

from tests.scripts_module import load_script
from trainer.config import load_config
from trainer.data.synthetic import generate_dataset
from trainer.loop import Trainer


@pytest.fixture(scope="module")
def of():
    return load_script("offsets_found")


def test_the_truth_finds_the_offsets_and_a_run_is_scored_beside_it(of, hard_one, tmp_path):
    src = next(hard_one.glob("singleskit_*"))
    name = src.name.split("_")[1]
    run = tmp_path / "run"
    Trainer(load_config("tiny", overrides=["train.steps=1", "train.threads=1"]), src, run).run()
    out = tmp_path / "rows.json"
    assert of.main([str(hard_one), name, str(run), "--radius", "3", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    offsets = yaml.safe_load((src / "synthetic.yaml").read_text())["realism"]["registration_offsets_px"]
    assert any(o != [0, 0] for o in offsets)
    truth, recorded = rows["truth"], rows["recorded"]
    assert truth["touches"] >= 2 and truth["hit_rate"] >= 0.75
    assert truth["mean_px_left"] < 0.5 * recorded["mean_px_recorded"]
    assert recorded["mean_px_left"] == recorded["mean_px_recorded"] > 0
    assert rows[f"{run.parent.name}/run"]["touches"] >= 1
    assert of.main([str(hard_one), name, "--split", "test", "--radius", "3", "--json", str(out)]) == 0
    held_out = json.loads(out.read_text())
    assert held_out["split"] == "test" and held_out["rows"]["truth"]["touches"] >= 1
    other = tmp_path / "other"   # the same garment under another name: the run was not trained on it
    other.mkdir()
    (other / src.name.replace(name, "Other")).symlink_to(src.resolve(), target_is_directory=True)
    with pytest.raises(SystemExit, match="trained on"):
        of.main([str(other), "Other", str(run)])


def test_what_cannot_be_placed_is_refused(of, hard_one, tmp_path):
    with pytest.raises(SystemExit, match="no garment Nothing"):
        of.main([str(hard_one), "Nothing"])
    with pytest.raises(SystemExit, match="radius"):
        of.main([str(hard_one), "x", "--radius", "0"])
    easy = tmp_path / "easy"
    generate_dataset(easy, garments=1, seed=3, frame=(320, 240), progress=False, profile="easy")
    name = next(easy.glob("singleskit_*")).name.split("_")[1]
    with pytest.raises(SystemExit, match="no recorded registration offsets"):
        of.main([str(easy), name])
    with pytest.raises(SystemExit, match="no touch of the split"):
        of.score({}, [])
