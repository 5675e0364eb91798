"""The study page in headless Chromium as a participant meets it: instructions on the first screen, consent and
the optional questions, the familiarisation texture, "please wait" until the experimenter presses N, the question
above the panels (never over them), no band of another colour in a panel, no console errors or failed requests,
and a reload that restarts the response time."""
from __future__ import annotations

import time

import pytest

from kiosk.study.config import load_study_config
from kiosk.study.log import read_log
from kiosk.study.runtime import StudyRuntime, control_socket_of

from tests.kiosk.browser import headless_chromium

from .conftest import write_study
from .driver import operator

pytestmark = pytest.mark.browser

CONSENT = {"version": "v2", "text": "I agree to take part in this study."}


def _overlap(a: dict, b: tuple[float, float, float, float]) -> bool:
    bx, by, bw, bh = b
    return a["x"] < bx + bw and bx < a["x"] + a["width"] and a["y"] < by + bh and by < a["y"] + a["height"]


def test_page_stages_layout_and_console(tmp_path, study_env):
    playwright = pytest.importorskip("playwright.sync_api")
    cfg = load_study_config(write_study(
        tmp_path, study_env, name="layout", release="each_trial", consent=CONSENT,
        demographics={"dominant_hand": ["left", "right"]},
        familiarisation={"screen_mm": [217, 136], "textures": [{"kind": "grating", "period_mm": 6}]}))
    rt = StudyRuntime(cfg, port=0, device="emulated")
    problems: list[str] = []
    try:
        sock = control_socket_of(cfg)
        with playwright.sync_playwright() as pw:
            browser = headless_chromium(pw)
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.on("console", lambda m: problems.append(f"console {m.type}: {m.text}") if m.type == "error" else None)
            page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
            # (a poll in flight when the page reloads is aborted by the browser: that is not a failure)
            page.on("requestfailed", lambda r: problems.append(f"request failed: {r.url} {r.failure}")
                    if "ERR_ABORTED" not in (r.failure or "") else None)
            page.on("response", lambda r: problems.append(f"HTTP {r.status}: {r.url}") if r.status >= 400 else None)
            page.goto(rt.url)
            page.wait_for_function("document.getElementById('notice-text').textContent.includes('experimenter')")

            operator(sock, "study.start", participant="P21")
            page.wait_for_selector("#consent:not([hidden])")
            assert CONSENT["text"] in page.inner_text("#consent-text")
            page.click("#consent-yes")
            page.wait_for_selector("#about:not([hidden])")
            page.select_option("#about-dominant_hand", "right")
            page.click("#about-go")
            page.wait_for_selector("#next-texture:not([hidden])")
            assert "grating, 6 mm period" in page.inner_text("#question")
            page.click("#next-texture")

            # the first trial waits for the experimenter, with the instructions on screen
            page.wait_for_function("document.getElementById('notice-text').textContent.includes('preparing')")
            assert "index finger" in page.inner_text("#notice-instructions")
            page.keyboard.press("n")                                     # the experimenter's key
            page.wait_for_function("!document.getElementById('choose-left').disabled", timeout=20000)

            # layout: the question band lies above both panels and the question fits inside it
            trial = page.evaluate("fetch('/api/study/trial').then(r => r.json())")["trial"]
            k = min(1280 / trial["screen"][0], 800 / trial["screen"][1])
            q = page.locator("#question").bounding_box()
            band = page.locator("#band").bounding_box()
            for p in trial["panels"]:
                rect = tuple(v * k for v in p["rect"])
                assert not _overlap(q, rect) and not _overlap(band, rect), (q, band, rect)
            assert q["y"] >= band["y"] and q["y"] + q["height"] <= band["y"] + band["height"] + 1
            fits = page.evaluate("(() => { const e = document.getElementById('ask');"
                                 " return e.scrollHeight <= e.clientHeight + 1; })()")
            assert fits
            for side in ("left", "right"):
                b = page.locator(f"#choose-{side}").bounding_box()
                for p in trial["panels"]:
                    assert not _overlap(b, tuple(v * k for v in p["rect"]))
            # no band of another colour: where the image does not reach, a panel continues the image's background
            visual = rt.bundles.get("ours", cfg.warmup_garment).bundle.asset("visual")
            background = visual[0, 0][:3].astype(int)
            for p in trial["panels"]:
                x, y, w, h = (int(v * k) for v in p["rect"])
                for cx, cy in ((x + 2, y + 2), (x + w - 3, y + 2), (x + 2, y + h - 3), (x + w - 3, y + h - 3)):
                    px = page.evaluate(f"Array.from(document.getElementById('stage').getContext('2d')"
                                       f".getImageData({cx}, {cy}, 1, 1).data)")
                    assert max(abs(a - int(b)) for a, b in zip(px[:3], background)) <= 3, (p["side"], cx, cy, px)
            assert "practice" in page.inner_text("#progress") and "not counted" in page.inner_text(
                "#instructions-line")

            # a reload in the middle of the trial: the response time counts from the reloaded page
            time.sleep(1.5)
            page.reload()
            page.wait_for_function("!document.getElementById('choose-left').disabled", timeout=20000)
            page.click("#choose-left")
            page.wait_for_function("document.getElementById('notice-text').textContent.includes('preparing')")
            browser.close()
        records = read_log(cfg.log).records
        [resp] = [r for r in records if r["type"] == "response"]
        shown = [r for r in records if r["type"] == "shown"]
        assert len(shown) == 2 and shown[1]["reshown"] and resp["shown_mono"] == shown[1]["mono"]
        assert resp["rt_s"] == pytest.approx(resp["mono"] - shown[1]["mono"])   # from the reloaded page ...
        assert resp["mono"] - shown[0]["mono"] >= resp["rt_s"] + 1.5            # ... not from the first one
        assert [r["by"] for r in records if r["type"] == "release"] == ["key"]
        assert [r["answers"] for r in records if r["type"] == "demographics"] == [{"dominant_hand": "right"}]
        assert problems == []
    finally:
        rt.close()
