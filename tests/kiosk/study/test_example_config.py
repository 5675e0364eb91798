"""configs/study.example.yaml runs as written (ours against pix2pix, pix2pixhd and gaugan, consent, optional
questions, familiarisation, the operator's release between trials) against bundles built like the synthetic set's,
through the real daemon. Only what names the installation is replaced: the log and trusted-keys paths, the device,
the port, the control socket and its system group."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from kiosk.study.config import load_study_config
from kiosk.study.log import read_log
from kiosk.study.report import report_log
from kiosk.study.runtime import StudyRuntime
from kiosk.study.schedule import make_schedule

from .driver import StudyPage, operator
from .simulate import ROOT
from .study_bundles import make_study_bundles

pytestmark = pytest.mark.slow

EXAMPLES = ROOT / "configs"


def _as_written(name: str, tmp: Path) -> Path:
    doc = yaml.safe_load((EXAMPLES / name).read_text())
    trusted = make_study_bundles(tmp, list(doc["conditions"]), doc["garments"])   # tmp/bundles/<c>/<g>.vtb
    doc["log"] = str(tmp / "study.jsonl")
    doc["trusted_keys"] = str(trusted)
    doc["kiosk"].get("control", {}).pop("group", None)      # a system group made by the package's sysusers file
    out = tmp / name
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def test_the_haptic_example_config_runs_a_full_session(tmp_path):
    cfg = load_study_config(_as_written("study.example.yaml", tmp_path))
    assert cfg.comparisons == ("pix2pix", "pix2pixhd", "gaugan") and cfg.release == "each_trial"
    rt = StudyRuntime(cfg, port=0, device="emulated", control_socket=tmp_path / "study.sock")
    page, sock = StudyPage(rt.daemon.server.url), tmp_path / "study.sock"
    try:
        operator(sock, "study.start", participant="P01")
        st = page.state()
        page.raw("POST", "/api/study/consent", {"token": st["token"], "agreed": True, "version": "2026-01"})
        st = page.state()
        page.raw("POST", "/api/study/demographics", {"token": st["token"], "answers": {"age_band": "25-34",
                                                                                      "dominant_hand": "right"}})
        for step in range(len(cfg.familiarisation.textures)):
            st = page.state()
            assert st["state"] == "familiarisation" and st["step"] == step + 1
            page.raw("POST", "/api/study/familiarised", {"token": st["token"]})
        schedule = make_schedule(cfg, "P01")
        for t in schedule.trials:
            st = page.state()
            assert st["state"] == "wait"                                  # the inter-trial pause
            status = operator(sock, "study.status")["active"]
            assert status["put_garment_on_table"] == t.garment and status["waiting_for_release"]
            operator(sock, "study.next")
            tr = page.state()["trial"]
            page.raw("POST", "/api/study/shown", {"token": tr["token"], "page": "p"})
            assert page.choose(tr["token"], t.side_of("ours"))["recorded"]
        assert page.state()["state"] == "done"
    finally:
        rt.close()
    records = read_log(cfg.log).records
    assert len([r for r in records if r["type"] == "release"]) == len(schedule.trials) == 1 + 5 * 3
    rep = report_log(cfg.log, resamples=200)
    assert [c["baseline"] for c in rep["comparisons"]] == ["gaugan", "pix2pix", "pix2pixhd"]
    assert rep["demographics"]["line"] == "1 participant; age band: 25-34 1; dominant hand: right 1"


def test_the_visual_example_config_loads():
    cfg = load_study_config(EXAMPLES / "study-visual.example.yaml")
    assert cfg.kind == "visual" and cfg.warmup_trials == 5
    assert cfg.test_garments * len(cfg.comparisons) == 30                 # the paper's 30 test rounds
