"""`vtkiosk study run` stops cleanly on SIGTERM in the middle of a participant's session, and its log stays whole."""
from __future__ import annotations

import threading
import time

from kiosk.study.config import load_study_config
from kiosk.study.log import read_log

from .conftest import write_study
from .driver import operator
from .simulate import StudyProcess


def test_sigterm_mid_session_stops_cleanly_and_loses_nothing(tmp_path, study_env):
    cfg_path = write_study(tmp_path, study_env, name="sig", seed=3)
    config = load_study_config(cfg_path)
    proc = StudyProcess(cfg_path, tmp_path / "proc")
    proc.start()
    recorded: list[int] = []
    done = threading.Event()

    def participant() -> None:
        assert proc.page is not None and proc.socket is not None
        try:
            assert operator(proc.socket, "study.start", participant="P01")["ok"]
            while not done.is_set():
                st = proc.page.state()
                if st["state"] != "trial":
                    return
                tr = st["trial"]
                proc.page.shown(tr["token"])
                if proc.page.choose(tr["token"], "left")["recorded"]:
                    recorded.append(tr["index"])
        except Exception:  # noqa: BLE001 - the server went away mid-request: expected once it stops
            return

    try:
        t = threading.Thread(target=participant, daemon=True)
        t.start()
        deadline = time.monotonic() + 60
        while len(recorded) < 2 and time.monotonic() < deadline and t.is_alive():
            time.sleep(0.02)
        assert len(recorded) >= 2, "the session never got going"
    finally:
        done.set()
        assert proc.stop() == 0
    log = read_log(config.log)
    assert not log.problems and not log.torn_tail
    responses = [r for r in log.records if r["type"] == "response"]
    assert len(responses) >= len(recorded)
