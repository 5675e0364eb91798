"""`vtkiosk study plan`: its power matches a direct simulation of whole studies (schedules, log records and the
report's own analysis) at two sample sizes; the paper's design is the worked example; bad input is one line."""
from __future__ import annotations

import json
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.contract.errors import InputError
from kiosk.study.log import LogState
from kiosk.study.plan import beta_params, detected, plan, power_at
from kiosk.study.records import response_payload
from kiosk.study.report import analyse
from kiosk.study.schedule import make_schedule
from kiosk.study.stats import cluster_robust_interval

from .helpers import fake_bundle_ids, study_config
from .simulate import ROOT

RATES = {"pix2pix": 0.72, "pix2pixhd": 0.62}
SPREAD = 0.12
GARMENTS = 3


def _direct_power(n_participants: int, studies: int, seed: int) -> dict[str, float]:
    """Whole simulated studies: real schedules and records, analysed by the report; how often each comparison's
    participant-clustered interval excludes 50 %."""
    cfg = study_config(Path("."), test_garments=GARMENTS, garments=[f"g{i:02d}" for i in range(6)])
    ids = fake_bundle_ids(cfg)
    rng = random.Random(seed)
    hits = {c: 0 for c in RATES}
    for k in range(studies):
        state = LogState(study_id=cfg.id, header={"seq": 1})
        seq = 1
        for p in range(n_participants):
            code = f"P{p:02d}"
            schedule = make_schedule(cfg, code, 1 + k)     # a fresh schedule per simulated study
            a_b = {c: beta_params(r, SPREAD) for c, r in RATES.items()}
            own = {c: rng.betavariate(*a_b[c]) for c in RATES}
            stamp = {"wall": "", "mono": 0.0, "boot_id": "sim"}
            seq += 1
            state.fold({"seq": seq, "type": "session", "participant": code, "session": 1 + k, "kind": "haptic",
                        "schedule": {"trials": list(schedule.trials)}})
            for t in schedule.trials:
                ref_side = t.side_of(cfg.reference)
                side = ref_side if rng.random() < own[t.comparison] else ("left" if ref_side == "right" else "right")
                seq += 1
                state.fold({"seq": seq, "type": "response", **response_payload(
                    schedule, t, choice=side, timeout=False, rt_s=1.0, time_limit_s=60.0, bundles=ids,
                    software="sim", shown=stamp, stamp=stamp)})
        rep = analyse(state, resamples=2, strengths=False)
        for c in rep["comparisons"]:
            lo, hi = c["clustered"]["ci95"]
            hits[c["baseline"]] += int(lo > 0.5 or hi < 0.5)
    return {c: h / studies for c, h in hits.items()}


@pytest.mark.parametrize("n_participants", [4, 10])
def test_plan_power_matches_a_direct_simulation_of_whole_studies(n_participants):
    studies = 160
    direct = _direct_power(n_participants, studies, seed=n_participants)
    planned = power_at(n_participants, GARMENTS, RATES, SPREAD, sims=20000, seed=1).power
    for c in RATES:
        se = np.sqrt(planned[c] * (1 - planned[c]) / studies)
        assert abs(direct[c] - planned[c]) <= 4 * se + 0.01, (c, direct[c], planned[c])
    assert planned["pix2pixhd"] < planned["pix2pix"]     # and the test could tell a weaker effect apart


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 6), st.integers(1, 6)), min_size=2, max_size=12))
def test_vectorised_detection_is_the_reports_clustered_interval(pairs):
    wins = np.array([[min(k, n) for k, n in pairs]])
    counts = np.array([[n for _, n in pairs]])
    ci = cluster_robust_interval(wins[0], counts[0])["ci95"]
    assert bool(detected(wins, counts)[0]) == (ci[0] > 0.5 or ci[1] < 0.5)


def test_the_papers_design_is_the_worked_example():
    p = plan({"pix2pixhd": 0.767, "pix2pix": 0.796, "gaugan": 0.842}, garments=5, spread=0.1,
             participants=[20], sims=4000, seed=0)
    row = p["rows"][0]
    assert row["power"]["pix2pixhd"] > 0.95 and p["participants_needed"] == 20
    assert row["false_positive_at_50"] < 0.12               # the reference row: no preference, few false claims


@pytest.mark.parametrize("rate, spread", [(0.0, 0.1), (1.0, 0.1), (0.5, -0.1), (0.9, 0.5)])
def test_impossible_rates_and_spreads_are_refused(rate, spread):
    with pytest.raises(InputError):
        beta_params(rate, spread)


def test_cli_plan(tmp_path):
    out = tmp_path / "plan.json"
    cmd = [sys.executable, "-m", "vtkiosk.cli", "study", "plan", "--rate", "pix2pixhd=0.767", "--rate",
           "pix2pix=0.796", "--garments", "5", "--participants", "6,20", "--sims", "2000", "--json", str(out)]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "participants needed for 80% power" in proc.stdout
    assert [r["participants"] for r in json.loads(out.read_text())["rows"]] == [6, 20]
    bad = subprocess.run(cmd[:5] + ["--rate", "gaugan=1.4"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and "0 < RATE < 1" in bad.stderr
