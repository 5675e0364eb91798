"""The visual study through the real daemon: each side shows its condition's visual output (the model's visual
graph, run by ONNX Runtime from the reference sketch), the haptic layer stays off, and the records and report are
the same as the haptic study's."""
from __future__ import annotations

import math

import cv2
import numpy as np

from kiosk.study.config import load_study_config
from kiosk.study.log import read_log
from kiosk.study.report import plot, report_log
from kiosk.study.runtime import StudyRuntime, control_socket_of
from kiosk.study.schedule import make_schedule

from .conftest import write_study
from .driver import StudyPage, operator
from .study_bundles import GAINS


def _green(condition: str) -> float:
    """Inside the object, off the sketch lines, the test graph's visual is (tanh 0, tanh(10 gain), tanh 0)."""
    return 127.5 + 127.5 * math.tanh(10 * GAINS[condition])


def test_visual_trials_show_each_conditions_visual_output_and_nothing_to_feel(tmp_path, study_env):
    cfg = load_study_config(write_study(tmp_path, study_env, name="visual", kind="visual", warmup_trials=2,
                                        time_limit_s=None))
    assert cfg.question == "Which image do you think is more realistic?"
    rt = StudyRuntime(cfg, port=0, device="emulated")
    page, sock = StudyPage(rt.daemon.server.url), control_socket_of(cfg)
    try:
        loaded = rt.daemon.status()["last_reload"]["loaded"]
        assert all(list(e["probe"]) == ["visual"] for e in loaded)      # visual graphs only
        operator(sock, "study.start", participant="P01")
        schedule = make_schedule(cfg, "P01")
        assert [t.half for t in schedule.trials] == ["full"] * len(schedule.trials)
        for t in schedule.trials:
            st = page.state()
            tr = st["trial"]
            assert tr["index"] == t.index and tr["kind"] == "visual" and "visual" not in tr
            assert tr["timed"] is False and tr["time_limit_s"] is None
            for p in tr["panels"]:
                status, png = page.get_bytes(p["image"])
                assert status == 200
                rgba = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED),
                                    cv2.COLOR_BGRA2RGBA)
                inside = rgba[..., 3] > 0
                assert inside.mean() > 0.2
                cond = t.condition_on(p["side"])
                assert abs(np.median(rgba[..., 1][inside]) - _green(cond)) <= 2, (p["side"], cond)
                x, y, w, h = p["placement"]["rect"]
                px, py, pw, ph = p["rect"]
                assert px <= x + w / 2 <= px + pw and py <= y + h / 2 <= py + ph   # the garment lies on its panel
            _, plan = page.raw("GET", "/api/plan")
            assert all(q["graph"] in ("visual", "none") for q in plan["plan"]["panels"])
            status, frame = page.get_bytes("/api/debug/device-frame")
            assert status == 200 and not cv2.imdecode(np.frombuffer(frame, np.uint8), cv2.IMREAD_GRAYSCALE).any()
            page.raw("POST", "/api/study/shown", {"token": tr["token"], "page": "p"})
            # this participant prefers the reference's image
            assert page.choose(tr["token"], t.side_of(cfg.reference))["recorded"]
        assert page.state()["state"] == "done"
    finally:
        rt.close()
    responses = [r for r in read_log(cfg.log).records if r["type"] == "response"]
    assert len(responses) == len(schedule.trials) and all(r["half"] == "full" for r in responses)
    session = [r for r in read_log(cfg.log).records if r["type"] == "session"][0]
    assert session["kind"] == "visual"
    rep = report_log(cfg.log, resamples=200)
    assert rep["kind"] == "visual" and rep["warmup_responses"] == 2
    assert all(c["rate"] == 1.0 for c in rep["comparisons"])
    out = plot(rep, tmp_path / "visual.png")
    assert out.read_bytes()[:4] == b"\x89PNG"
