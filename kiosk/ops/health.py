"""Health checks: is the kiosk doing its job right now? They gate the systemd watchdog and feed `GET /healthz`.

A check is any callable returning `CheckResult(ok, detail)`; it must be cheap and must not block (read state that
the working threads keep, never do the work itself). The daemon registers its checks (inference loop, device link,
server, bundle) on one `HealthMonitor`; `kiosk.ops.notify.Watchdog` pings systemd only while `run()` says all pass, so
a kiosk that stopped doing its job stops pinging and systemd restarts it.

`Heartbeat` is how a working loop proves it is alive and fast enough: it calls `beat()` every iteration, with the
iteration's latency when it did work and without when it only polled. Its check fails when no beat came for
`stale_after_s` (the loop hangs) or the p95 latency of the recent runs (at least `min_samples` of them within
`window_s`) exceeds the budget (the loop is too slow to be useful); a non-finite latency fails at once.
"""
from __future__ import annotations

import math
import os
import threading
import time
import urllib.error
import urllib.request
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

Check = Callable[[], "CheckResult"]
MAX_DETAIL = 160


@dataclass(frozen=True)
class CheckResult:
    ok: bool
    detail: str


def _one_line(text: str, limit: int = MAX_DETAIL) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def percentile(values: list[float], q: float) -> float:
    """Linear-interpolated percentile (numpy's default method) without numpy; q in [0, 100]."""
    s = sorted(values)
    if not s:
        raise ValueError("percentile of no values")
    pos = (len(s) - 1) * q / 100.0
    lo = math.floor(pos)
    hi = min(lo + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (pos - lo)


class Heartbeat:
    """Liveness and latency of one working loop. Thread-safe; `clock` is injectable for tests."""

    def __init__(self, *, window: int = 64, window_s: float = 30.0, min_samples: int = 5,
                 clock: Callable[[], float] = time.monotonic):
        if window < 1 or window_s <= 0 or not 1 <= min_samples <= window:
            raise ValueError("Heartbeat needs window >= 1, window_s > 0 and 1 <= min_samples <= window")
        self._clock = clock
        self._window_s = window_s
        self._min_samples = min_samples
        self._latencies: deque[tuple[float, float]] = deque(maxlen=window)
        self._last: float | None = None
        self._beats = 0
        self._lock = threading.Lock()

    def beat(self, latency_s: float | None = None) -> None:
        now = self._clock()
        with self._lock:
            self._last = now
            self._beats += 1
            if latency_s is not None:
                self._latencies.append((now, float(latency_s)))

    @property
    def beats(self) -> int:
        return self._beats

    def recent_latencies(self) -> list[float]:
        """Latencies recorded within the last `window_s` seconds (at most `window` of them)."""
        now = self._clock()
        with self._lock:
            return [v for t, v in self._latencies if now - t <= self._window_s]

    def check(self, *, stale_after_s: float, budget_s: float) -> CheckResult:
        now = self._clock()
        with self._lock:
            last = self._last
        if last is None:
            return CheckResult(False, "no heartbeat yet")
        age = now - last
        if age > stale_after_s:
            return CheckResult(False, f"no heartbeat for {age:.1f} s (limit {stale_after_s:g} s): loop stalled")
        recent = self.recent_latencies()
        if not recent:
            return CheckResult(True, f"alive (beat {age * 1e3:.0f} ms ago, idle)")
        p95 = percentile(recent, 95)
        if len(recent) < self._min_samples and all(math.isfinite(v) for v in recent):
            # One slow run (the first at a new size, a busy moment) is not a slow kiosk: judge p95 only on enough
            # runs, so a single outlier cannot stop the watchdog pings and get the kiosk restarted.
            return CheckResult(True, f"alive, {len(recent)} recent run(s) (p95 judged from {self._min_samples})")
        if not math.isfinite(p95) or p95 > budget_s:
            return CheckResult(False, f"p95 latency {p95 * 1e3:.0f} ms over budget {budget_s * 1e3:.0f} ms "
                                      f"(last {len(recent)} runs)")
        return CheckResult(True, f"p95 {p95 * 1e3:.0f} ms of {budget_s * 1e3:.0f} ms budget")


@dataclass
class HealthReport:
    ok: bool
    checks: dict[str, CheckResult]
    status_line: str
    checked_at: float = 0.0  # time.time() when the checks ran

    def to_json(self) -> dict[str, Any]:
        """The `GET /healthz` body."""
        return {"ok": self.ok, "status": self.status_line, "checked_at": self.checked_at,
                "checks": {name: {"ok": r.ok, "detail": r.detail} for name, r in self.checks.items()}}


def status_line(checks: Mapping[str, CheckResult]) -> str:
    """One line for systemd's STATUS=: what is wrong first, else what is fine."""
    if not checks:
        return "unhealthy: no health checks configured"
    failed = [f"{n}: {r.detail}" for n, r in checks.items() if not r.ok]
    if failed:
        return _one_line("unhealthy: " + "; ".join(failed), 400)
    return _one_line("healthy: " + "; ".join(f"{n} {r.detail}" for n, r in checks.items()), 400)


class HealthMonitor:
    """Runs the named checks; a check that raises counts as failed with the exception as its detail."""

    def __init__(self, checks: Mapping[str, Check] | None = None):
        self._checks: dict[str, Check] = dict(checks or {})
        self._last: HealthReport | None = None
        self._lock = threading.Lock()

    def add_check(self, name: str, check: Check) -> None:
        if not name or not all(c.isalnum() or c in "_-." for c in name):
            raise ValueError(f"health check name {name!r}: use letters, digits, '_', '-' or '.'")
        with self._lock:
            self._checks[name] = check

    def remove_check(self, name: str) -> None:
        with self._lock:
            self._checks.pop(name, None)

    @property
    def names(self) -> list[str]:
        with self._lock:
            return list(self._checks)

    def run(self) -> HealthReport:
        with self._lock:
            checks = dict(self._checks)
        results: dict[str, CheckResult] = {}
        for name, check in checks.items():
            try:
                r = check()
                if not isinstance(r, CheckResult):
                    r = CheckResult(False, f"check returned {type(r).__name__}, not CheckResult")
            except Exception as exc:  # noqa: BLE001 - a broken check is an unhealthy kiosk, not a dead watchdog
                r = CheckResult(False, f"check raised {type(exc).__name__}: {exc}")
            results[name] = CheckResult(bool(r.ok), _one_line(r.detail))
        ok = bool(results) and all(r.ok for r in results.values())
        report = HealthReport(ok, results, status_line(results), time.time())
        with self._lock:
            self._last = report
        return report

    def last(self) -> HealthReport | None:
        with self._lock:
            return self._last


# -- ready-made checks for the daemon's parts ------------------------------------------------------------------------

def http_check(url: str, *, timeout_s: float = 1.0) -> Check:
    """The server answers `url` with 2xx within timeout_s. Point it at a cheap route, not at /healthz itself."""

    def check() -> CheckResult:
        t0 = time.perf_counter()
        try:
            with urllib.request.urlopen(url, timeout=timeout_s) as resp:  # noqa: S310 - loopback URL from config
                resp.read(1 << 16)
                code = resp.status
        except urllib.error.HTTPError as exc:
            return CheckResult(False, f"{url} answered HTTP {exc.code}")
        except (OSError, ValueError) as exc:
            return CheckResult(False, f"{url} does not answer: {getattr(exc, 'reason', exc)}")
        ms = (time.perf_counter() - t0) * 1e3
        return CheckResult(200 <= code < 300, f"answering ({ms:.0f} ms)" if 200 <= code < 300 else f"HTTP {code}")

    return check


def device_check(health: Callable[[], Any], *, max_heartbeat_age_s: float = 2.0) -> Check:
    """The haptic link is up and its heartbeat fresh. `health` returns firmware_bridge's LinkHealth (or alike:
    `.state`, `.last_heartbeat_age_s`, `.last_error`)."""

    def check() -> CheckResult:
        h = health()
        if h.state != "up":
            why = f" ({h.last_error})" if getattr(h, "last_error", None) else ""
            return CheckResult(False, f"link {h.state}{why}")
        age = h.last_heartbeat_age_s
        if age is not None and age > max_heartbeat_age_s:
            return CheckResult(False, f"link up but last heartbeat {age:.1f} s ago (limit {max_heartbeat_age_s:g} s)")
        return CheckResult(True, "link up" + (f", heartbeat {age * 1e3:.0f} ms ago" if age is not None else ""))

    return check


def storage_check(path: Path, write_error: Callable[[], str | None], *, min_free_bytes: int = 1 << 20) -> Check:
    """A file the kiosk must keep writing (the study log): its last write went through and its file system has at
    least `min_free_bytes` free, so the researcher hears of a filling disk before a record is refused."""

    def check() -> CheckResult:
        err = write_error()
        if err:
            return CheckResult(False, err)
        try:
            st = os.statvfs(Path(path).parent)
        except OSError as exc:
            return CheckResult(False, f"cannot check free space beside {path}: {exc.strerror or exc}")
        free = st.f_bavail * st.f_frsize
        if free < min_free_bytes:
            return CheckResult(False, f"only {free / 2**20:.2f} MiB free for {path} (below "
                                      f"{min_free_bytes / 2**20:g} MiB): free disk space before records are refused")
        return CheckResult(True, f"writable, {free / 2**20:.0f} MiB free")

    return check


def health_metrics(registry) -> Callable[[HealthReport], None]:
    """A `Watchdog(on_report=...)` hook that exports each round as gauges on a kiosk.ops.metrics.Registry:
    vtkiosk_health_ok (1 while all checks pass, i.e. while systemd gets pings) and vtkiosk_health_check_ok{check}."""
    ok = registry.gauge("vtkiosk_health_ok", "1 while every health check passes (systemd gets watchdog pings).")
    per_check = registry.gauge("vtkiosk_health_check_ok", "1 while this health check passes.", labels=("check",))

    def record(report: HealthReport) -> None:
        ok.set(1.0 if report.ok else 0.0)
        for name, result in report.checks.items():
            per_check.set(1.0 if result.ok else 0.0, check=name)

    return record
