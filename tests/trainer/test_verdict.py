"""The Fidelity II target check: ordered first only where every interval excludes 0 against every method that was
trained on that garment, and met only with enough such garments and the gap closed."""
import numpy as np
import pytest

from trainer import verdict
from trainer.bootstrap import Units

GARMENTS = ("A", "B", "C", "D")


def _units(level: float, n: int = 40, seed: int = 0) -> dict[str, Units]:
    rng = np.random.default_rng(seed)
    keys = np.arange(n)
    return {k: Units(keys, level + 0.05 * rng.standard_normal(n), np.ones(n)) for k in verdict.TARGET_METRICS}


def _results(gaps: dict[str, float]) -> list[dict]:
    return [{"method": "ours", "garment": g, "gap_closed": {verdict.TARGET_GAP_METRIC: v}} for g, v in gaps.items()]


def test_ordered_first_on_three_of_four_garments_with_the_gap_closed_is_met():
    grouped = {"ours": {g: [_units(1.0, seed=i)] for i, g in enumerate(GARMENTS)},
               "x": {g: [_units(2.0 if g != "D" else 1.0, seed=10 + i)] for i, g in enumerate(GARMENTS)}}
    v = verdict.check(grouped, _results(dict.fromkeys(GARMENTS, 0.7)), "ours", ["x"], n_boot=300)
    assert [g["won"] for g in v["garments"]] == [True, True, True, False]
    assert v["wins"] == 3 and v["garments_needed"] == 3 and v["met"]
    assert v["garments"][0]["against"][0]["full_fbsifid_unseen"]["hi"] < 0
    assert "**Met**" in verdict.markdown(v)


@pytest.mark.parametrize("gap", [0.59, None])
def test_not_met_without_the_gap(gap):
    grouped = {"ours": {g: [_units(1.0)] for g in GARMENTS}, "x": {g: [_units(2.0)] for g in GARMENTS}}
    results = [] if gap is None else _results(dict.fromkeys(GARMENTS, gap))
    v = verdict.check(grouped, results, "ours", ["x"], n_boot=200)
    assert v["wins"] == 4 and not v["met"]
    assert "**Not met**" in verdict.markdown(v)


def test_a_garment_where_a_baseline_was_not_trained_cannot_be_won():
    grouped = {"ours": {g: [_units(1.0)] for g in GARMENTS},
               "x": {g: [_units(2.0)] for g in GARMENTS}, "y": {"A": [_units(2.0)]}}
    v = verdict.check(grouped, _results(dict.fromkeys(GARMENTS, 0.9)), "ours", ["x", "y"], n_boot=200)
    assert v["wins"] == 1 and v["garments"][1]["missing"] == ["y"] and not v["met"]
    assert "| B | y | not run | not run |" in verdict.markdown(v)


def test_a_tie_is_not_an_ordering():
    grouped = {"ours": {g: [_units(1.0, seed=1)] for g in GARMENTS}, "x": {g: [_units(1.0, seed=2)] for g in GARMENTS}}
    v = verdict.check(grouped, _results(dict.fromkeys(GARMENTS, 0.9)), "ours", ["x"], n_boot=300)
    assert v["wins"] == 0 and not v["met"]


def test_fewer_than_four_garments_need_three_wins_still():
    grouped = {"ours": {"A": [_units(1.0)], "B": [_units(1.0)]}, "x": {"A": [_units(2.0)], "B": [_units(2.0)]}}
    v = verdict.check(grouped, _results({"A": 0.9, "B": 0.9}), "ours", ["x"], n_boot=200)
    assert v["wins"] == 2 and v["garments_needed"] == 3 and not v["met"]
