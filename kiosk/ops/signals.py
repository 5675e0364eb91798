"""The one way a long-running command hears SIGTERM, SIGINT or SIGHUP: the handler only records the signal.

A handler runs between two bytecodes of the main thread, whatever that thread holds at the time. One that takes a
lock (`threading.Event.set`, logging, a queue) can deadlock against the main thread holding the same lock, and the
stop would then never start. So the handler appends the signal number to a list (atomic under the GIL, no lock),
and the command's main loop polls `stop` or `take(...)` and does the stopping itself, on its own thread.

    with on_signals() as signals:
        while not signals.stop:
            do_some_work()
            signals.wait(1.0)              # returns early when a signal arrives

firmware_bridge imports nothing of ours, so it carries a byte-identical copy of this file
(`firmware_bridge/signals.py`); a test keeps the two the same.
"""
from __future__ import annotations

import contextlib
import signal
import time
from collections.abc import Iterable, Iterator

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)
_POLL_S = 0.05


class Signals:
    """Signals received since `on_signals` installed the handlers, in order of arrival."""

    def __init__(self, stop_signals: Iterable[int] = STOP_SIGNALS) -> None:
        self.received: list[int] = []
        self._stop_signals = frozenset(stop_signals)
        self._taken: dict[int, int] = {}

    def handler(self, signum: int, _frame: object) -> None:
        self.received.append(signum)

    @property
    def stop(self) -> bool:
        """True once a stop signal (SIGTERM, SIGINT) has arrived."""
        return any(s in self._stop_signals for s in self.received)

    @property
    def stop_signal(self) -> int | None:
        """The first stop signal that arrived, or None."""
        return next((s for s in self.received if s in self._stop_signals), None)

    def take(self, signum: int) -> bool:
        """True if `signum` arrived since the last `take(signum)` (a request such as SIGHUP: reload)."""
        count = self.received.count(signum)
        if count > self._taken.get(signum, 0):
            self._taken[signum] = count
            return True
        return False

    def wait(self, timeout_s: float) -> None:
        """Sleep up to `timeout_s`, returning as soon as any signal arrives."""
        seen = len(self.received)
        end = time.monotonic() + timeout_s
        while len(self.received) == seen:
            left = end - time.monotonic()
            if left <= 0:
                return
            time.sleep(min(left, _POLL_S))


@contextlib.contextmanager
def on_signals(*also: int, stop_signals: Iterable[int] = STOP_SIGNALS) -> Iterator[Signals]:
    """Record `stop_signals` and `also` (e.g. SIGHUP) while the block runs; the previous handlers come back after.
    Must run on the main thread (Python delivers signals only there)."""
    signals = Signals(stop_signals)
    wanted = tuple(dict.fromkeys((*signals._stop_signals, *also)))
    previous = {s: signal.getsignal(s) for s in wanted}
    for s in wanted:
        signal.signal(s, signals.handler)
    try:
        yield signals
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
