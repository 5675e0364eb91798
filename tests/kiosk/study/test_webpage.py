"""The visual study as a self-contained web page: opened from a file in headless Chromium (no server), a remote
participant consents, answers the questions, does the practice and test rounds, reloads in the middle, and
downloads a log that the kiosk's own reader accepts (every checksum valid) and `study report` pools with a kiosk's
log of the same config."""
from __future__ import annotations

import subprocess
import sys

import pytest

from kiosk.study.config import load_study_config
from kiosk.study.log import read_log, replay
from kiosk.study.report import report_log
from kiosk.study.schedule import make_schedule

from tests.kiosk.browser import headless_chromium

from .conftest import write_study
from .simulate import ROOT

pytestmark = pytest.mark.browser
# Markup and the page's own fill markers in a study's text stay text.
CONSENT = "Ich stimme zu. \u00c4rger \u2013 nein. </script><!-- /*SCRIPT*/ <!--SCREENS--> /*DATA*/"


def test_exported_page_writes_the_kiosks_log_records(tmp_path, study_env):
    playwright = pytest.importorskip("playwright.sync_api")
    cfg_path = write_study(tmp_path, study_env, name="web", kind="visual", warmup_trials=2, time_limit_s=None,
                           consent={"version": "w1", "text": CONSENT},
                           demographics={"age_band": ["18-24", "25-34"]},
                           participants={"codes": ["W01", "W02"]})
    cfg = load_study_config(cfg_path)
    out = tmp_path / "site" / "study.html"
    proc = subprocess.run([sys.executable, "-m", "vtkiosk.cli", "study", "export-page", "--config", str(cfg_path),
                           "--out", str(out)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    html = out.read_text()
    assert "http://" not in html.replace("http://www.w3.org", "") and "<script src" not in html   # self-contained
    schedule = make_schedule(cfg, "W02")
    errors: list[str] = []
    with playwright.sync_playwright() as pw:
        browser = headless_chromium(pw)
        page = browser.new_page(viewport={"width": 1280, "height": 800}, accept_downloads=True)
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(out.as_uri())
        page.fill("#code-input", "Jane")                                  # not a code of this study
        page.click("#code-form button")
        assert "not part of the study" in page.inner_text("#code-error")
        page.fill("#code-input", "W02")
        page.click("#code-form button")
        assert page.inner_text("#consent-text") == CONSENT
        assert page.locator("#consent").count() == 1 and page.locator("#about-form").count() == 1
        page.click("#consent-yes")
        page.select_option("#about-age_band", "25-34")
        page.click("#about-go")
        assert "realistic" in page.inner_text("#notice-instructions")
        page.click("#start")
        for t in schedule.trials:
            if t.index == 3:                                              # a reload resumes where it was
                page.goto(out.as_uri() + "?participant=W02")            # (no instructions again)
            page.wait_for_function("!document.getElementById('choose-left').disabled")
            page.dispatch_event(f"#choose-{t.side_of('ours')}", "pointerdown")
            page.wait_for_function("document.getElementById('choose-left').disabled")
        page.wait_for_selector("#download-row:not([hidden])")
        with page.expect_download() as dl:
            page.click("#download")
        log_path = tmp_path / "W02.jsonl"
        dl.value.save_as(log_path)
        browser.close()
    assert errors == []
    read = read_log(log_path)
    assert read.problems == [] and not read.torn_tail                     # every record's checksum is valid
    state = replay(read.records)
    s = state.sessions[("W02", 1)]
    assert s.consented and s.consent["text_sha256"] == cfg.consent.sha256
    assert s.demographics["answers"] == {"age_band": "25-34"}
    assert sorted(s.responses) == [t.index for t in schedule.trials]
    assert all(r["chose_reference"] and r["rt_s"] > 0 for r in s.responses.values())
    assert [r["reason"] for r in read.records if r["type"] == "resume"] == ["reload"]
    assert s.started["kiosk"] == "web" and s.started["config_sha256"] == cfg.source_sha256
    rep = report_log([log_path], resamples=100)
    assert rep["kind"] == "visual" and rep["kiosks"] == {"web": len(schedule.trials)}
    assert all(c["rate"] == 1.0 for c in rep["comparisons"])


def test_a_haptic_study_is_not_exported_as_a_page(tmp_path, study_env):
    cfg_path = write_study(tmp_path, study_env, name="hap", participants={"codes": ["P01"]})
    proc = subprocess.run([sys.executable, "-m", "vtkiosk.cli", "study", "export-page", "--config", str(cfg_path),
                           "--out", str(tmp_path / "x.html")], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "only a visual study" in proc.stderr and "Traceback" not in proc.stderr
