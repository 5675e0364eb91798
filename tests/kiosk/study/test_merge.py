"""Several kiosks, one study: logs pool when their study config is the same, are refused when it differs, count a
trial once per (participant, session, trial), and say which kiosk each trial came from."""
from __future__ import annotations

import csv
import shutil
import subprocess
import sys

import pytest

from kiosk.study.export import export_csv
from kiosk.study.log import StudyLog
from kiosk.study.merge import StudyMergeError, merge_logs
from kiosk.study.report import report_log

from .helpers import run_session, study_config
from .simulate import ROOT

PER_SESSION = 11         # a warm-up + 5 test garments x 2 comparisons


def _kiosk_log(tmp, name: str, codes: list[str], choose, **overrides):
    cfg = study_config(tmp / name, log=f"{name}.jsonl", kiosk_name=name, **overrides)
    with StudyLog.open(cfg.log, cfg.id) as log:
        for code in codes:
            run_session(log, cfg, code, choose)
    return cfg.log


def test_two_kiosks_pool_into_one_report_and_export(tmp_path):
    a = _kiosk_log(tmp_path, "kiosk-a", ["P01", "P02"], lambda s, i: "left")
    b = _kiosk_log(tmp_path, "kiosk-b", ["P03"], lambda s, i: "right")
    rep_a, rep_b = report_log(a, resamples=200), report_log(b, resamples=200)
    rep = report_log([a, b], resamples=200)
    assert rep["participants"] == 3 and rep["kiosks"] == {"kiosk-a": 2 * PER_SESSION, "kiosk-b": PER_SESSION}
    assert rep["overall"]["n"] == rep_a["overall"]["n"] + rep_b["overall"]["n"]
    assert rep["overall"]["wins"] == rep_a["overall"]["wins"] + rep_b["overall"]["wins"]
    assert {k["kiosk"]: k["n"] for k in rep["overall"]["by_kiosk"]} == {"kiosk-a": 20, "kiosk-b": 10}
    out = tmp_path / "all.csv"
    n = export_csv([a, b], out)
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    assert n == len(rows) == 3 * PER_SESSION
    assert {r["participant"]: r["kiosk"] for r in rows} == {"P01": "kiosk-a", "P02": "kiosk-a", "P03": "kiosk-b"}


def test_copies_of_a_trial_count_once_and_conflicts_are_reported(tmp_path):
    a = _kiosk_log(tmp_path, "kiosk-a", ["P01"], lambda s, i: "left")
    copy = tmp_path / "copy.jsonl"
    shutil.copy(a, copy)
    merged = merge_logs([a, copy])
    assert merged.duplicates == PER_SESSION and merged.conflicts == []
    assert report_log([a, copy], resamples=200)["overall"]["n"] == report_log(a, resamples=200)["overall"]["n"]
    # the same participant and session answered differently elsewhere: the first log's copy counts, and it is said
    other = _kiosk_log(tmp_path, "kiosk-b", ["P01"], lambda s, i: "right")
    merged = merge_logs([a, other])
    assert merged.duplicates == PER_SESSION and len(merged.conflicts) == PER_SESSION
    assert merged.conflicts[0]["kept"]["kiosk"] == "kiosk-a" and merged.conflicts[0]["dropped"]["kiosk"] == "kiosk-b"
    rep = report_log([a, other], resamples=200)
    assert len(rep["log_health"]["conflicting_copies"]) == PER_SESSION


def test_logs_of_different_configs_or_studies_are_refused(tmp_path):
    a = _kiosk_log(tmp_path, "kiosk-a", ["P01"], lambda s, i: "left")
    cfg = study_config(tmp_path / "c", log="c.jsonl")
    changed = cfg.__class__(**{**cfg.__dict__, "source_sha256": "1" * 64})
    with StudyLog.open(changed.log, changed.id) as log:
        run_session(log, changed, "P02", lambda s, i: "left")
    with pytest.raises(StudyMergeError, match="different study configs"):
        merge_logs([a, changed.log])
    other = _kiosk_log(tmp_path, "kiosk-x", ["P03"], lambda s, i: "left", id="another-study")
    with pytest.raises(StudyMergeError, match="different studies"):
        merge_logs([a, other])
    proc = subprocess.run([sys.executable, "-m", "vtkiosk.cli", "study", "report", "--log", str(a), "--log",
                           str(changed.log)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1 and "different study configs" in proc.stderr


def test_cli_reports_several_logs(tmp_path):
    a = _kiosk_log(tmp_path, "kiosk-a", ["P01"], lambda s, i: "left")
    b = _kiosk_log(tmp_path, "kiosk-b", ["P02"], lambda s, i: "left")
    proc = subprocess.run([sys.executable, "-m", "vtkiosk.cli", "study", "report", "--log", str(a), "--log", str(b),
                           "--bootstrap", "200"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert f"trials per kiosk: kiosk-a {PER_SESSION}, kiosk-b {PER_SESSION}" in proc.stdout and "2 participants" in proc.stdout
