"""CSV export: one row per scheduled trial, PsychoPy-style columns, pending trials shown as pending."""
from __future__ import annotations

import csv

from kiosk.study.export import COLUMNS, export_csv
from kiosk.study.log import StudyLog

from .helpers import run_session, study_config


def test_export_rows(tmp_path):
    cfg = study_config(tmp_path)
    with StudyLog.open(cfg.log, cfg.id) as log:
        a = run_session(log, cfg, "P01", lambda s, i: None if i == 3 else ("left" if i % 2 else "right"))
        b = run_session(log, cfg, "P02", lambda s, i: "left", stop_after=4)
    out = tmp_path / "out" / "trials.csv"
    n = export_csv(cfg.log, out)
    with open(out, newline="") as f:
        reader = csv.DictReader(f)
        assert reader.fieldnames == COLUMNS
        table = list(reader)
    assert n == len(table) == len(a.trials) + len(b.trials)
    p1 = [r for r in table if r["participant"] == "P01"]
    assert [int(r["trials.thisN"]) for r in p1] == list(range(len(a.trials)))
    for r, t in zip(p1, a.trials):
        assert (r["garment"], r["left_condition"], r["right_condition"], r["half"], r["block"]) == \
            (t.garment, t.left, t.right, t.half, t.block)
        assert r["expName"] == "haptic-ab-test" and r["session"] == "1"
        assert r["reference_side"] == t.side_of("ours")
        assert r["left_manifest_sha256"] and r["right_model_version"] == f"{t.right}-1"
    timeout = p1[3]
    assert (timeout["status"], timeout["timed_out"], timeout["key_resp.keys"], timeout["key_resp.rt"],
            timeout["chose_reference"]) == ("timeout", "1", "", "", "")
    answered = p1[1]
    assert answered["status"] == "answered" and answered["key_resp.keys"] == "left"
    assert answered["chosen_condition"] == a.trials[1].left
    assert answered["chose_reference"] == str(int(a.trials[1].left == "ours"))
    assert float(answered["key_resp.rt"]) == 1.5 and answered["time_limit_s"] == "60.0"
    assert p1[0]["time_limit_s"] == ""                            # the warm-up is untimed
    p2 = [r for r in table if r["participant"] == "P02"]
    assert [r["status"] for r in p2] == ["answered"] * 4 + ["pending"] * (len(b.trials) - 4)
