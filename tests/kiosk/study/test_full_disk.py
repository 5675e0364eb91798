"""A full disk during a study: nothing acknowledged is lost, the participant is asked to call the researcher, the
researcher sees why in /healthz and the log, and recording resumes by itself when space returns."""
from __future__ import annotations

import logging
import time

from kiosk.study.config import load_study_config
from kiosk.study.log import read_log
from kiosk.study.runtime import StudyRuntime, control_socket_of

from ..full_disk import small_disk
from .conftest import write_study
from .driver import StudyPage, operator


def _answer(page: StudyPage, side: str = "left") -> tuple[int, dict]:
    tr = page.state()["trial"]
    page.raw("POST", "/api/study/shown", {"token": tr["token"]})
    return page.raw("POST", "/api/study/choice", {"token": tr["token"], "side": side})


def _answer_until_refused(page: StudyPage, acked: list[int]) -> tuple[int, dict]:
    """Tap until the log refuses (a small record may still fit in the log file's last page)."""
    for _ in range(6):
        status, doc = _answer(page)
        if status != 200:
            return status, doc
        assert doc["recorded"], doc
        acked.append(doc["seq"])
    raise AssertionError("the full disk never refused a record")


def test_a_full_disk_mid_study_is_visible_loses_nothing_and_recording_resumes(tmp_path, study_env, caplog):
    with small_disk(tmp_path / "disk", size_kib=4096) as disk:
        cfg = load_study_config(write_study(tmp_path, study_env, log=str(disk.folder / "study.jsonl")))
        rt = StudyRuntime(cfg, port=0, device="emulated")
        page, sock = StudyPage(rt.daemon.server.url), control_socket_of(cfg)
        try:
            operator(sock, "study.start", participant="P05")
            acked = []
            for _ in range(2):
                status, doc = _answer(page)
                assert status == 200 and doc["recorded"], doc
                acked.append(doc["seq"])
            status, health = page.raw("GET", "/healthz")
            assert health["checks"]["study_log"]["ok"], health

            disk.fill(slack=64)
            with caplog.at_level(logging.ERROR, logger="kiosk.study.service"):
                status, doc = _answer_until_refused(page, acked)
            assert status == 503 and doc["recorded"] is False and "call the researcher" in doc["notice"], doc
            assert page.state() == {"state": "call_researcher", "notice": doc["notice"]}
            status, health = page.raw("GET", "/healthz")
            check = health["checks"]["study_log"]
            assert status == 503 and not check["ok"] and "cannot write to the study log" in check["detail"], health
            assert any("call the researcher" in r.getMessage() for r in caplog.records)
            assert operator(sock, "study.status")["log_error"] is not None

            # a restart on the full disk (what the stopped watchdog pings lead to) comes back in the same state
            rt.close()
            rt = StudyRuntime(cfg, port=0, device="emulated")
            page = StudyPage(rt.daemon.server.url)
            if page.state()["state"] == "trial":   # its resume record may still have fit in the file's last page
                assert _answer_until_refused(page, acked)[0] == 503
            assert page.state()["state"] == "call_researcher"

            disk.free()
            deadline = time.monotonic() + 20
            while page.state()["state"] != "trial" and time.monotonic() < deadline:
                time.sleep(0.1)
            status, doc = _answer(page, "right")
            assert status == 200 and doc["recorded"], doc
            acked.append(doc["seq"])
            status, health = page.raw("GET", "/healthz")
            assert health["checks"]["study_log"]["ok"], health
        finally:
            rt.close()
        read = read_log(cfg.log)
        assert not read.problems and not read.torn_tail
        responses = {r["seq"]: r for r in read.records if r["type"] == "response"}
        assert set(acked) <= set(responses) and len(responses) == len(acked)
        down = [r for r in read.records if r["type"] == "event" and r["kind"] == "log_write_failed"]
        assert len(down) == 1 and down[0]["down_s"] > 0 and "cannot write" in down[0]["detail"]
