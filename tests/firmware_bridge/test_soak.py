"""Fault soak: >= 1000 stroke-edit frames on a 1280x800 panel under injected faults (modelled time), and a
real-time unplug/replug that must recover within 2 s and re-send the current frame."""
from __future__ import annotations

import time

import numpy as np
import pytest

from firmware_bridge import protocol as P
from firmware_bridge import synth
from firmware_bridge.config import FaultConfig
from firmware_bridge.display import LinkState
from firmware_bridge.errors import CommitError, LinkDownError

from .conftest import build

FAULTS = FaultConfig(seed=1234, drop=0.01, corrupt=0.01, duplicate=0.01, reorder=0.01, delay=0.01, delay_s=0.02,
                     stall=0.002, stall_s=0.05)
UNPLUG_AT = {250, 600, 900}


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_soak_1000_frames_under_faults_commits_only_whole_host_frames():
    disp, emu = build(transport="hid", link="hs-hid", report_size=1024, faults=FAULTS)
    disp.open()
    frame, mask = synth.friction_frame(seed=7)
    rng = np.random.default_rng(7)
    host_crcs = {P.crc32(np.zeros((800, 1280), np.uint8).tobytes())}
    felt = np.zeros((800, 1280), np.uint8)  # what the device must hold
    outcomes = {"ok": 0, "link_down": 0, "refused": 0, "recoveries": 0}
    for i in range(1000):
        if i:
            frame, mask = synth.stroke_edit(frame, mask, rng)
        host_crcs.add(P.crc32(frame.tobytes()))
        if i in UNPLUG_AT:
            emu.unplug()
        try:
            disp.present(frame)
            felt = frame
            outcomes["ok"] += 1
        except LinkDownError:
            outcomes["link_down"] += 1
        except CommitError:
            outcomes["refused"] += 1  # the previous frame stays: checked below
        if i - 3 in UNPLUG_AT:
            emu.replug()
        if disp.link_state is LinkState.DOWN:
            t0 = emu.clock.now()
            if disp.reconnect(timeout_s=2.0):
                assert emu.clock.now() - t0 <= 2.0
                outcomes["recoveries"] += 1
                felt = frame  # reconnect re-sends the current frame
        if disp.link_state is LinkState.UP:
            assert np.array_equal(emu.active_frame, felt), f"frame {i}: device differs from host"
    disp.close()
    # every frame that ever became active on the device was a whole host frame, never a partial one
    assert all(crc in host_crcs for _, crc in emu.committed)
    assert len(emu.committed) >= 900
    assert outcomes["recoveries"] >= len(UNPLUG_AT)
    counts = emu.fault_counts()
    for kind in ("drop", "corrupt", "duplicate", "reorder", "delay", "stall"):
        assert counts.get(f"out.{kind}", 0) + counts.get(f"in.{kind}", 0) > 0, kind
    assert disp.session.stats["retransmits"] > 50
    print(f"soak: {outcomes}, faults {counts}, session {dict(disp.session.stats)}")


@pytest.mark.timeout(30)
def test_real_time_unplug_replug_recovers_within_2s_and_resends_the_frame():
    disp, emu = build(transport="hid", link="none", report_size=1024, modelled=False, background=True,
                      heartbeat_interval_s=0.1, heartbeat_timeout_s=0.05, reconnect_interval_s=0.05)
    disp.open()
    frame, _ = synth.friction_frame(seed=3)
    disp.present(frame)
    emu.unplug()
    deadline = time.monotonic() + 2.0
    while disp.link_state is not LinkState.DOWN and time.monotonic() < deadline:
        time.sleep(0.01)
    assert disp.link_state is LinkState.DOWN, "heartbeat did not notice the unplug"
    newer = frame.copy()
    newer[:64, :64] = 1
    with pytest.raises(LinkDownError):
        disp.present(newer)  # the kiosk moves on; this frame must arrive after the replug
    emu.replug()
    t0 = time.monotonic()
    while not (disp.link_state is LinkState.UP and np.array_equal(emu.active_frame, newer)):
        assert time.monotonic() - t0 < 2.0, "no recovery within 2 s of the replug"
        time.sleep(0.01)
    assert disp.health().reconnects == 1
    disp.close()
    assert not emu.felt().any()
