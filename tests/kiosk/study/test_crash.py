"""Reliability: SIGKILL the study process at random moments across >= 200 trials driven through its real HTTP API;
no acknowledged choice is lost or duplicated, sessions resume at their first unanswered trial, the log always parses."""
from __future__ import annotations

import http.client
import json
import random
import threading
import urllib.error
from collections import Counter

import pytest

from kiosk.ops.control import ControlError
from kiosk.study.config import load_study_config
from kiosk.study.log import load_state, read_log

from .conftest import write_study
from .driver import operator
from .simulate import StudyProcess

pytestmark = pytest.mark.slow
TRIALS = 200      # at least this many acknowledged choices ...
MIN_KILLS = 20    # ... and at least this many SIGKILLs, whichever takes longer on this machine


def _check_log(config) -> None:
    """After every restart: the log parses with no problem at all (a torn last line, if a kill made one, has been
    set aside by the writer before anything else was appended) and nothing is counted twice."""
    read = read_log(config.log)
    assert not read.problems, read.problems
    state, _ = load_state(config.log)
    for s in state.sessions.values():
        assert not s.duplicates
        assert set(s.responses) == set(range(len(s.responses)))   # answered trials are always a prefix


def test_sigkill_at_random_moments_loses_and_duplicates_nothing(tmp_path, study_env):
    root = study_env[0]
    cfg_path = write_study(tmp_path, study_env, name="crash", seed=3, garments=["g00", "g01", "g02"],
                           test_garments=2, participants={"pattern": "P[0-9]{3}"},
                           conditions={c: str(root / "bundles" / c / "{garment}.vtb") for c in ("ours", "pix2pix")})
    config = load_study_config(cfg_path)
    proc = StudyProcess(cfg_path, tmp_path / "proc")
    rng = random.Random(20231001)
    acked: dict[tuple[str, int, int], str] = {}
    codes = iter(f"P{i:03d}" for i in range(1, 1000))
    kills = 0
    while len(acked) < TRIALS or kills < MIN_KILLS:
        proc.start()
        _check_log(config)
        fired = threading.Event()

        def kill_now() -> None:
            fired.set()
            proc.kill()

        killer = threading.Timer(rng.uniform(0.02, 1.5), kill_now)
        killer.start()
        try:
            status = operator(proc.socket, "study.status")
            who = status["active"] and (status["active"]["participant"], status["active"]["session"])
            while True:                                    # until the SIGKILL
                st = proc.page.state()
                if st["state"] in ("idle", "done"):
                    reply = operator(proc.socket, "study.start", participant=next(codes))
                    assert reply["ok"], reply
                    who = (reply["participant"], reply["session"])
                    continue
                assert st["state"] == "trial", st
                tr = st["trial"]
                proc.page.shown(tr["token"])
                side = rng.choice(("left", "right"))
                res = proc.page.choose(tr["token"], side)
                if res["recorded"]:
                    key = (who[0], who[1], res["trial"])
                    assert key not in acked, f"{key} acknowledged twice"
                    acked[key] = side
        except (urllib.error.URLError, http.client.HTTPException, json.JSONDecodeError, ConnectionError,
                ControlError, TimeoutError, OSError):
            if not fired.is_set():                         # only the SIGKILL may break a request
                raise
        killer.cancel()
        killer.join()
        kills += fired.is_set()
        proc.kill()                                        # (no-op when the timer already did it)
    proc.start()
    _check_log(config)
    assert proc.stop() == 0

    assert kills >= MIN_KILLS, kills
    read = read_log(config.log)
    responses = [r for r in read.records if r["type"] == "response"]
    counts = Counter((r["participant"], r["session"], r["trial"]) for r in responses)
    assert max(counts.values()) == 1                       # no response is ever written twice
    for key, side in acked.items():                        # every acknowledged choice is there, as tapped
        assert counts[key] == 1, key
        rec = next(r for r in responses if (r["participant"], r["session"], r["trial"]) == key)
        assert rec["choice"] == side
    assert len(responses) >= len(acked) >= TRIALS          # (a choice written but killed before its reply counts)
    resumes = [r for r in read.records if r["type"] == "resume" and r["reason"] == "restart"]
    assert len(resumes) >= kills // 2
    torn = list(config.log.parent.glob(config.log.name + ".torn-*"))
    print(f"\n{kills} SIGKILLs, {len(acked)} acknowledged choices, {len(responses)} responses in the log, "
          f"{len(resumes)} resumes after restart, {len(torn)} torn tail(s) set aside")
