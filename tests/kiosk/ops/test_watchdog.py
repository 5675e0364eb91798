"""The watchdog contract with systemd, on a notify socket the test owns (as systemd would):
READY=1 arrives once serving; WATCHDOG=1 pings stop while inference hangs or the haptic device is gone; they
resume after recovery; STOPPING=1 on shutdown.

First in-process, with the real parts the daemon composes (an ONNX Runtime inference loop beating a Heartbeat,
a HapticDisplay on the emulated bridge, a loopback HTTP server, HealthMonitor + Watchdog + Notifier), for both
sd_notify back ends. Then end to end: the real `vtkiosk serve` as a child process with NOTIFY_SOCKET and
WATCHDOG_USEC set, broken and mended through its fault-injection control ops (debug.hang, debug.unplug/replug).
"""
from __future__ import annotations

import http.server
import json
import threading
import time
import urllib.error
import urllib.request

import numpy as np
import onnxruntime as ort
import pytest
from prometheus_client.parser import text_string_to_metric_families

from firmware_bridge.config import BridgeConfig, EmulatorConfig
from firmware_bridge.display import HapticDisplay
from firmware_bridge.emulator import DeviceEmulator
from firmware_bridge.transports.emulated import EmulatedTransport
from kiosk.ops.control import send_control
from kiosk.ops.health import HealthMonitor, Heartbeat, device_check, http_check
from kiosk.ops.notify import Notifier, Watchdog
from kiosk.bundle.probe import session_options
from tests.kiosk.bundle_factory import make_bundle, tiny_graph
from tests.kiosk.serve_process import ServeProcess, TimedNotifySocket

PING = "WATCHDOG=1"


def is_ping(m: str) -> bool:
    return m == PING


class _Ok(http.server.BaseHTTPRequestHandler):
    def do_GET(self):  # noqa: N802
        self.send_response(200)
        self.end_headers()
        self.wfile.write(b"{}")

    def log_message(self, *a):
        pass


class InferenceLoop:
    """A real ORT loop: run the graph, beat with the latency; `hang()` blocks it mid-iteration like a stuck call."""

    def __init__(self, graph, heartbeat: Heartbeat):
        self.sess = ort.InferenceSession(str(graph), session_options(1), providers=["CPUExecutionProvider"])
        self.hb = heartbeat
        self.running = threading.Event()
        self.running.set()
        self.stop_ = threading.Event()
        x = np.zeros((1, 1, 64, 64), np.float32)
        self.feed = {"sketch": x, "mask": np.ones_like(x)}
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self.stop_.is_set():
            self.running.wait()
            t0 = time.perf_counter()
            out = self.sess.run(None, self.feed)[0]
            assert np.isfinite(out).all()
            self.hb.beat(time.perf_counter() - t0)
            time.sleep(0.01)

    def hang(self) -> None:
        self.running.clear()

    def recover(self) -> None:
        self.running.set()

    def close(self) -> None:
        self.stop_.set()
        self.running.set()
        self.thread.join(timeout=5)


def _quiet_for(ns: TimedNotifySocket, since: float, seconds: float) -> list[str]:
    time.sleep(max(0.0, since + seconds - time.monotonic()))
    return ns.between(since, since + seconds)


@pytest.mark.parametrize("native", [True, False], ids=["systemd-python", "pure-python"])
def test_in_process_pings_follow_real_health(tmp_path, monkeypatch, native):
    ns = TimedNotifySocket(str(tmp_path / "notify.sock"))
    monkeypatch.setenv("NOTIFY_SOCKET", ns.address)
    notifier = Notifier.from_env(native=native)
    assert notifier.backend == ("systemd-python" if native else "socket")

    loop = InferenceLoop(tiny_graph(tmp_path / "t.onnx", ["tactile"]), Heartbeat(window_s=5))
    emu = DeviceEmulator(EmulatorConfig(panel_w=128, panel_h=64, tile_w=32, tile_h=32, link="none"))
    cfg = BridgeConfig(type="emulated", heartbeat_interval_s=0.03, reconnect_interval_s=0.05, link_loss_after=2)
    display = HapticDisplay(cfg, transport=EmulatedTransport(cfg, emulator=emu))
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Ok)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    monitor = HealthMonitor({
        "inference": lambda: loop.hb.check(stale_after_s=0.4, budget_s=0.5),
        "device": device_check(display.health, max_heartbeat_age_s=0.5),
        "server": http_check(f"http://127.0.0.1:{srv.server_address[1]}/ping"),
    })
    wd = Watchdog(notifier, monitor, interval_s=0.05)
    try:
        display.open()
        loop.thread.start()
        notifier.ready("serving test")
        wd.start()
        assert ns.wait_for(lambda m: m.startswith("READY=1"), 5)
        t_ok, _ = ns.wait_for(lambda m: m.startswith("STATUS=healthy"), 5)
        assert ns.wait_for(is_ping, 5, after=t_ok), ns.messages

        loop.hang()  # the inference call never returns
        t_bad, status = ns.wait_for(lambda m: m.startswith("STATUS=unhealthy"), 5, after=t_ok)
        assert "inference: no heartbeat for" in status
        assert PING not in _quiet_for(ns, t_bad, 0.6)
        loop.recover()
        t_ok, _ = ns.wait_for(lambda m: m.startswith("STATUS=healthy"), 5, after=t_bad)
        assert ns.wait_for(is_ping, 5, after=t_ok)

        emu.unplug()  # the device dies: the display's heartbeat thread notices
        t_bad, status = ns.wait_for(lambda m: m.startswith("STATUS=unhealthy"), 5, after=t_ok)
        assert "device: link down" in status
        assert PING not in _quiet_for(ns, t_bad, 0.6)
        emu.replug()  # reconnected by the display's own thread
        t_ok, _ = ns.wait_for(lambda m: m.startswith("STATUS=healthy"), 5, after=t_bad)
        assert ns.wait_for(is_ping, 5, after=t_ok)
        assert display.health().reconnects >= 1
    finally:
        wd.stop()
        notifier.stopping()
        loop.close()
        display.close()
        srv.shutdown()
        srv.server_close()
    assert ns.wait_for(lambda m: m.startswith("STOPPING=1"), 5)
    ns.close()


# -- end to end: the real daemon process -------------------------------------------------------------------------

@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    return make_bundle(tmp_path_factory.mktemp("wd-bundle"))


def kiosk_config(bundle_path, trusted, sock) -> dict:
    return {"server": {"port": 0}, "bundles": [str(bundle_path)], "store": {"trusted_keys": str(trusted)},
            "device": {"type": "emulated", "report_size": 1024, "heartbeat_interval_s": 0.05,
                       "reconnect_interval_s": 0.05},
            "health": {"stale_after_s": 1.0, "device_max_heartbeat_age_s": 0.5},
            "control": {"socket": str(sock)}, "debug": {"fault_injection": True}}


def _get(url: str) -> tuple[int, str, str]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, r.headers.get("Content-Type", ""), r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.headers.get("Content-Type", ""), e.read().decode()


@pytest.mark.slow
@pytest.mark.parametrize("hide_systemd", [False, True], ids=["systemd-python", "pure-python"])
def test_daemon_process_pings_only_while_healthy(tmp_path, bundle, hide_systemd):
    path, trusted = bundle
    ns = TimedNotifySocket(str(tmp_path / "notify.sock"))
    ctl = tmp_path / "control.sock"
    watchdog_s = 1.0  # WatchdogSec=1s: systemd expects a ping every 0.5 s
    kiosk = ServeProcess(kiosk_config(path, trusted, ctl), tmp_path, hide_systemd=hide_systemd,
                         env={"NOTIFY_SOCKET": ns.address, "WATCHDOG_USEC": str(int(watchdog_s * 1e6))})
    try:
        kiosk.start()
        t_ready, ready = ns.wait_for(lambda m: m.startswith("READY=1"), 10)
        assert "STATUS=serving denim-shorts on http://127.0.0.1:" in ready
        t_ok, _ = ns.wait_for(lambda m: m.startswith("STATUS=healthy"), 10)
        assert ns.wait_for(is_ping, 5, after=t_ok)
        # while healthy, pings come at half the watchdog period (0.5 s): never a gap systemd would act on
        time.sleep(2.0)
        pings = [t for t, m in ns.timed if m == PING and t > t_ok]
        assert len(pings) >= 3 and max(np.diff(pings)) < watchdog_s

        # /healthz and /metrics on loopback
        status, ctype, body = _get(kiosk.url + "healthz")
        health = json.loads(body)
        assert status == 200 and "json" in ctype and health["ok"] is True
        assert set(health["checks"]) >= {"inference", "device", "server", "bundle"}
        status, ctype, body = _get(kiosk.url + "metrics")
        assert status == 200 and ctype.startswith("text/plain; version=0.0.4")
        families = {f.name: f for f in text_string_to_metric_families(body)}
        assert any(f.type == "histogram" for f in families.values())
        assert families["vtkiosk_health_ok"].samples[0].value == 1.0

        # inference hangs -> pings stop for longer than the watchdog period (systemd would restart it)
        assert send_control(ctl, {"op": "debug.hang", "on": True})["hang"] is True
        t_bad, status_line = ns.wait_for(lambda m: m.startswith("STATUS=unhealthy"), 10, after=t_ok)
        # the hang stops both loops (inference and preview); which goes stale first depends on when each last beat
        assert any(f"{loop}: no heartbeat" in status_line for loop in ("inference", "preview")), status_line
        assert PING not in _quiet_for(ns, t_bad, 1.5 * watchdog_s)
        code, _, body = _get(kiosk.url + "healthz")
        health = json.loads(body)
        assert code == 503 and health["ok"] is False and health["checks"]["inference"]["ok"] is False
        assert 'vtkiosk_health_check_ok{check="inference"} 0.0' in _get(kiosk.url + "metrics")[2]
        send_control(ctl, {"op": "debug.hang", "on": False})
        t_ok, _ = ns.wait_for(lambda m: m.startswith("STATUS=healthy"), 10, after=t_bad)
        assert ns.wait_for(is_ping, 5, after=t_ok)

        # the haptic device dies -> pings stop; it comes back -> reconnect -> pings resume
        assert send_control(ctl, {"op": "debug.unplug"})["plugged"] is False
        t_bad, status_line = ns.wait_for(lambda m: m.startswith("STATUS=unhealthy"), 10, after=t_ok)
        assert "device:" in status_line
        assert PING not in _quiet_for(ns, t_bad, 1.5 * watchdog_s)
        assert send_control(ctl, {"op": "debug.replug"})["plugged"] is True
        t_ok, _ = ns.wait_for(lambda m: m.startswith("STATUS=healthy"), 10, after=t_bad)
        assert ns.wait_for(is_ping, 5, after=t_ok)
        assert json.loads(_get(kiosk.url + "healthz")[2])["ok"] is True
    finally:
        rc = kiosk.stop()
        ns.drain(0.2)
    assert rc == 0, "".join(kiosk.output)
    assert ns.wait_for(lambda m: m.startswith("STOPPING=1"), 5), ns.messages
    assert ns.messages.index(next(m for m in ns.messages if m.startswith("READY=1"))) < \
        ns.messages.index(next(m for m in ns.messages if m.startswith("STOPPING=1")))
    ns.close()
