"""sd_notify for a `Type=notify` service, and the watchdog that pings systemd only while the kiosk is healthy.

systemd passes `NOTIFY_SOCKET` (a unix datagram socket path, or `@name` for the abstract namespace) and, with
`WatchdogSec=`, `WATCHDOG_USEC` (+ `WATCHDOG_PID`). We send READY=1 once serving, WATCHDOG=1 at half the
watchdog period while every health check passes, STATUS=<one line> whenever the state changes, STOPPING=1 on
shutdown. If the pings stop (a check fails for longer than WatchdogSec, or the process hangs), systemd kills
and restarts the kiosk (`Restart=on-failure`).

`systemd.daemon.notify` (systemd-python, the `[journal]` extra) is used when importable; otherwise the same
datagram is sent with the standard library. Both are exercised by tests against a socket the test owns.
"""
from __future__ import annotations

import logging
import os
import socket
import threading
from collections.abc import Callable, Mapping

from kiosk.ops.health import HealthMonitor, HealthReport

log = logging.getLogger(__name__)


def _systemd_daemon():
    try:
        from systemd import daemon  # type: ignore[import-not-found]
    except ImportError:
        return None
    return daemon


def _clean(text: str) -> str:
    """STATUS= is one line of the datagram; a newline would start a new (possibly bogus) assignment."""
    return " ".join(str(text).split())


class Notifier:
    """Sends sd_notify messages to `address`; with no address every call is a no-op (not under systemd).

    `native`: True = use systemd-python (error if missing), False = the pure-Python sender, None = systemd-python
    when importable and `address` is the process's own NOTIFY_SOCKET (libsystemd reads it from the environment).
    """

    def __init__(self, address: str | None, *, native: bool | None = None):
        self.address = address or None
        self._daemon = None
        if self.address is not None:
            lib = _systemd_daemon() if native is not False else None
            if native is True and lib is None:
                raise RuntimeError("systemd-python is not installed (pip install 'vtkiosk[journal]')")
            if lib is not None and (native is True or os.environ.get("NOTIFY_SOCKET") == self.address):
                if os.environ.get("NOTIFY_SOCKET") != self.address:
                    raise ValueError("the systemd-python sender can only reach the NOTIFY_SOCKET of the environment")
                self._daemon = lib
        self._sock: socket.socket | None = None
        self._lock = threading.Lock()
        self._said_noop = False
        self._said_error = False
        self.sent: int = 0

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None, *, native: bool | None = None) -> Notifier:
        env = os.environ if environ is None else environ
        return cls(env.get("NOTIFY_SOCKET"), native=native)

    @property
    def enabled(self) -> bool:
        return self.address is not None

    @property
    def backend(self) -> str:
        if self.address is None:
            return "none"
        return "systemd-python" if self._daemon is not None else "socket"

    def notify(self, message: str) -> bool:
        """Send one raw sd_notify datagram (newline-separated VAR=value lines). True when sent."""
        if self.address is None:
            if not self._said_noop:
                self._said_noop = True
                log.debug("NOTIFY_SOCKET is not set (not started by systemd): sd_notify messages are not sent")
            return False
        try:
            if self._daemon is not None:
                ok = bool(self._daemon.notify(message))
                if not ok:
                    raise OSError("sd_notify() reported failure")
            else:
                self._send(message.encode())
        except OSError as exc:
            if not self._said_error:
                self._said_error = True
                log.warning("cannot notify systemd at %s: %s", self.address, exc)
            return False
        self.sent += 1
        return True

    def _send(self, data: bytes) -> None:
        addr = self.address
        if addr.startswith("@"):
            addr = "\0" + addr[1:]
        elif not addr.startswith("/"):
            raise OSError(f"NOTIFY_SOCKET={self.address!r} is neither an absolute path nor an abstract '@' name")
        with self._lock:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.sendto(data, addr)

    def ready(self, status: str = "serving") -> bool:
        return self.notify(f"READY=1\nSTATUS={_clean(status)}")

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={_clean(text)}")

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def stopping(self, status: str = "stopping") -> bool:
        return self.notify(f"STOPPING=1\nSTATUS={_clean(status)}")

    def extend_timeout(self, seconds: float) -> bool:
        """Ask systemd for more start/stop time (e.g. while a large bundle loads)."""
        return self.notify(f"EXTEND_TIMEOUT_USEC={int(seconds * 1e6)}")

    def close(self) -> None:
        with self._lock:
            if self._sock is not None:
                self._sock.close()
                self._sock = None


def watchdog_interval_s(environ: Mapping[str, str] | None = None) -> float | None:
    """Half of WATCHDOG_USEC in seconds (systemd's advice), or None when the watchdog is off or not ours."""
    env = os.environ if environ is None else environ
    usec = env.get("WATCHDOG_USEC")
    if not usec:
        return None
    pid = env.get("WATCHDOG_PID")
    if pid:
        try:
            if int(pid) != os.getpid():
                return None  # meant for another process (e.g. our parent)
        except ValueError:
            log.warning("ignoring malformed WATCHDOG_PID=%r", pid)
            return None
    try:
        value = int(usec)
    except ValueError:
        log.warning("ignoring malformed WATCHDOG_USEC=%r", usec)
        return None
    if value <= 0:
        return None
    return value / 2e6


class Watchdog:
    """A thread that, every `interval_s`, runs the health checks, sends STATUS= when the line changed, and
    WATCHDOG=1 only when all checks passed. `on_report` (optional) sees every report (e.g. to export metrics)."""

    def __init__(self, notifier: Notifier, monitor: HealthMonitor, interval_s: float, *,
                 on_report: Callable[[HealthReport], None] | None = None):
        if not interval_s > 0:
            raise ValueError(f"watchdog interval must be > 0 s; got {interval_s}")
        self.notifier, self.monitor, self.interval_s = notifier, monitor, float(interval_s)
        self.on_report = on_report
        self.pings = 0
        self.missed = 0  # ticks without a ping because a check failed
        self._last_status: str | None = None
        self._last_ok: bool | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def tick(self) -> HealthReport:
        """One round: check, report, ping if healthy. The thread calls this; tests may too."""
        report = self.monitor.run()
        if report.status_line != self._last_status:
            self.notifier.status(report.status_line)
            self._last_status = report.status_line
        if report.ok != self._last_ok:
            (log.info if report.ok else log.warning)("health %s", report.status_line,
                                                     extra={"HEALTH_OK": int(report.ok)})
            self._last_ok = report.ok
        if report.ok:
            self.notifier.watchdog()
            self.pings += 1
        else:
            self.missed += 1
        if self.on_report is not None:
            try:
                self.on_report(report)
            except Exception:  # noqa: BLE001 - a metrics hook must not stop the watchdog
                log.exception("watchdog on_report hook failed")
        return report

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.tick()
            except Exception:  # noqa: BLE001 - keep the thread; no ping is sent for this round
                log.exception("watchdog round failed")
            self._stop.wait(self.interval_s)

    def start(self) -> None:
        if self._thread is not None and self._thread.is_alive():
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="vtkiosk-watchdog", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=max(5.0, 2 * self.interval_s))
            self._thread = None
