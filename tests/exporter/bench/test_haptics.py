"""`vtkiosk bench haptics` on one fabric: today's planner feels corduroy 43 % too fine on a 0.17 mm/px panel, the
physical planner feels it at its true period; the perceptual mapping gives it >= 4 steps; bad options are one line."""
import subprocess
import sys

import numpy as np
import pytest

from exporter.bench.haptics import (FLAT_NOISES, MAX_TEXTURE_PERIOD_MM, PITCH_MM, TRUTH_PITCH_MM, calibrate,
                                    contrast_row, distinguishability, fabric_params, period_row, run_case)
from trainer.data.synth_fabrics import FabricParams


@pytest.fixture(scope="module")
def corduroy():
    p = next(f for f in fabric_params(0) if f.name == "corduroy")
    return p, calibrate(p, PITCH_MM, 0)


def test_today_is_felt_too_fine_and_new_at_true_size(corduroy):
    p, cal = corduroy
    today = period_row(run_case(p, cal, 0.17, 1.0, "today", 0), p)
    new_case = run_case(p, cal, 0.17, 1.0, "new", 0)
    new = period_row(new_case, p)
    assert today["spectrum_scale_error"] == pytest.approx(0.17 / 0.3 - 1, abs=0.02)  # -43 %
    assert abs(new["spectrum_scale_error"]) <= 0.02 and abs(new["error"]) <= 0.10
    assert new["computed_pixels"] < today["computed_pixels"]
    assert contrast_row(new_case)["iqr_steps"] >= 4.0
    assert TRUTH_PITCH_MM < PITCH_MM and MAX_TEXTURE_PERIOD_MM > new["true_friction_period_mm"]


def test_a_weave_finer_than_the_panel_can_show_is_reported_unrenderable():
    # Denim ribs 1.0 mm apart: friction ridges (both flanks of a rib) every ~0.5 mm, under the 0.60 mm Nyquist limit
    # of a 0.30 mm/px panel. The row says so instead of scoring the finest structure the panel can hold as a miss.
    fine = FabricParams("denim", 1.0, 0.08, 0.7, 0.35, 0.02)
    cal = calibrate(fine, PITCH_MM, 0)
    row = period_row(run_case(fine, cal, 0.30, 1.0, "new", 0), fine)
    assert row["nyquist_mm"] == pytest.approx(0.60)
    assert row["true_friction_period_mm"] < row["nyquist_mm"] and row["renderable"] is False
    assert row["true_period_panel_px"] < 2.0
    # On a 0.17 mm/px panel the same ridges are above its 0.34 mm limit: renderable, and felt at their period.
    row = period_row(run_case(fine, cal, 0.17, 1.0, "new", 0), fine)
    assert row["renderable"] is True and abs(row["error"]) <= 0.10


def test_oracle_is_the_truth_at_panel_pixels(corduroy):
    p, cal = corduroy
    c = run_case(p, cal, 0.25, 1.0, "new", 0)
    x0, y0, x1, y1 = c.window
    assert c.oracle.shape == (y1 - y0, x1 - x0)
    assert abs(c.oracle.mean() - c.truth_levels.mean()) < 1.0  # area averaging keeps the mean friction
    row = period_row(c, p)
    assert row["renderable"] and abs(row["oracle_error"]) <= 0.10


def test_flat_garment_stays_at_natural_friction(corduroy):
    flat = next(f for f in fabric_params(0) if f.name == "flat")
    row = contrast_row(run_case(flat, calibrate(flat, PITCH_MM, 0), 0.17, 1.0, "new", 0))
    assert row["p95_steps"] <= 1.0 and np.isfinite(row["iqr_steps"])


def test_every_fabric_spans_four_steps_and_every_pair_is_told_apart():
    # The default garments on the default panel: each synthetic fabric's plain texture spans >= 4 just-noticeable
    # steps with the new mapping, and every pair of fabrics is further apart than two regions of one fabric.
    cases = [run_case(p, calibrate(p, PITCH_MM, 0), 0.17, 1.0, "new", 0) for p in fabric_params(0)
             if p.name not in FLAT_NOISES]
    steps = {c.fabric: contrast_row(c)["iqr_steps"] for c in cases}
    assert min(steps.values()) >= 4.0, steps
    d = distinguishability(cases)
    assert d["all_separated"], [p for p in d["pairs"] if not p["separated"]]
    assert all(d["confusion"][i][i] == 2 for i in range(len(cases)))


@pytest.mark.parametrize("args, message", [
    (["--panels", "0.25"], "must include 0.17"),
    (["--panels", "abc"], "comma-separated numbers"),
    (["--bundle", "/nonexistent/x.vtb"], "no such bundle"),
])
def test_bad_options_are_one_line(args, message):
    r = subprocess.run([sys.executable, "-m", "vtkiosk", "bench", "haptics", *args], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode != 0 and message in r.stderr + r.stdout and "Traceback" not in r.stderr
