"""The study service on the real daemon: real HTTP, real control socket, real ONNX Runtime, the emulated device."""
from __future__ import annotations

import re
import threading
import time

import cv2
import numpy as np
import pytest

from kiosk.contract.haptics import friction_map
from kiosk.study.bundles import StudyBundleError, open_study_bundles
from kiosk.study.config import load_study_config
from kiosk.study.log import read_log
from kiosk.study.runtime import StudyRuntime, control_socket_of
from kiosk.study.schedule import make_schedule

from .conftest import write_study
from .driver import StudyPage, operator
from .study_bundles import GAINS, make_study_bundles


def _runtime(tmp_path, env, **overrides):
    cfg = load_study_config(write_study(tmp_path, env, **overrides))
    rt = StudyRuntime(cfg, port=0, device="emulated")
    return rt, cfg, StudyPage(rt.daemon.server.url), control_socket_of(cfg)


@pytest.fixture
def running(tmp_path, study_env):
    rt, cfg, page, sock = _runtime(tmp_path, study_env)
    yield rt, cfg, page, sock
    rt.close()


def _events(cfg, kind):
    return [r for r in read_log(cfg.log).records if r["type"] == "event" and r["kind"] == kind]


def _level(condition: str) -> int:
    g = GAINS[condition]   # tactile = gain * (+-1) inside the mask: a constant friction level per condition
    return int(friction_map(np.full((4, 4), g), np.full((4, 4), -g), 0.05, size=(4, 4))[0, 0])


def test_a_trial_puts_two_tactile_renderings_under_one_reference_visual(running):
    rt, cfg, page, sock = running
    reply = operator(sock, "study.start", participant="P01")
    assert reply["ok"] and reply["trial"] == 0 and reply["block"] == "warmup"
    schedule = make_schedule(cfg, "P01")
    for index in range(3):
        st = page.state()
        assert st["state"] == "trial"
        tr = st["trial"]
        trial = schedule.trials[index]
        assert tr["index"] == index and tr["question"] == cfg.question
        # one ground-truth visual (the reference condition's asset) for both halves
        status, png = page.get_bytes(tr["visual"])
        assert status == 200 and png == rt.bundles.visual_file(trial.garment).read_bytes()
        # both panels show the same half: the garment's centre line on the panel's inner edge for that half
        bx, by, bw, bh = rt.daemon.bundles[f"ours:{trial.garment}"].reference_bbox()
        for p in tr["panels"]:
            x, y, w, h = p["rect"]
            centre = p["placement"]["x"] + (bx + bw / 2) * p["placement"]["scale"]
            assert centre == pytest.approx(x + w if trial.half == "left" else x, abs=1e-6)
        # the planner ran tactile graphs only: no visual inference in a study trial
        _, plan = page.raw("GET", "/api/plan")
        # (a panel whose tactile output is already cached for the same content runs no graph at all)
        assert all(p["graph"] == "tactile" or (p["graph"] == "none" and p["reused"] == ["tactile"])
                   for p in plan["plan"]["panels"]), plan["plan"]["panels"]
        assert [p["bundle"] for p in plan["plan"]["panels"]] == [f"{trial.left}:{trial.garment}",
                                                                 f"{trial.right}:{trial.garment}"]
        # the device holds the two friction maps, each under its own panel, at its condition's level
        status, frame_png = page.get_bytes("/api/debug/device-frame")
        frame = cv2.imdecode(np.frombuffer(frame_png, np.uint8), cv2.IMREAD_GRAYSCALE)
        inside = np.zeros(frame.shape, bool)
        for p in tr["panels"]:
            x, y, w, h = p["rect"]
            inside[y:y + h, x:x + w] = True
            region = frame[y:y + h, x:x + w]
            felt = region[region > 0]
            assert felt.size > 0.2 * region.size
            want = _level(trial.condition_on(p["side"]))
            assert abs(int(np.median(felt)) - want) <= 1, (p["side"], want)
            # ... and exactly under the garment as the page draws it: the reference mask at the panel's placement
            pl = p["placement"]
            mask = rt.bundles.get("ours", trial.garment).bundle.asset("mask").astype(np.uint8)
            warp = np.array([[pl["scale"], 0, pl["x"]], [0, pl["scale"], pl["y"]]])
            placed = cv2.warpAffine(mask, warp, (frame.shape[1], frame.shape[0]), flags=cv2.INTER_NEAREST) > 0
            felt_mask, drawn = region > 0, placed[y:y + h, x:x + w].astype(np.uint8)
            # tolerance: three network-grid pixels in screen pixels (the map is resampled from a 256 grid here, and
            # the network's mask is the filled sketch outline, which includes the line's width)
            grid_scale = next(q["scale"] for q in plan["plan"]["panels"] if q["panel"] == p["side"])
            tol = int(np.ceil(3 / grid_scale))
            kernel = np.ones((2 * tol + 1, 2 * tol + 1), np.uint8)
            assert not (felt_mask & (cv2.dilate(drawn, kernel) == 0)).any(), p["side"]   # nothing off the garment
            assert felt_mask[cv2.erode(drawn, kernel) > 0].all(), p["side"]               # all of it felt
        assert not frame[~inside].any()                     # nothing between or below the panels
        assert _level(trial.left) != _level(trial.right)
        assert page.shown(tr["token"])["ok"]
        assert page.choose(tr["token"], "left")["recorded"]
    # study mode loads and probes the tactile graphs only: the visual comes from the bundle's reference asset
    loaded = rt.daemon.status()["last_reload"]["loaded"]
    assert len(loaded) == 12 and all(list(e["probe"]) == ["tactile"] for e in loaded)
    metrics = page.get_bytes("/metrics")[1].decode()
    assert not re.search(r'vtkiosk_graph_runs_total\{graph="(visual|full)"\} [1-9]', metrics)


def test_every_acknowledged_choice_is_on_disk_and_double_taps_count_once(running):
    rt, cfg, page, sock = running
    operator(sock, "study.start", participant="P02")
    for _ in range(3):
        tr = page.state()["trial"]
        page.shown(tr["token"])
        replies: list[dict] = []
        taps = [threading.Thread(target=lambda: replies.append(page.choose(tr["token"], "right"))) for _ in range(3)]
        for t in taps:
            t.start()
        for t in taps:
            t.join()
        recorded = [r for r in replies if r["recorded"]]
        assert len(recorded) == 1 and sorted(r.get("ignored") for r in replies if not r["recorded"]) == \
            ["double_tap", "double_tap"]
        # acknowledged => already durable: a fresh read of the file has it
        on_disk = [r for r in read_log(cfg.log).records if r["type"] == "response" and r["participant"] == "P02"
                   and r["trial"] == tr["index"]]
        assert len(on_disk) == 1 and on_disk[0]["seq"] == recorded[0]["seq"] and on_disk[0]["choice"] == "right"
    assert len(_events(cfg, "double_tap")) == 6
    r = [x for x in read_log(cfg.log).records if x["type"] == "response"][1]
    assert r["rt_s"] > 0 and r["timeout"] is False and r["bundles"]["left"]["manifest_sha256"]
    assert r["software"].startswith("vtkiosk") and r["boot_id"] and r["wall"] and r["mono"] > r["shown_mono"]


def test_stale_early_and_orphan_taps_are_ignored_and_logged(running):
    rt, cfg, page, sock = running
    assert page.choose("1-0-feedfeedfeed", "left") == {"recorded": False, "ignored": "tap_without_session"}
    operator(sock, "study.start", participant="P03")
    tr = page.state()["trial"]
    assert page.choose(tr["token"], "left") == {"recorded": False, "ignored": "tap_before_shown"}
    assert page.shown("1-0-000000000000") == {"ok": False, "ignored": "not the current trial"}
    page.shown(tr["token"])
    assert page.choose("1-0-000000000000", "left") == {"recorded": False, "ignored": "stale_tap"}
    assert page.choose(tr["token"], "left")["recorded"]
    for kind in ("tap_without_session", "tap_before_shown", "stale_tap"):
        assert len(_events(cfg, kind)) == 1, kind
    assert len([r for r in read_log(cfg.log).records if r["type"] == "response"]) == 1


def test_timeouts_are_recorded_late_taps_ignored_and_warmup_is_untimed(tmp_path, study_env):
    rt, cfg, page, sock = _runtime(tmp_path, study_env, time_limit_s=1)
    try:
        operator(sock, "study.start", participant="P04")
        warm = page.state()["trial"]
        assert warm["block"] == "warmup" and warm["timed"] is False
        assert page.shown(warm["token"])["time_left_s"] is None
        time.sleep(1.3)                                      # longer than the limit: the warm-up does not care
        assert page.choose(warm["token"], "left")["recorded"]
        test = page.state()["trial"]
        assert test["block"] == "test" and test["time_limit_s"] == 1.0
        assert 0.9 < page.shown(test["token"])["time_left_s"] <= 1.0
        time.sleep(1.4)                                      # the daemon's timer records the timeout on its own
        assert page.choose(test["token"], "left") == {"recorded": False, "ignored": "tap_after_timeout"}
        nxt = page.state()["trial"]
        assert nxt["index"] == test["index"] + 1
        responses = [r for r in read_log(cfg.log).records if r["type"] == "response"]
        assert [(r["trial"], r["timeout"], r["choice"], r["rt_s"]) for r in responses[1:]] == \
            [(test["index"], True, None, None)]
        assert responses[0]["time_limit_s"] is None and responses[1]["time_limit_s"] == 1.0
        # a tap that races the timer (limit passed, timer not run yet) is also a timeout, never a choice
        page.shown(nxt["token"])
        rt.service.close()                                   # stop the timer thread: only the tap can notice
        time.sleep(1.2)
        assert page.choose(nxt["token"], "right") == {"recorded": False, "ignored": "tap_after_timeout"}
        last = [r for r in read_log(cfg.log).records if r["type"] == "response"][-1]
        assert (last["trial"], last["timeout"], last["choice"]) == (nxt["index"], True, None)
        assert len(_events(cfg, "tap_after_timeout")) == 2
    finally:
        rt.close()


def test_unknown_codes_are_refused_and_logged_without_the_text(running):
    rt, cfg, page, sock = running
    for code, why in (("P1", "does not match"), ("Jane Doe", "a code, not a name"), ("", "a code, not a name")):
        reply = operator(sock, "study.start", participant=code)
        assert reply["ok"] is False and why in reply["error"]
    events = _events(cfg, "participant_rejected")
    assert [e["detail"] for e in events] == ["does not match the pattern", "not a code", "not a code"]
    assert "Jane" not in cfg.log.read_text()
    assert page.state()["state"] == "idle"


def test_sessions_resume_complete_and_refuse(tmp_path, study_env):
    rt, cfg, page, sock = _runtime(tmp_path, study_env)
    try:
        operator(sock, "study.start", participant="P05")
        for _ in range(3):
            tr = page.state()["trial"]
            page.shown(tr["token"])
            page.choose(tr["token"], "left")
        other = operator(sock, "study.start", participant="P06")
        assert not other["ok"] and "session of P05 is running" in other["error"]
    finally:
        rt.close()
    # a new daemon on the same log resumes P05 at the first unanswered trial
    rt, cfg, page, sock = _runtime(tmp_path, study_env)
    try:
        st = operator(sock, "study.status")
        assert st["active"]["participant"] == "P05" and st["active"]["trial"] == 3
        resume = [r for r in read_log(cfg.log).records if r["type"] == "resume"]
        assert resume[-1]["reason"] == "restart" and resume[-1]["at_trial"] == 3
        n = st["active"]["trials"]
        for i in range(3, n):
            tr = page.state()["trial"]
            assert tr["index"] == i
            page.shown(tr["token"])
            assert page.choose(tr["token"], "right")["recorded"]
        assert page.state()["state"] == "done"
        again = operator(sock, "study.start", participant="P05")
        assert not again["ok"] and "completed session 1" in again["error"]
        assert operator(sock, "study.start", participant="P05", new_session=True)["session"] == 2
        stopped = operator(sock, "study.stop")
        assert stopped["stopped"] == {"participant": "P05", "session": 2}
        assert page.state()["state"] == "idle"
    finally:
        rt.close()
    recs = read_log(cfg.log).records
    p05 = [r for r in recs if r["type"] == "response" and r["session"] == 1]
    assert sorted(r["trial"] for r in p05) == list(range(n))    # each trial once, none lost across the restart
    # a stopped session is not resumed on restart, but the operator can resume it
    rt, cfg, page, sock = _runtime(tmp_path, study_env)
    try:
        assert operator(sock, "study.status")["active"] is None
        assert operator(sock, "study.start", participant="P05")["session"] == 2
    finally:
        rt.close()


def test_bad_requests_get_clear_errors(running):
    rt, cfg, page, sock = running
    operator(sock, "study.start", participant="P07")
    tr = page.state()["trial"]
    assert page.raw("POST", "/api/study/choice", b"{not json")[0] == 400
    status, doc = page.raw("POST", "/api/study/choice", {"token": tr["token"], "side": "up"})
    assert status == 400 and "left' or 'right" in doc["error"]
    status, doc = page.raw("POST", "/api/study/choice", {"token": tr["token"], "side": "left", "rt": 1})
    assert status == 400 and "unknown field(s): rt" in doc["error"]
    assert page.raw("POST", "/api/study/choice", [1, 2])[0] == 400
    assert page.get_bytes("/api/study/visual/nope.png")[0] == 404
    assert page.get_bytes("/api/study/visual/..%2Fmanifest.png")[0] == 404
    assert operator(sock, "study.nope")["ok"] is False
    status, html = page.get_bytes("/study")
    assert status == 200 and b"study.js" in html


def test_bundles_without_reference_assets_or_for_the_wrong_garment_are_refused(tmp_path, study_env):
    root, trusted = study_env
    bad = tmp_path / "bad"
    make_study_bundles(bad, ["ours", "pix2pix"], ["g00", "g01"], drop_asset=("pix2pix", "g01", "visual"))
    cfg = load_study_config(write_study(
        tmp_path, (bad, bad / "trusted"), garments=["g00", "g01"], test_garments=1,
        conditions={c: str(bad / "bundles" / c / "{garment}.vtb") for c in ("ours", "pix2pix")}))
    with pytest.raises(StudyBundleError, match=r"condition pix2pix, garment g01\) has no reference asset\(s\) visual"):
        open_study_bundles(cfg)
    cfg = load_study_config(write_study(
        tmp_path, study_env, garments=["g00", "g01"], test_garments=1,
        conditions={"ours": str(root / "bundles/ours/{garment}.vtb"),
                    "pix2pix": {"g00": str(root / "bundles/pix2pix/g00.vtb"),
                                "g01": str(root / "bundles/pix2pix/g02.vtb")}}))
    with pytest.raises(StudyBundleError, match="is for garment 'g02', not 'g01'"):
        open_study_bundles(cfg)
    cfg = load_study_config(write_study(tmp_path, study_env, conditions={
        "ours": str(root / "bundles/ours/{garment}.vtb"), "pix2pix": str(root / "missing/{garment}.vtb")}))
    with pytest.raises(StudyBundleError, match="missing/g00.vtb.*no such bundle"):
        open_study_bundles(cfg)
    assert not list(tmp_path.glob("vtkiosk-study-*"))        # nothing left behind


def test_a_session_resumes_only_with_the_bundles_it_was_scheduled_with(tmp_path, study_env):
    root = study_env[0]
    rt, cfg, page, sock = _runtime(tmp_path, study_env)
    try:
        operator(sock, "study.start", participant="P08")
        tr = page.state()["trial"]
        page.shown(tr["token"])
        page.choose(tr["token"], "left")
    finally:
        rt.close()
    # the config loses a condition: the unfinished session cannot continue, and nothing pretends it can
    rt, cfg, page, sock = _runtime(tmp_path, study_env, conditions={
        c: str(root / "bundles" / c / "{garment}.vtb") for c in ("ours", "pix2pix")})
    try:
        assert operator(sock, "study.status")["active"] is None
        assert _events(cfg, "resume_impossible")[0]["detail"].startswith("session 1 of P08 was scheduled with")
        reply = operator(sock, "study.start", participant="P08")
        assert not reply["ok"] and "pix2pixhd:g0" in reply["error"] and "--new-session" in reply["error"]
        reply = operator(sock, "study.start", participant="P08", new_session=True)
        assert reply["ok"] and reply["session"] == 2
    finally:
        rt.close()
    ends = [r for r in read_log(cfg.log).records if r["type"] == "end"]
    assert [(e["session"], e["reason"], e["at_trial"]) for e in ends] == [(1, "abandoned", 1)]
    assert len(_events(cfg, "config_changed")) == 0       # the abandoned session was never resumed


def test_resuming_under_a_changed_config_is_logged(tmp_path, study_env):
    rt, cfg, page, sock = _runtime(tmp_path, study_env)
    try:
        operator(sock, "study.start", participant="P09")
    finally:
        rt.close()
    rt, cfg, page, sock = _runtime(tmp_path, study_env, time_limit_s=45)
    try:
        assert operator(sock, "study.status")["active"]["participant"] == "P09"
        assert [e["participant"] for e in _events(cfg, "config_changed")] == ["P09"]
    finally:
        rt.close()
