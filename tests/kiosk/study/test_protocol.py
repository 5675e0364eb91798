"""The whole protocol through the real daemon (real HTTP, control socket, ONNX Runtime, emulated device): consent
before trial 1, optional demographics, familiarisation textures on the device (logged, skipped by the operator
only, never analysed), the operator's release between trials, the plain timeout notice, the response time of a
reloaded page, withdrawal, and the researcher's status view."""
from __future__ import annotations

import hashlib
import time

import cv2
import numpy as np
import pytest

from kiosk.study.config import load_study_config
from kiosk.study.log import load_state, read_log
from kiosk.study.report import report_log
from kiosk.study.runtime import StudyRuntime, control_socket_of
from kiosk.study.watch import format_status

from .conftest import write_study
from .driver import StudyPage, operator

CONSENT = {"version": "2026-01", "text": "I agree to take part. I may stop at any time."}
DEMOGRAPHICS = {"age_band": ["18-24", "25-34", "35+"], "dominant_hand": ["left", "right"]}
FAMILIARISATION = {"screen_mm": [217, 136], "textures": [{"kind": "grating", "period_mm": 8},
                                                          {"kind": "uniform", "level": 0.5},
                                                          {"kind": "bump", "diameter_mm": 30}]}


def _runtime(tmp_path, env, **overrides):
    cfg = load_study_config(write_study(tmp_path, env, **overrides))
    rt = StudyRuntime(cfg, port=0, device="emulated")
    return rt, cfg, StudyPage(rt.daemon.server.url), control_socket_of(cfg)


def _records(cfg, kind):
    return [r for r in read_log(cfg.log).records if r["type"] == kind]


def _device_frame(page) -> np.ndarray:
    status, png = page.get_bytes("/api/debug/device-frame")
    assert status == 200
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)


def _answer_trial(page, side="left", page_id="p1"):
    tr = page.state()["trial"]
    page.raw("POST", "/api/study/shown", {"token": tr["token"], "page": page_id})
    assert page.choose(tr["token"], side)["recorded"]
    return tr


def test_consent_demographics_and_familiarisation_come_before_trial_one(tmp_path, study_env):
    rt, cfg, page, sock = _runtime(tmp_path, study_env, consent=CONSENT, demographics=DEMOGRAPHICS,
                                   familiarisation=FAMILIARISATION)
    try:
        assert operator(sock, "study.start", participant="P01")["stage"] == "consent"
        st = page.state()
        assert st["state"] == "consent" and st["consent"] == CONSENT
        # nothing of a trial exists before consent: no token to show or tap, no release
        assert page.shown(st["token"]) == {"ok": False, "ignored": "not the current trial"}
        assert page.choose(st["token"], "left")["recorded"] is False
        assert not operator(sock, "study.next")["ok"]
        status, err = page.raw("POST", "/api/study/consent", {"token": st["token"], "agreed": "yes",
                                                              "version": "2026-01"})
        assert status == 400 and "true or false" in err["error"]
        # a page that showed an older consent text cannot agree to this one
        assert page.raw("POST", "/api/study/consent", {"token": st["token"], "agreed": True,
                                                       "version": "2025-12"})[1]["recorded"] is False
        assert page.raw("POST", "/api/study/consent", {"token": st["token"], "agreed": True,
                                                       "version": "2026-01"})[1]["recorded"]
        [c] = _records(cfg, "consent")
        assert c["agreed"] is True and c["version"] == "2026-01"
        assert c["text_sha256"] == hashlib.sha256(CONSENT["text"].encode()).hexdigest()
        assert "take part" not in cfg.log.read_text()          # the text itself is not copied into every log

        st = page.state()
        assert st["state"] == "demographics" and st["fields"] == DEMOGRAPHICS
        status, err = page.raw("POST", "/api/study/demographics", {"token": st["token"],
                                                                   "answers": {"age_band": "17"}})
        assert status == 400 and "offered choices" in err["error"]
        status, err = page.raw("POST", "/api/study/demographics", {"token": st["token"], "answers": {"name": "x"}})
        assert status == 400 and "unknown demographics field" in err["error"]
        assert page.raw("POST", "/api/study/demographics", {"token": st["token"], "answers": {
            "age_band": "18-24", "dominant_hand": None}})[1]["recorded"]

        # familiarisation: the grating lies on the device at its physical period (8 mm on a 217 mm wide screen)
        st = page.state()
        assert (st["state"], st["step"], st["of"], st["label"]) == ("familiarisation", 1, 3, "grating, 8 mm period")
        frame = _device_frame(page)
        x, y, w, h = st["rect"]
        row = frame[y + h // 2, x:x + w].astype(float)
        assert not frame[:y].any() and not frame[y + h:].any()            # only in the stage area
        spectrum = np.abs(np.fft.rfft(row - row.mean()))
        period_px = w / np.argmax(spectrum)
        assert period_px == pytest.approx(8 / (217 / frame.shape[1]), rel=0.03)
        status, png = page.get_bytes(st["image"])
        shown = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
        assert status == 200 and np.array_equal(shown, frame[y:y + h, x:x + w])  # the page shows what is felt
        # the participant's page can only go to the next texture; the stage has no participant-side skip
        assert page.raw("POST", "/api/study/skip", {"token": st["token"]})[0] == 404
        assert page.raw("POST", "/api/study/familiarised", {"token": st["token"]})[1]["recorded"]
        st = page.state()
        assert st["step"] == 2 and (_device_frame(page)[y:y + h, x:x + w] == 128).all()   # 50 % everywhere
        assert "texture 2/3" in format_status(operator(sock, "study.status"))
        assert operator(sock, "study.skip")["stage"] == "trial"            # release: none in this config
        assert not operator(sock, "study.skip")["ok"]                      # nothing left to skip
        _answer_trial(page)                                                # the warm-up
        _answer_trial(page)                                                # the first test trial
        fam = _records(cfg, "familiarisation")
        assert [(f["step"], f["action"]) for f in fam] == [(0, "shown"), (0, "done"), (1, "shown"), (1, "skipped")]
        rep = report_log(cfg.log)
        assert rep["familiarisation_steps_not_analysed"] == 1 and rep["consent"] == {"agreed": 1, "declined": 0}
    finally:
        rt.close()

    # after a restart the session resumes past consent, demographics and the skipped familiarisation
    rt, cfg, page, sock = _runtime(tmp_path, study_env, consent=CONSENT, demographics=DEMOGRAPHICS,
                                   familiarisation=FAMILIARISATION)
    try:
        assert page.state()["state"] == "trial" and len(_records(cfg, "consent")) == 1
    finally:
        rt.close()


def test_declined_consent_ends_the_session_without_trials(tmp_path, study_env):
    rt, cfg, page, sock = _runtime(tmp_path, study_env, consent=CONSENT)
    try:
        operator(sock, "study.start", participant="P02")
        st = page.state()
        assert page.raw("POST", "/api/study/consent", {"token": st["token"], "agreed": False,
                                                       "version": "2026-01"})[1] == {"recorded": True,
                                                                                     "agreed": False}
        assert page.state()["state"] == "done" and "consent" in page.state()["notice"]
        assert _records(cfg, "consent")[0]["agreed"] is False
        assert [e["reason"] for e in _records(cfg, "end")] == ["no_consent"]
        assert not _records(cfg, "shown") and not _records(cfg, "response")
    finally:
        rt.close()


def test_operator_releases_each_trial_and_the_clock_starts_on_screen(tmp_path, study_env):
    rt, cfg, page, sock = _runtime(tmp_path, study_env, release="each_trial", time_limit_s=1.5,
                                   timeout_notice_s=1.0)
    try:
        reply = operator(sock, "study.start", participant="P03")
        assert reply["stage"] == "wait" and reply["put_garment_on_table"] == cfg.warmup_garment
        st = page.state()
        assert st["state"] == "wait" and "wait" in st["notice"].lower() and "index finger" in st["instructions"]
        assert not _device_frame(page).any()                      # nothing to feel while waiting
        text = format_status(operator(sock, "study.status"))
        assert f"garment on the table: {cfg.warmup_garment}" in text and "vtkiosk study next" in text
        assert operator(sock, "study.next")["stage"] == "trial"
        assert not operator(sock, "study.next")["ok"]             # nothing is waiting now
        _answer_trial(page)                                       # the warm-up
        st = page.state()
        assert st["state"] == "wait" and st["instructions"] is None
        time.sleep(1.0)                                           # a long pause: the test trial's clock must not run
        assert page.raw("POST", "/api/study/release", {})[1]["ok"]     # the N key on the kiosk page
        tr = page.state()["trial"]
        assert tr["time_left_s"] is None                          # released but not yet on screen: no clock
        time.sleep(0.5)
        left = page.raw("POST", "/api/study/shown", {"token": tr["token"], "page": "p1"})[1]["time_left_s"]
        assert 1.3 < left <= 1.5
        time.sleep(1.7)
        st = page.state()                                         # the timeout is told plainly ...
        assert st["state"] == "timeout" and "Time is up" in st["notice"]
        time.sleep(1.3)
        assert page.state()["state"] == "wait"                    # ... before moving on
        [r] = [r for r in _records(cfg, "response") if r["timeout"]]
        assert r["trial"] == tr["index"]
        releases = _records(cfg, "release")
        assert [(x["trial"], x["by"]) for x in releases] == [(0, "operator"), (1, "key")]
    finally:
        rt.close()


def test_new_garment_release_and_reloaded_page_response_time(tmp_path, study_env):
    rt, cfg, page, sock = _runtime(tmp_path, study_env, release="new_garment")
    try:
        operator(sock, "study.start", participant="P04")
        schedule = rt.service._active.schedule
        waits = []
        for t in schedule.trials:
            st = page.state()
            waits.append(st["state"] == "wait")
            if st["state"] == "wait":
                operator(sock, "study.next")
            tr = page.state()["trial"]
            assert tr["index"] == t.index
            if t.index == 2:                                      # a page reload in the middle of a trial
                page.raw("POST", "/api/study/shown", {"token": tr["token"], "page": "first"})
                time.sleep(1.0)
                page.raw("POST", "/api/study/shown", {"token": tr["token"], "page": "reloaded"})
                assert page.choose(tr["token"], "right")["recorded"]
            else:
                _answer_trial(page)
        expect = [i == 0 or schedule.trials[i - 1].garment != t.garment for i, t in enumerate(schedule.trials)]
        assert waits == expect
        r2 = [r for r in _records(cfg, "response") if r["trial"] == 2][0]
        shown = [r for r in _records(cfg, "shown") if r["trial"] == 2]
        assert [s["page"] for s in shown] == ["first", "reloaded"] and shown[1]["reshown"] is True
        assert r2["rt_s"] < 0.9 and r2["shown_mono"] == shown[1]["mono"]    # from the reloaded page's report
    finally:
        rt.close()


def test_withdrawal_ends_the_session_excludes_and_deletes_nothing(tmp_path, study_env):
    rt, cfg, page, sock = _runtime(tmp_path, study_env)
    try:
        for code in ("P05", "P06"):
            operator(sock, "study.start", participant=code)
            for _ in range(7):
                _answer_trial(page, side="left" if code == "P05" else "right")
        operator(sock, "study.start", participant="P07")
        _answer_trial(page)
        _answer_trial(page)
        before = cfg.log.read_bytes()
        status = operator(sock, "study.status")
        assert status["counts"] is None                           # hidden unless asked for
        counts = operator(sock, "study.status", counts=True)["counts"]
        assert sum(c["n"] for c in counts) == 6 + 6 + 1
        reply = operator(sock, "study.withdraw", participant="P07")
        assert reply["ok"] and reply["withdrawn"] == "P07"
        assert page.state()["state"] == "done"                    # their running session ended
        assert operator(sock, "study.withdraw", participant="P06")["ok"]
        after = cfg.log.read_bytes()
        assert after.startswith(before)                           # append-only: nothing deleted or rewritten
        again = operator(sock, "study.start", participant="P06")
        assert not again["ok"] and "withdrawn" in again["error"]
        assert not operator(sock, "study.withdraw", participant="P99")["ok"]
        assert sum(c["n"] for c in operator(sock, "study.status", counts=True)["counts"]) == 6
    finally:
        rt.close()
    rep = report_log(cfg.log)
    assert rep["withdrawn"] == ["P06", "P07"] and rep["participants"] == 1
    assert rep["overall"]["n"] == 6 and rep["withdrawn_responses_excluded"] == 7 + 2
    state, _ = load_state(cfg.log)
    assert len(state.responses()) == 7 * 2 + 2                   # every record is still in the log


def test_operator_page_api_is_read_only_with_counts_on_request(tmp_path, study_env):
    rt, cfg, page, sock = _runtime(tmp_path, study_env, release="each_trial")
    try:
        status, html = page.get_bytes("/study-operator")
        assert status == 200 and b"Release next trial" in html
        operator(sock, "study.start", participant="P08")
        st = page.raw("GET", "/api/study/operator")[1]
        assert st["active"]["waiting_for_release"] and st["counts"] is None
        assert page.raw("GET", "/api/study/operator?counts=1")[1]["counts"][0]["n"] == 0
        assert page.raw("POST", "/api/study/operator/next", {})[1]["ok"]
        assert page.raw("GET", "/api/study/operator")[1]["active"]["stage"] == "trial"
    finally:
        rt.close()
