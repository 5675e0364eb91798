"""kiosk.ops.notify: sd_notify datagrams (systemd-python and the pure-Python sender) to a socket the test owns,
the watchdog interval from the environment, and the health-gated Watchdog."""
from __future__ import annotations

import logging
import os
import uuid

import pytest
from hypothesis import given
from hypothesis import strategies as st

from kiosk.ops.health import CheckResult, HealthMonitor
from kiosk.ops.notify import Notifier, Watchdog, watchdog_interval_s
from tests.kiosk.serve_process import NotifySocket


@pytest.fixture
def notify_socket(tmp_path):
    s = NotifySocket(str(tmp_path / "notify.sock"))
    yield s
    s.close()


@pytest.mark.parametrize("native", [True, False], ids=["systemd-python", "pure-python"])
def test_messages_arrive_with_both_backends(notify_socket, monkeypatch, native):
    monkeypatch.setenv("NOTIFY_SOCKET", notify_socket.address)
    n = Notifier.from_env(native=native)
    assert n.backend == ("systemd-python" if native else "socket")
    assert n.ready("serving denim on 127.0.0.1:8080")
    assert n.status("line one\nWATCHDOG=1 injected")
    assert n.watchdog()
    assert n.extend_timeout(2.5)
    assert n.stopping()
    n.close()
    assert notify_socket.drain() == ["READY=1\nSTATUS=serving denim on 127.0.0.1:8080",
                                     "STATUS=line one WATCHDOG=1 injected",  # a newline can't forge a ping
                                     "WATCHDOG=1", "EXTEND_TIMEOUT_USEC=2500000", "STOPPING=1\nSTATUS=stopping"]
    assert n.sent == 5


def test_default_backend_is_systemd_python_when_installed(notify_socket, monkeypatch):
    pytest.importorskip("systemd.daemon")
    monkeypatch.setenv("NOTIFY_SOCKET", notify_socket.address)
    assert Notifier.from_env().backend == "systemd-python"
    # another address than the environment's: libsystemd cannot reach it, so the socket sender is used
    assert Notifier("/elsewhere.sock").backend == "socket"
    with pytest.raises(ValueError, match="only reach the NOTIFY_SOCKET"):
        Notifier("/elsewhere.sock", native=True)


@pytest.mark.parametrize("native", [True, False], ids=["systemd-python", "pure-python"])
def test_abstract_namespace_socket(monkeypatch, native):
    s = NotifySocket(f"@vtkiosk-test-{uuid.uuid4().hex}")
    try:
        monkeypatch.setenv("NOTIFY_SOCKET", s.address)
        n = Notifier.from_env(native=native)
        assert n.watchdog()
        assert s.drain() == ["WATCHDOG=1"]
    finally:
        s.close()


def test_without_notify_socket_everything_is_a_quiet_no_op(monkeypatch, caplog):
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    n = Notifier.from_env()
    assert not n.enabled and n.backend == "none"
    with caplog.at_level(logging.DEBUG, logger="kiosk.ops.notify"):
        assert not n.ready() and not n.watchdog() and not n.stopping()
    said = [r for r in caplog.records if "NOTIFY_SOCKET is not set" in r.message]
    assert len(said) == 1 and said[0].levelno == logging.DEBUG


def test_a_vanished_socket_is_a_warning_once_not_a_crash(tmp_path, caplog):
    n = Notifier(str(tmp_path / "gone.sock"), native=False)
    with caplog.at_level(logging.WARNING, logger="kiosk.ops.notify"):
        assert not n.watchdog()
        assert not n.watchdog()
    assert len([r for r in caplog.records if "cannot notify systemd" in r.message]) == 1
    assert not Notifier("relative.sock", native=False).watchdog()


def test_watchdog_interval_from_environment():
    pid = str(os.getpid())
    assert watchdog_interval_s({}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "10000000"}) == 5.0
    assert watchdog_interval_s({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": pid}) == 5.0
    assert watchdog_interval_s({"WATCHDOG_USEC": "10000000", "WATCHDOG_PID": str(os.getpid() + 1)}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "0"}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "ten"}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "100", "WATCHDOG_PID": "x"}) is None


@given(st.text(max_size=12), st.one_of(st.none(), st.text(max_size=8)))
def test_watchdog_interval_never_raises(usec, pid):
    env = {"WATCHDOG_USEC": usec} if pid is None else {"WATCHDOG_USEC": usec, "WATCHDOG_PID": pid}
    v = watchdog_interval_s(env)
    assert v is None or v > 0


@pytest.mark.parametrize("native", [True, False], ids=["systemd-python", "pure-python"])
def test_watchdog_pings_only_while_healthy_and_reports_status_changes(notify_socket, monkeypatch, native):
    monkeypatch.setenv("NOTIFY_SOCKET", notify_socket.address)
    state = {"ok": True}
    mon = HealthMonitor({"device": lambda: CheckResult(state["ok"], "link up" if state["ok"] else "link down")})
    seen = []
    wd = Watchdog(Notifier.from_env(native=native), mon, 0.05, on_report=seen.append)
    for _ in range(3):
        wd.tick()
    state["ok"] = False
    for _ in range(3):
        wd.tick()
    state["ok"] = True
    wd.tick()
    assert notify_socket.drain() == ["STATUS=healthy: device link up", "WATCHDOG=1", "WATCHDOG=1", "WATCHDOG=1",
                                     "STATUS=unhealthy: device: link down",
                                     "STATUS=healthy: device link up", "WATCHDOG=1"]
    assert (wd.pings, wd.missed) == (4, 3) and len(seen) == 7


def test_watchdog_thread_runs_and_stops(notify_socket):
    mon = HealthMonitor({"x": lambda: CheckResult(True, "fine")})
    wd = Watchdog(Notifier(notify_socket.address, native=False), mon, 0.02)
    wd.start()
    msgs = notify_socket.drain(0.3)
    wd.stop()
    assert msgs[0] == "STATUS=healthy: x fine" and msgs.count("WATCHDOG=1") >= 3
    n = len(notify_socket.drain(0.1))
    assert len(notify_socket.drain(0.1)) == n  # nothing after stop()
    with pytest.raises(ValueError):
        Watchdog(Notifier(None), mon, 0)
