"""A hidapi-shaped surface over the emulated link, so `transports/hid.py` runs unchanged against it.

`EmulatedHidApi` mirrors the `hid` module (`enumerate`, `device`); `EmulatedHidDevice` mirrors `hid.device`:
open/open_path/write/read(max_length, timeout_ms)/get_feature_report/send_feature_report/close and the string
getters. Errors mirror cython-hidapi: OSError for I/O failures and failed opens, ValueError when not open.
Writes carry the report ID in byte 0 (0: the bridge uses unnumbered reports), reads return a list of ints.

Feature reports (also implemented by the firmware, see docs/bridge-protocol.md):
  id 1 (get): [1, protocol_version, report_size lo, report_size hi]
  id 2 (send): [2] resets the device-side reassembly (resync after a host restart)
"""
from __future__ import annotations

from .. import protocol as P
from .link import DeviceGone

PATH = b"emulated:bridge:0"


class EmulatedHidApi:
    """The `hid` module's discovery surface, answering for one emulated controller."""

    def __init__(self, emulator) -> None:
        self._emu = emulator

    def enumerate(self, vendor_id: int = 0, product_id: int = 0) -> list[dict]:
        e = self._emu
        if not e.link.plugged or (vendor_id and vendor_id != e.vid) or (product_id and product_id != e.pid):
            return []
        return [{
            "path": PATH, "vendor_id": e.vid, "product_id": e.pid, "serial_number": e.config.serial,
            "release_number": 0x0100, "manufacturer_string": "vtkiosk", "product_string": "haptic bridge (emulated)",
            "usage_page": 0xFF00, "usage": 0x01, "interface_number": 0,
        }]

    def device(self) -> "EmulatedHidDevice":
        return EmulatedHidDevice(self._emu)


class EmulatedHidDevice:
    def __init__(self, emulator) -> None:
        self._emu = emulator
        self._gen: int | None = None
        self.nonblocking = False

    # -- open / close --------------------------------------------------------------------------------------------
    def open(self, vendor_id: int = 0, product_id: int = 0, serial_number: str | None = None) -> None:
        e = self._emu
        if not e.link.plugged or vendor_id != e.vid or product_id != e.pid \
                or (serial_number is not None and serial_number != e.config.serial):
            raise OSError("open failed")
        self._gen = e.link.generation

    def open_path(self, path: bytes) -> None:
        if path != PATH or not self._emu.link.plugged:
            raise OSError("open failed")
        self._gen = self._emu.link.generation

    def close(self) -> None:
        self._gen = None

    def _check(self) -> None:
        if self._gen is None:
            raise ValueError("not open")

    def set_nonblocking(self, v: int | bool) -> int:
        self._check()
        self.nonblocking = bool(v)
        return 0

    # -- reports -------------------------------------------------------------------------------------------------
    def write(self, buff) -> int:
        self._check()
        data = bytes(buff)
        if not data:
            raise OSError("write error")
        report = data[1:]
        size = self._emu.link.report_size
        if len(report) > size:
            raise OSError("write error")
        try:
            self._emu.link.write(report.ljust(size, b"\0"), self._gen)
        except DeviceGone:
            raise OSError("write error") from None
        return len(data)

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        self._check()
        # cython-hidapi: timeout_ms > 0 -> hid_read_timeout; otherwise hid_read, which blocks unless nonblocking
        timeout = timeout_ms / 1000 if timeout_ms > 0 else 0.0 if self.nonblocking else 3600.0
        try:
            rep = self._emu.link.read(timeout, self._gen)
        except DeviceGone:
            raise OSError("read error") from None
        return list(rep[:max_length]) if rep else []

    def get_feature_report(self, report_id: int, max_length: int) -> list[int]:
        self._check()
        self._alive()
        if report_id != 1:
            raise OSError("get_feature_report failed")
        size = self._emu.link.report_size
        return [1, P.VERSION, size & 0xFF, size >> 8][:max_length]

    def send_feature_report(self, data) -> int:
        self._check()
        self._alive()
        data = bytes(data)
        if data[:1] != b"\x02":
            raise OSError("send_feature_report failed")
        self._emu.link.reset_reassembly()
        return len(data)

    def _alive(self) -> None:
        try:
            self._emu.link.check(self._gen)
        except DeviceGone:
            raise OSError("device disconnected") from None

    def get_serial_number_string(self) -> str:
        self._check()
        return self._emu.config.serial

    def get_manufacturer_string(self) -> str:
        self._check()
        return "vtkiosk"

    def get_product_string(self) -> str:
        self._check()
        return "haptic bridge (emulated)"

    def error(self) -> str:
        return "" if self._emu.link.plugged else "device disconnected"
