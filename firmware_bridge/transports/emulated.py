"""`type: emulated`: the emulated controller, in-process or in a separate process over a unix socket.

In-process (no `socket` in config): builds a `DeviceEmulator` from `config.emulator` (or uses the one passed in)
and moves reports straight through its link. With `socket: PATH`: connects to `vtkiosk device emulate --socket
PATH` and moves the same reports over the socket (u16 length prefix per report). Either way the messages and
reports are exactly those of the hid transport.
"""
from __future__ import annotations

import os
import socket

from ..config import BridgeConfig
from ..emulator import DeviceEmulator, DeviceGone
from ..emulator.server import ReportStream
from ..errors import LinkError, NoDeviceError
from .base import Candidate, ReportTransport


class EmulatedTransport(ReportTransport):
    name = "emulated"
    pad = True

    def __init__(self, config: BridgeConfig, emulator: DeviceEmulator | None = None, clock=None) -> None:
        if emulator is None and config.socket is None:
            emulator = DeviceEmulator(config.emulator, report_size=config.report_size, vid=config.vid,
                                      pid=config.pid, clock=clock)
        super().__init__(config, clock or (emulator.clock if emulator else None))
        self.emulator = emulator
        self._gen: int | None = None
        self._stream: ReportStream | None = None

    def probe(self) -> list[Candidate]:
        if self.emulator is not None:
            e = self.emulator
            return [Candidate("emulated", e.vid, e.pid, e.config.serial, "in-process")] if e.link.plugged else []
        path = self.config.socket
        return [Candidate("emulated", self.config.vid, self.config.pid, None, path)] if os.path.exists(path) else []

    def open(self) -> None:
        self.close()
        if self.emulator is not None:
            if not self.emulator.link.plugged:
                raise NoDeviceError("no bridge found (the emulated device is unplugged)")
            self._gen = self.emulator.link.generation
            self.emulator.link.reset_reassembly()
        else:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                sock.settimeout(self.config.handshake_timeout_s)
                sock.connect(self.config.socket)
            except OSError as exc:
                sock.close()
                raise NoDeviceError(f"no emulated bridge at {self.config.socket} ({exc}); start one with "
                                    f"`vtkiosk device emulate --socket {self.config.socket}`") from None
            self._stream = ReportStream(sock)
        self._reset_framing()

    @property
    def is_open(self) -> bool:
        return self._gen is not None or self._stream is not None

    def close(self) -> None:
        self._gen = None
        stream, self._stream = self._stream, None
        if stream is not None:
            stream.sock.close()

    def _write_report(self, report: bytes) -> None:
        rep = report.ljust(self.report_size, b"\0")
        if self._stream is not None:
            try:
                self._stream.send_report(rep)
            except OSError as exc:
                raise LinkError(f"emulated bridge socket failed ({exc})") from None
            return
        if self._gen is None:
            raise LinkError("emulated transport is not open")
        try:
            self.emulator.link.write(rep, self._gen)
        except DeviceGone as exc:
            raise LinkError(f"emulated bridge gone ({exc.strerror})") from None

    def _read_report(self, timeout_s: float) -> bytes | None:
        if self._stream is not None:
            deadline = self.clock.now() + timeout_s
            for _ in range(10_000):
                rep = self._stream.pop()
                if rep is not None:
                    return rep
                remaining = deadline - self.clock.now()
                if remaining <= 0:
                    return None
                try:
                    alive = self._stream.fill(remaining)
                except OSError as exc:
                    raise LinkError(f"emulated bridge socket failed ({exc})") from None
                if not alive:
                    raise LinkError("emulated bridge closed the socket")
            return None
        if self._gen is None:
            raise LinkError("emulated transport is not open")
        try:
            return self.emulator.link.read(timeout_s, self._gen)
        except DeviceGone as exc:
            raise LinkError(f"emulated bridge gone ({exc.strerror})") from None
