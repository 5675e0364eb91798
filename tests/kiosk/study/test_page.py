"""The study page in headless Chromium: it draws the reference visual in both panels where the friction maps lie,
and a tap on "left" is written to the log before the next trial appears."""
from __future__ import annotations

import time

import pytest

from kiosk.study.config import load_study_config
from kiosk.study.log import read_log
from kiosk.study.runtime import StudyRuntime, control_socket_of
from kiosk.study.schedule import make_schedule

from tests.kiosk.browser import headless_chromium

from .conftest import write_study
from .driver import operator

pytestmark = pytest.mark.browser


def test_page_shows_trial_and_records_taps(tmp_path, study_env):
    playwright = pytest.importorskip("playwright.sync_api")
    cfg = load_study_config(write_study(tmp_path, study_env, name="page"))
    rt = StudyRuntime(cfg, port=0, device="emulated")
    try:
        sock = control_socket_of(cfg)
        assert operator(sock, "study.start", participant="P11")["ok"]
        schedule = make_schedule(cfg, "P11")
        with playwright.sync_playwright() as pw:
            browser = headless_chromium(pw)
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(rt.url)
            page.wait_for_function("!document.getElementById('choose-left').disabled", timeout=20000)
            assert page.inner_text("#question") == cfg.question
            # the reference visual is drawn in both panels: sample the object a quarter into the shown half
            trial = page.evaluate("fetch('/api/study/trial').then(r => r.json())")["trial"]
            for p in trial["panels"]:
                pl = p["placement"]
                u = 100 if schedule.trials[0].half == "left" else 220   # asset column inside the shown half
                x, y = pl["x"] + u * pl["scale"], pl["y"] + 120 * pl["scale"]
                px = page.evaluate(f"Array.from(document.getElementById('stage').getContext('2d')"
                                   f".getImageData({int(x)}, {int(y)}, 1, 1).data)")
                want = rt.bundles.get("ours", schedule.trials[0].garment).bundle.asset("visual")[120, u]
                assert max(abs(int(a) - int(b)) for a, b in zip(px[:3], want)) <= 3, (p["side"], px, want)
            page.click("#choose-left")
            page.wait_for_function(f"document.getElementById('progress').textContent === '1 / 6'", timeout=20000)
            page.wait_for_function("!document.getElementById('choose-right').disabled", timeout=20000)
            page.dblclick("#choose-right")                                     # a double tap
            page.wait_for_function("document.getElementById('progress').textContent === '2 / 6'", timeout=20000)
            browser.close()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            responses = [r for r in read_log(cfg.log).records if r["type"] == "response"]
            if len(responses) >= 2:
                break
            time.sleep(0.1)
        assert [(r["trial"], r["choice"]) for r in responses] == [(0, "left"), (1, "right")]
        assert responses[1]["rt_s"] > 0
    finally:
        rt.close()
