"""`vtkiosk bench haptics` on one fabric: today's planner feels corduroy 43 % too fine on a 0.17 mm/px panel, the
physical planner feels it at its true period; the perceptual mapping gives it >= 4 steps; bad options are one line."""
import subprocess
import sys

import numpy as np
import pytest

from exporter.bench.haptics import (MAX_TEXTURE_PERIOD_MM, PITCH_MM, TRUTH_PITCH_MM, calibrate, contrast_row,
                                    fabric_params, period_row, run_case)


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


def test_flat_garment_stays_at_natural_friction(corduroy):
    flat = next(f for f in fabric_params(0) if f.name == "flat")
    row = contrast_row(run_case(flat, calibrate(flat, PITCH_MM, 0), 0.17, 1.0, "new", 0))
    assert row["p95_steps"] <= 1.0 and np.isfinite(row["iqr_steps"])


@pytest.mark.parametrize("args, message", [
    (["--panels", "0.25"], "must include 0.17"),
    (["--panels", "abc"], "comma-separated numbers"),
    (["--bundle", "/nonexistent/x.vtb"], "no such bundle"),
])
def test_bad_options_are_one_line(args, message):
    r = subprocess.run([sys.executable, "-m", "vtkiosk", "bench", "haptics", *args], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode != 0 and message in r.stderr + r.stdout and "Traceback" not in r.stderr
