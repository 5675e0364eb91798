"""The Fidelity II target check: ordered first only where every interval excludes 0 against every method that was
trained on that garment, met only with enough such garments, each on enough runs of `ours`, and the gap closed."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trainer import verdict
from trainer.bootstrap import Units

GARMENTS = ("A", "B", "C", "D")


def _units(level: float, n: int = 40, seed: int = 0) -> dict[str, Units]:
    rng = np.random.default_rng(seed)
    keys = np.arange(n)
    return {k: Units(keys, level + 0.05 * rng.standard_normal(n), np.ones(n)) for k in verdict.TARGET_METRICS}


def _results(gaps: dict[str, float]) -> list[dict]:
    return [{"method": "ours", "garment": g, "gap_closed": {verdict.TARGET_GAP_METRIC: v}} for g, v in gaps.items()]


def _seeds(level: float, seed: int, n: int = verdict.TARGET_SEEDS) -> list[dict[str, Units]]:
    return [_units(level, seed=100 * seed + s) for s in range(n)]


def test_ordered_first_on_three_of_four_garments_with_the_gap_closed_is_met():
    grouped = {"ours": {g: _seeds(1.0, i) for i, g in enumerate(GARMENTS)},
               "x": {g: [_units(2.0 if g != "D" else 1.0, seed=10 + i)] for i, g in enumerate(GARMENTS)}}
    v = verdict.check(grouped, _results(dict.fromkeys(GARMENTS, 0.7)), "ours", ["x"], n_boot=300)
    assert [g["won"] for g in v["garments"]] == [True, True, True, False]
    assert v["wins"] == v["settled_wins"] == 3 and v["garments_needed"] == 3 and v["met"]
    assert v["garments"][0]["against"][0]["full_fbsifid_unseen"]["hi"] < 0
    assert v["garments"][0]["runs"] == {"ours": 3, "x": 1}
    assert "**Met**" in verdict.markdown(v)


def test_an_ordering_from_one_run_of_ours_is_provisional_and_not_met():
    """The same clear lead on one run of `ours` is reported, but cannot meet the target: its interval holds the
    held-out data's variation, not a second seed's."""
    grouped = {"ours": {g: [_units(1.0, seed=i)] for i, g in enumerate(GARMENTS)},
               "x": {g: _seeds(2.0, 10 + i) for i, g in enumerate(GARMENTS)}}
    v = verdict.check(grouped, _results(dict.fromkeys(GARMENTS, 0.7)), "ours", ["x"], n_boot=300)
    assert v["wins"] == 4 and v["settled_wins"] == 0 and not v["met"]
    assert not any(g["settled"] for g in v["garments"])
    md = verdict.markdown(v)
    assert "**Not met**: ours is ordered first on 0 of 4 garments, 4 more on fewer than 3 runs of ours" in md
    assert "| A | provisional (needs 3 runs) | 1 |" in md
    assert "Fewer than 3 runs of ours" in md
    # x's three seeds give the SD; ours' single run adds nothing to it
    sd = v["garments"][0]["seed_sd"]["full_angle_deg_outside"]
    vals = [float(np.sum(u["full_angle_deg_outside"].num)) / 40 for u in grouped["x"]["A"]]
    assert sd == pytest.approx(float(np.std(vals, ddof=1)))


@settings(max_examples=50, deadline=None)
@given(st.lists(st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=5), min_size=1, max_size=4))
def test_seed_sd_is_the_pooled_within_method_sd(groups):
    """Each method's runs hold one unit with the given value: the pooled SD matches its definition, and is None
    (never a division by zero) when no method has two runs."""
    runs = {f"m{i}": [{"k": Units([0], [x], [1.0])} for x in xs] for i, xs in enumerate(groups)}
    got = verdict.seed_sd(runs, "k")
    dof = sum(len(xs) - 1 for xs in groups)
    if dof == 0:
        assert got is None
        return
    ss = sum(float(np.sum((np.array(xs) - np.mean(xs)) ** 2)) for xs in groups)
    assert got == pytest.approx(math.sqrt(ss / dof), rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("gap", [0.59, None])
def test_not_met_without_the_gap(gap):
    grouped = {"ours": {g: [_units(1.0)] for g in GARMENTS}, "x": {g: [_units(2.0)] for g in GARMENTS}}
    results = [] if gap is None else _results(dict.fromkeys(GARMENTS, gap))
    v = verdict.check({"ours": {g: _seeds(1.0, 0) for g in GARMENTS}, "x": grouped["x"]}, results, "ours", ["x"],
                      n_boot=200)
    assert v["wins"] == v["settled_wins"] == 4 and not v["met"]
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
