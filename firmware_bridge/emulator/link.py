"""The emulated USB link between host and controller: framing, bandwidth model, faults, unplug/replug.

Both device surfaces (hidapi-like, pyusb-like) and the unix-socket server move reports through one `EmulatedLink`.
The controller runs synchronously: a report the host writes is reassembled, handled and its reply queued, with the
delivery time given by the link model. Thread-safe (one lock).

Modelled time (a `VirtualClock`): a report of n bytes occupies its pipe for n / bandwidth seconds, a reply becomes
available one transfer latency after its request arrived (1 ms USB frame at full speed, 125 us microframe at high
speed), and a read with nothing due advances the clock instead of sleeping. HID links are full duplex (separate
interrupt IN and OUT endpoints, each at the stated bandwidth); bulk shares one pipe for both directions.
With a `RealClock` nothing is modelled: replies are due at once, faults delays and stalls use real time.
"""
from __future__ import annotations

import errno
import heapq
import itertools
import threading
from dataclasses import dataclass

from ..config import FaultConfig
from ..framing import Reassembler, split
from .controller import Controller
from .faults import FaultInjector


@dataclass(frozen=True)
class LinkModel:
    """Bandwidth in bytes/s per pipe, latency in seconds per request/reply turnaround."""

    name: str
    bandwidth: float
    latency_s: float
    duplex: bool
    description: str


LINK_MODELS = {
    "fs-hid": LinkModel("fs-hid", 64_000.0, 1e-3, True, "full-speed interrupt HID, 64 B report per 1 ms frame"),
    "hs-hid": LinkModel("hs-hid", 24_576_000.0, 125e-6, True,
                        "high-speed interrupt HID, 3 x 1024 B per 125 us microframe"),
    "hs-bulk": LinkModel("hs-bulk", 35_000_000.0, 125e-6, False, "high-speed bulk, ~35 MB/s practical"),
    "none": LinkModel("none", float("inf"), 0.0, True, "no modelled cost"),
}


class DeviceGone(OSError):
    """The emulated device is unplugged (or the handle predates a replug)."""

    def __init__(self, what: str = "device unplugged") -> None:
        super().__init__(errno.ENODEV, what)


class EmulatedLink:
    def __init__(self, controller: Controller, report_size: int, pad: bool, faults: FaultConfig, clock,
                 model: LinkModel) -> None:
        self.controller = controller
        self.report_size = report_size
        self.pad = pad
        self.clock = clock
        self.model = model
        self.generation = 0
        self.plugged = True
        self._lock = threading.RLock()
        self._order = itertools.count()
        self.set_faults(faults)
        self._reset_queues()
        self.wire_out = self.wire_in = self.reports_out = self.reports_in = 0

    # -- configuration -------------------------------------------------------------------------------------------
    def set_faults(self, faults: FaultConfig) -> None:
        """Change the fault mix (seeded); used by tests to switch faults on and off mid-run."""
        gap = 4 * self.report_size / self.model.bandwidth + 2 * self.model.latency_s \
            if self.clock.virtual and self.model.bandwidth != float("inf") else 0.002
        with getattr(self, "_lock", threading.RLock()):
            self.faults = faults
            self.out_faults = FaultInjector(faults, 0, gap)
            self.in_faults = FaultInjector(faults, 1, gap)

    def _reset_queues(self) -> None:
        self._out: list = []  # heap of (due, order, report) host -> device
        self._in: list = []  # heap of (due, order, report) device -> host
        self._reasm = Reassembler(self.report_size)
        self._out_free = self._in_free = self.clock.now()
        self._stall_start = self._stalled_until = float("-inf")

    # -- plug --------------------------------------------------------------------------------------------------
    def unplug(self) -> None:
        with self._lock:
            self.plugged = False
            self._reset_queues()

    def replug(self) -> None:
        """Plug back in: the controller cold-starts; handles opened before the unplug stay dead."""
        with self._lock:
            self.generation += 1
            self.controller.power_on()
            self._reset_queues()
            self.plugged = True

    def check(self, generation: int | None = None) -> None:
        if not self.plugged:
            raise DeviceGone()
        if generation is not None and generation != self.generation:
            raise DeviceGone("device was replugged; reopen it")

    def reset_reassembly(self) -> None:
        with self._lock:
            self._reasm.reset()

    # -- model ---------------------------------------------------------------------------------------------------
    def _cost(self, n: int) -> float:
        return n / self.model.bandwidth if self.clock.virtual else 0.0

    def _latency(self) -> float:
        return self.model.latency_s if self.clock.virtual else 0.0

    # -- host side -----------------------------------------------------------------------------------------------
    def write(self, report: bytes, generation: int | None = None) -> int:
        """Host writes one report; returns its length. Raises DeviceGone when unplugged."""
        with self._lock:
            self.check(generation)
            if not 0 < len(report) <= self.report_size:
                raise ValueError(f"report of {len(report)} B does not fit the {self.report_size} B report size")
            now = self.clock.now()
            start = max(now, self._out_free)
            end = start + self._cost(len(report))
            self._out_free = end
            if not self.model.duplex:
                self._in_free = max(self._in_free, end)
            self.wire_out += len(report)
            self.reports_out += 1
            if self.clock.virtual and end > now:
                self.clock.advance(end - now)  # a synchronous write returns when its report is on the wire
            if self.out_faults.stall():
                self._stall_start, self._stalled_until = end, end + self.faults.stall_s
            for due, rep in self.out_faults.apply(bytes(report), end):
                heapq.heappush(self._out, (due, next(self._order), rep))
            self._pump()
            return len(report)

    def read(self, timeout_s: float, generation: int | None = None) -> bytes | None:
        """Host reads one report, waiting up to `timeout_s` (modelled or real). None on timeout."""
        deadline = self.clock.now() + max(0.0, timeout_s)
        for _ in range(1_000_000):
            with self._lock:
                self.check(generation)
                self._pump()
                now = self.clock.now()
                if self._in and self._in[0][0] <= now and now >= self._stalled_until:
                    _, _, rep = heapq.heappop(self._in)
                    self.wire_in += len(rep)
                    self.reports_in += 1
                    return rep
                nxt = deadline
                if self._out:
                    nxt = min(nxt, self._out[0][0])
                if self._in:
                    nxt = min(nxt, max(self._in[0][0], self._stalled_until))
            if now >= deadline:
                return None
            wait = max(nxt - now, 0.0)
            if self.clock.virtual:
                self.clock.advance(wait)
            else:
                self.clock.sleep(min(max(wait, 1e-4), 0.002))
        return None

    def _pump(self) -> None:
        """Deliver due host reports to the controller; queue its replies (device side of the link)."""
        now = self.clock.now()
        while self._out and self._out[0][0] <= now:
            due, _, rep = heapq.heappop(self._out)
            if self._stall_start <= due < self._stalled_until:
                continue  # the device is stalled: the report is lost
            msg = self._reasm.feed(rep)
            if msg is None:
                continue
            reply = self.controller.handle(msg)
            if reply is None:
                continue
            for part in split(reply, self.report_size, self.pad):
                start = max(due + self._latency(), self._in_free)
                self._in_free = start + self._cost(len(part))
                for t, r in self.in_faults.apply(part, self._in_free):
                    heapq.heappush(self._in, (t, next(self._order), r))
