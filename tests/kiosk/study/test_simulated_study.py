"""Done-when: scripted participants who prefer the reference 75 % of the time run a whole study through a real
`vtkiosk study run` process, and `vtkiosk study report` recovers 75 % within its intervals."""
from __future__ import annotations

import csv
import json
import subprocess
import sys

import pytest

from kiosk.study.config import load_study_config

from .conftest import write_study
from .simulate import ROOT, StudyProcess, run_participants

pytestmark = pytest.mark.slow


def test_simulated_study_recovers_the_known_preference(tmp_path, study_env):
    cfg_path = write_study(tmp_path, study_env, name="sim", seed=11)
    config = load_study_config(cfg_path)
    proc = StudyProcess(cfg_path, tmp_path / "proc")
    proc.start()
    try:
        codes = [f"P{i:02d}" for i in range(1, 25)]
        acked = run_participants(proc, config, codes, {"pix2pix": 0.75, "pix2pixhd": 0.75}, seed=5)
    finally:
        assert proc.stop() == 0
    per_session = 1 + 3 * 2                                   # warm-up + 3 garments x 2 comparisons
    assert acked == len(codes) * per_session

    out_json, out_png, out_csv = tmp_path / "report.json", tmp_path / "fig.png", tmp_path / "trials.csv"
    cli = [sys.executable, "-m", "vtkiosk.cli", "study"]
    rep_run = subprocess.run(cli + ["report", "--log", str(config.log), "--json", str(out_json), "--plot",
                                    str(out_png)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert rep_run.returncode == 0, rep_run.stderr
    assert "ours vs pix2pix" in rep_run.stdout and "ours vs pix2pixhd" in rep_run.stdout
    rep = json.loads(out_json.read_text())
    assert out_png.read_bytes()[:4] == b"\x89PNG"
    assert rep["participants"] == 24 and rep["complete_sessions"] == 24 and rep["warmup_responses"] == 24
    for c in rep["comparisons"] + [rep["overall"]]:
        assert c["timeouts"] == 0
        for interval in (c["wilson95"], c["clustered"]["ci95"], c["bootstrap"]["ci95"]):
            assert interval[0] < 0.75 < interval[1], (c.get("baseline", "all"), interval)
        assert c["p_value"] < 0.05                             # and clearly better than chance
    assert sum(c["n"] for c in rep["comparisons"]) == rep["overall"]["n"] == 24 * 6

    exp = subprocess.run(cli + ["export", "--log", str(config.log), "--out", str(out_csv)], cwd=ROOT,
                         capture_output=True, text=True, timeout=300)
    assert exp.returncode == 0, exp.stderr
    with open(out_csv, newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == acked and all(r["status"] == "answered" for r in rows)
    tests = [r for r in rows if r["block"] == "test"]
    assert sum(r["chose_reference"] == "1" for r in tests) == rep["overall"]["wins"]
