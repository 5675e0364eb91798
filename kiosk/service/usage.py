"""Anonymous usage figures of the shopper's page, counted into the daemon's `/metrics` registry.

The page reports a handful of events (`POST /api/usage`, one small JSON object each); the daemon only counts them.
An event carries no coordinates, strokes, client id or time of day, and the parser refuses any other field, so no
drawing and nothing personal can leave the kiosk through this path: what Prometheus scrapes is sums.

Events::

    {"event": "session"}                       a shopper woke the kiosk from its attract screen
    {"event": "touch", "mode": "draw"|"feel"}  a finger (or pen) went down on the garment canvas
    {"event": "felt", "seconds": 12.5}         first touch of the session -> first touch on a garment in Feel mode
    {"event": "idle_reset"}                    the page went idle: drawing cleared, attract screen back
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from kiosk.contract.errors import InputError
from kiosk.ops.metrics import Registry

EVENTS = ("session", "touch", "felt", "idle_reset")
MODES = ("draw", "feel")
MAX_FELT_S = 86400.0
# A shopper finds the fabric in seconds or never; the upper buckets tell a confusing page from a busy store.
FELT_BUCKETS = (1.0, 2.0, 3.0, 5.0, 8.0, 13.0, 20.0, 30.0, 45.0, 60.0, 90.0, 120.0, 300.0, 600.0)


@dataclass(frozen=True)
class UsageEvent:
    event: str
    mode: str | None = None
    seconds: float | None = None


def parse_usage_event(doc: Any) -> UsageEvent:
    """Validate one page event; InputError names the first problem."""
    if not isinstance(doc, dict):
        raise InputError("a usage event must be a JSON object")
    event = doc.get("event")
    if event not in EVENTS:
        raise InputError(f"usage event must be one of {', '.join(EVENTS)}; got {event!r:.40}")
    allowed = {"event"} | ({"mode"} if event == "touch" else {"seconds"} if event == "felt" else set())
    extra = sorted(str(k) for k in doc if k not in allowed)
    if extra:
        raise InputError(f"usage event {event!r} takes no field(s) {', '.join(extra)[:80]}")
    if event == "touch":
        mode = doc.get("mode")
        if mode not in MODES:
            raise InputError(f"touch mode must be one of {', '.join(MODES)}; got {mode!r:.40}")
        return UsageEvent(event, mode=mode)
    if event == "felt":
        s = doc.get("seconds")
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not math.isfinite(s) \
                or not 0.0 <= s <= MAX_FELT_S:
            raise InputError(f"felt seconds must be a number from 0 to {MAX_FELT_S:g}; got {s!r:.40}")
        return UsageEvent(event, seconds=float(s))
    return UsageEvent(event)


class UsageMetrics:
    """The page's figures in a metrics `Registry` (the daemon's own, so one scrape has everything)."""

    def __init__(self, registry: Registry):
        self.sessions = registry.counter("vtkiosk_sessions_total",
                                         "Shopper sessions (the attract screen left by a touch).")
        self.touches = registry.counter("vtkiosk_touches_total", "Touches on the garment canvas by page mode.",
                                        labels=("mode",))
        self.felt = registry.histogram("vtkiosk_first_feel_seconds",
                                       "Per session: first touch -> first touch on a garment in Feel mode.",
                                       buckets=FELT_BUCKETS)
        self.idle_resets = registry.counter("vtkiosk_idle_resets_total",
                                            "Idle resets (drawing cleared, attract screen shown).")
        for mode in MODES:  # both series exist from the start, so a rate over "feel" is never an absent series
            self.touches.inc(0, mode=mode)

    def record(self, ev: UsageEvent) -> None:
        if ev.event == "session":
            self.sessions.inc()
        elif ev.event == "touch":
            self.touches.inc(mode=ev.mode)
        elif ev.event == "felt":
            assert ev.seconds is not None
            self.felt.observe(ev.seconds)
        else:
            self.idle_resets.inc()
