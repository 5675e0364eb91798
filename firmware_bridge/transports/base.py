"""Transport base: move protocol messages over a report-oriented link.

A transport knows how to open a device and write/read one report; `ReportTransport` adds the framing (split on
send, reassemble on receive) and the bounded receive loop, so `hid`, `usb` and `emulated` share everything else.
Timeouts are in seconds on the transport's clock (real, or the emulator's virtual clock).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

from ..clock import RealClock
from ..config import BridgeConfig
from ..framing import Reassembler, split

MAX_REPORTS_PER_RECV = 4096  # bound on garbage a single recv() will chew through


@dataclass(frozen=True)
class Candidate:
    """A device found by `probe()`: enough to print and to open it."""

    transport: str
    vid: int
    pid: int
    serial: str | None
    path: str
    product: str = ""

    def __str__(self) -> str:
        return f"{self.transport} {self.vid:04x}:{self.pid:04x} serial={self.serial or '?'} path={self.path}"


class Transport(ABC):
    """A message pipe to one bridge controller."""

    name = "base"
    pad = True

    def __init__(self, config: BridgeConfig, clock=None) -> None:
        self.config = config
        self.clock = clock or RealClock()
        self.report_size = config.report_size

    @abstractmethod
    def probe(self) -> list[Candidate]:
        """Devices this transport could open with the current config (no side effects)."""

    @abstractmethod
    def open(self) -> None:
        """Open the configured device; raises NoDeviceError or LinkError."""

    @abstractmethod
    def close(self) -> None:
        """Release the device; safe to call twice."""

    @property
    @abstractmethod
    def is_open(self) -> bool: ...

    @abstractmethod
    def send(self, message: bytes) -> None:
        """Send one encoded message; raises LinkError on I/O failure."""

    @abstractmethod
    def recv(self, timeout_s: float) -> bytes | None:
        """One complete message within timeout_s, or None. Raises LinkError on I/O failure."""


class ReportTransport(Transport):
    """Framing and the receive loop over `_write_report` / `_read_report`."""

    def __init__(self, config: BridgeConfig, clock=None) -> None:
        super().__init__(config, clock)
        self._reasm = Reassembler(self.report_size)
        self.reports_out = self.reports_in = self.bytes_out = self.bytes_in = 0

    @property
    def resyncs(self) -> int:
        return self._reasm.resyncs

    @abstractmethod
    def _write_report(self, report: bytes) -> None: ...

    @abstractmethod
    def _read_report(self, timeout_s: float) -> bytes | None: ...

    def send(self, message: bytes) -> None:
        for rep in split(message, self.report_size, self.pad):
            self._write_report(rep)
            self.reports_out += 1
            self.bytes_out += len(rep)

    def recv(self, timeout_s: float) -> bytes | None:
        deadline = self.clock.now() + max(0.0, timeout_s)
        for _ in range(MAX_REPORTS_PER_RECV):
            remaining = deadline - self.clock.now()
            rep = self._read_report(max(0.0, remaining))
            if rep is None:
                return None
            self.reports_in += 1
            self.bytes_in += len(rep)
            msg = self._reasm.feed(rep)
            if msg is not None:
                return msg
            if remaining <= 0:
                return None
        return None

    def _reset_framing(self) -> None:
        self._reasm = Reassembler(self.report_size)
