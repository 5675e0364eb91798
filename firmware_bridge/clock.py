"""Clocks: real time for hardware and the demo, a virtual clock for modelled-time links.

A `VirtualClock` never sleeps: `sleep(dt)` advances it by `dt` seconds. The emulated link advances it by
`bytes / bandwidth + latency`, so a test of 1000 frames with retransmit timeouts runs in CPU time only, and the
bench can report modelled link time beside measured host CPU time. Units: seconds (float).
"""
from __future__ import annotations

import threading
import time


class RealClock:
    """Monotonic wall clock; `sleep` really sleeps."""

    virtual = False

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, dt: float) -> None:
        if dt > 0:
            time.sleep(dt)


class VirtualClock:
    """Modelled time in seconds, starting at 0; `sleep(dt)` and `advance(dt)` move it forward instantly."""

    virtual = True

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)
        self._lock = threading.Lock()

    def now(self) -> float:
        with self._lock:
            return self._t

    def advance(self, dt: float) -> None:
        if dt < 0:
            raise ValueError(f"a clock cannot go backwards (dt={dt})")
        with self._lock:
            self._t += dt

    def sleep(self, dt: float) -> None:
        if dt > 0:
            self.advance(dt)
