"""scripts/seed_ensemble_study.py: seeds averaged at test time, scored beside each seed alone; the singles go through
the evaluation cache, an ensemble never does; groups that do not divide the runs are refused."""
from __future__ import annotations

import json

import pytest

from tests.scripts_module import load_script
from trainer.config import load_config
from trainer.loop import Trainer


@pytest.fixture(scope="module")
def es():
    return load_script("seed_ensemble_study")


def test_the_ensemble_is_scored_beside_its_seeds(es, easy_garment, tmp_path):
    runs = []
    for seed in (0, 1):
        runs.append(tmp_path / f"s{seed}")
        cfg = load_config("tiny", overrides=["train.steps=1", "train.threads=1", f"train.seed={seed}"])
        Trainer(cfg, easy_garment.root, runs[-1]).run()
    other = tmp_path / "p2p"
    Trainer(load_config("tiny", method="pix2pix", overrides=["train.steps=1", "train.threads=1"]),
            easy_garment.root, other).run()
    out = tmp_path / "study"
    assert es.main([*map(str, runs), "--sizes", "2", "--mirrors", "flip", "--relief", "none", "--out", str(out),
                    "--beside", str(other), f"p2p-flip={other}@flip"]) == 0
    data = json.loads((out / "compare.json").read_text())
    rows = data["runs"]
    assert [r["method"] for r in rows] == ["pix2pix", "p2p-flip", "single", "single", "ens-2"]
    assert rows[4]["members"] == ["s1"] and rows[1]["mirrors"] == "flip" and "mirrors" not in rows[0]
    assert set(data["target"]["competitors"]) == {"pix2pix", "p2p-flip", "single"}
    assert rows[2]["full_angle_deg"] != pytest.approx(rows[0]["full_angle_deg"])   # another relief than seed 0's
    md = (out / "compare.md").read_text()
    assert "ens-2 − X, paired bootstrap" in md and "Generator passes a frame: single 2, ens-2 4" in md
    for run in runs:   # each single stored once for `eval --compare`; the ensemble under no run
        assert len(list((run / "eval").glob("compare-latest*.json"))) == 1


@pytest.mark.parametrize("count,size", [(4, 3), (2, 1), (3, 2)])
def test_groups_must_divide_the_runs(es, tmp_path, count, size):
    with pytest.raises(ValueError, match="divide"):
        es.groups([tmp_path / str(i) for i in range(count)], size)
    assert es.groups([tmp_path / str(i) for i in range(4)], 2) == [[tmp_path / "0", tmp_path / "1"],
                                                                   [tmp_path / "2", tmp_path / "3"]]


def test_a_run_named_twice_is_refused(es, tmp_path, capsys):
    with pytest.raises(SystemExit):
        es.main([str(tmp_path / "a"), str(tmp_path / "a"), "--out", str(tmp_path / "o")])
    assert "named twice" in capsys.readouterr().err
