"""kiosk.ops.health: heartbeat staleness and latency budget, the monitor, the report, and the ready-made checks."""
from __future__ import annotations

import http.server
import json
import threading

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_bridge.config import BridgeConfig, EmulatorConfig
from firmware_bridge.display import HapticDisplay
from firmware_bridge.emulator import DeviceEmulator
from firmware_bridge.transports.emulated import EmulatedTransport
from kiosk.ops.health import (CheckResult, HealthMonitor, Heartbeat, device_check, health_metrics, http_check,
                          percentile, status_line)
from kiosk.ops.metrics import Registry


class FakeClock:
    """A settable monotonic clock (the Heartbeat's time source), so staleness is tested without sleeping."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def test_heartbeat_fails_before_first_beat_and_when_stale():
    clock = FakeClock()
    hb = Heartbeat(clock=clock)
    r = hb.check(stale_after_s=2, budget_s=0.1)
    assert not r.ok and "no heartbeat yet" in r.detail
    hb.beat()
    assert hb.check(stale_after_s=2, budget_s=0.1).ok
    clock.t += 1.9
    assert hb.check(stale_after_s=2, budget_s=0.1).ok
    clock.t += 0.2
    r = hb.check(stale_after_s=2, budget_s=0.1)
    assert not r.ok and "no heartbeat for 2.1 s" in r.detail
    hb.beat()
    assert hb.check(stale_after_s=2, budget_s=0.1).ok


def test_heartbeat_latency_budget_uses_recent_p95_and_forgets_old_runs():
    clock = FakeClock()
    hb = Heartbeat(window=20, window_s=10, clock=clock)
    for _ in range(19):
        hb.beat(0.03)
    hb.beat(0.5)  # one slow run of 20: p95 interpolates between 0.03 and 0.5 -> 0.0535
    r = hb.check(stale_after_s=5, budget_s=0.1)
    assert r.ok and "p95 54 ms" in r.detail
    hb.beat(0.5)
    hb.beat(0.5)  # two slow runs in the last 20 -> p95 = 0.5
    r = hb.check(stale_after_s=5, budget_s=0.1)
    assert not r.ok and "over budget 100 ms" in r.detail
    clock.t += 11  # all runs now older than window_s; a fresh idle beat keeps it alive
    hb.beat()
    r = hb.check(stale_after_s=5, budget_s=0.1)
    assert r.ok and "idle" in r.detail
    hb.beat(float("nan"))
    assert not hb.check(stale_after_s=5, budget_s=0.1).ok


def test_a_single_slow_run_is_not_a_slow_kiosk():
    clock = FakeClock()
    hb = Heartbeat(window_s=30, min_samples=5, clock=clock)
    hb.beat(0.9)  # the first frame after start-up, 9x the budget
    r = hb.check(stale_after_s=5, budget_s=0.1)
    assert r.ok and "1 recent run(s)" in r.detail
    for _ in range(3):
        hb.beat(0.9)
    assert hb.check(stale_after_s=5, budget_s=0.1).ok
    hb.beat(0.9)  # five slow runs: now it is a slow kiosk
    assert not hb.check(stale_after_s=5, budget_s=0.1).ok
    with pytest.raises(ValueError):
        Heartbeat(window=4, min_samples=5)


@given(st.lists(st.floats(min_value=-1e9, max_value=1e9), min_size=1, max_size=60), st.floats(0, 100))
def test_percentile_matches_numpy(values, q):
    assert percentile(values, q) == pytest.approx(float(np.percentile(values, q)), rel=1e-9, abs=1e-6)


def test_monitor_runs_every_check_and_turns_exceptions_into_failures():
    def broken():
        raise RuntimeError("sensor gone\nsecond line")

    mon = HealthMonitor({"inference": lambda: CheckResult(True, "p95 12 ms"), "broken": broken})
    mon.add_check("wrong", lambda: "yes")
    assert mon.last() is None
    rep = mon.run()
    assert not rep.ok and mon.last() is rep
    assert rep.checks["inference"].ok
    assert rep.checks["broken"] == CheckResult(False, "check raised RuntimeError: sensor gone second line")
    assert "not CheckResult" in rep.checks["wrong"].detail
    assert "\n" not in rep.status_line and rep.status_line.startswith("unhealthy: broken: check raised")
    body = json.loads(json.dumps(rep.to_json()))
    assert body["ok"] is False and body["checks"]["inference"] == {"ok": True, "detail": "p95 12 ms"}
    assert body["status"] == rep.status_line and body["checked_at"] > 0
    mon.remove_check("broken")
    mon.remove_check("wrong")
    rep = mon.run()
    assert rep.ok and rep.status_line == "healthy: inference p95 12 ms"


def test_monitor_without_checks_is_not_healthy():
    rep = HealthMonitor().run()
    assert not rep.ok and rep.status_line == "unhealthy: no health checks configured"


@pytest.mark.parametrize("name", ["", "has space", "semi;colon", "new\nline"])
def test_check_names_are_plain(name):
    with pytest.raises(ValueError, match="health check name"):
        HealthMonitor().add_check(name, lambda: CheckResult(True, ""))


def test_status_line_is_one_bounded_line():
    checks = {f"c{i}": CheckResult(i % 2 == 0, "x" * 300 + "\n\t") for i in range(10)}
    line = status_line(checks)
    assert "\n" not in line and "\t" not in line and len(line) <= 400 and line.startswith("unhealthy: c1:")


class _Handler(http.server.BaseHTTPRequestHandler):
    def do_GET(self):  # noqa: N802 - http.server's naming
        code = 200 if self.path == "/ok" else 503
        self.send_response(code)
        self.end_headers()
        self.wfile.write(b"x")

    def log_message(self, *a):
        pass


def test_http_check_against_a_real_loopback_server():
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    t = threading.Thread(target=srv.serve_forever, daemon=True)
    t.start()
    port = srv.server_address[1]
    try:
        assert http_check(f"http://127.0.0.1:{port}/ok")().ok
        r = http_check(f"http://127.0.0.1:{port}/bad")()
        assert not r.ok and "HTTP 503" in r.detail
    finally:
        srv.shutdown()
        srv.server_close()
    r = http_check(f"http://127.0.0.1:{port}/ok", timeout_s=0.5)()
    assert not r.ok and "does not answer" in r.detail


def test_device_check_follows_a_real_link_through_unplug_and_replug():
    emu = DeviceEmulator(EmulatorConfig(panel_w=64, panel_h=64, tile_w=32, tile_h=32, link="none"))
    cfg = BridgeConfig(type="emulated", background=False, link_loss_after=1)
    disp = HapticDisplay(cfg, transport=EmulatedTransport(cfg, emulator=emu))
    check = device_check(disp.health, max_heartbeat_age_s=5.0)
    assert not check().ok  # not open yet: closed
    disp.open()
    try:
        disp.poll()
        r = check()
        assert r.ok and r.detail.startswith("link up")
        emu.unplug()
        disp.poll()
        r = check()
        assert not r.ok and r.detail.startswith("link down")
        emu.replug()
        assert disp.reconnect(timeout_s=1.0)
        disp.poll()
        assert check().ok
    finally:
        disp.close()


def test_health_rounds_become_gauges():
    reg = Registry()
    record = health_metrics(reg)
    state = {"ok": True}
    mon = HealthMonitor({"device": lambda: CheckResult(state["ok"], "x"), "server": lambda: CheckResult(True, "y")})
    record(mon.run())
    assert "vtkiosk_health_ok 1.0" in reg.render() and 'vtkiosk_health_check_ok{check="device"} 1.0' in reg.render()
    state["ok"] = False
    record(mon.run())
    text = reg.render()
    assert "vtkiosk_health_ok 0.0" in text and 'vtkiosk_health_check_ok{check="device"} 0.0' in text
    assert 'vtkiosk_health_check_ok{check="server"} 1.0' in text
