"""`type: hid`: the bridge over USB HID reports via hidapi (`import hid`).

The `hid` module is imported lazily at first use; tests and the demo inject the emulator's look-alike:
`HidTransport(config, hid_api=emulator.hid_api(), clock=emulator.clock)`. Output reports are written with report ID
0 prepended (unnumbered reports, as hidapi requires); input reports are `report_size` bytes.
"""
from __future__ import annotations

import math

from ..config import BridgeConfig
from ..errors import LinkError, NoDeviceError
from .base import Candidate, ReportTransport

UDEV_HINT = "check the udev rule systemd/70-vtkiosk-bridge.rules and that the kiosk user is in group vtkiosk"


class HidTransport(ReportTransport):
    name = "hid"
    pad = True

    def __init__(self, config: BridgeConfig, hid_api=None, clock=None) -> None:
        super().__init__(config, clock)
        self._hid = hid_api
        self._dev = None

    def _api(self):
        if self._hid is None:
            try:
                import hid
            except ImportError as exc:
                raise LinkError(f"hidapi is not installed ({exc}); pip install hidapi") from None
            self._hid = hid
        return self._hid

    def probe(self) -> list[Candidate]:
        c = self.config
        try:
            found = self._api().enumerate(c.vid, c.pid)
        except OSError:
            return []
        out = []
        for d in found:
            serial = d.get("serial_number") or None
            if c.serial is not None and serial != c.serial:
                continue
            path = d.get("path", b"")
            out.append(Candidate("hid", d.get("vendor_id", c.vid), d.get("product_id", c.pid), serial,
                                 path.decode(errors="replace") if isinstance(path, bytes) else str(path),
                                 d.get("product_string") or ""))
        return out

    def open(self) -> None:
        self.close()
        c = self.config
        found = [d for d in self._api().enumerate(c.vid, c.pid)
                 if c.serial is None or (d.get("serial_number") or None) == c.serial]
        if not found:
            raise NoDeviceError(f"no bridge found (looked for VID:PID {c.vid:04x}:{c.pid:04x}"
                                f"{' serial ' + c.serial if c.serial else ''} over hid)")
        dev = self._api().device()
        try:
            dev.open_path(found[0]["path"])
        except OSError as exc:
            raise LinkError(f"cannot open hid bridge {c.vid:04x}:{c.pid:04x} ({exc}); {UDEV_HINT}") from None
        try:
            feat = bytes(dev.get_feature_report(1, 8))
            if len(feat) >= 4 and feat[0] == 1:
                size = feat[2] | feat[3] << 8
                if size != self.report_size:
                    raise LinkError(f"bridge uses {size} B reports but report_size is {self.report_size}; "
                                    f"set report_size: {size}")
            dev.send_feature_report(b"\x02")  # resync the device's reassembly
            dev.set_nonblocking(1)  # read(size, 0) polls; read(size, ms > 0) still waits up to ms
        except (OSError, ValueError) as exc:
            dev.close()
            raise LinkError(f"hid bridge did not answer its feature reports ({exc})") from None
        self._dev = dev
        self._reset_framing()

    @property
    def is_open(self) -> bool:
        return self._dev is not None

    def close(self) -> None:
        dev, self._dev = self._dev, None
        if dev is not None:
            try:
                dev.close()
            except (OSError, ValueError):
                pass

    def _require(self):
        if self._dev is None:
            raise LinkError("hid transport is not open")
        return self._dev

    def _write_report(self, report: bytes) -> None:
        dev = self._require()
        data = b"\x00" + report.ljust(self.report_size, b"\0")
        try:
            n = dev.write(data)
        except (OSError, ValueError) as exc:
            raise LinkError(f"hid write failed ({exc}); bridge unplugged?") from None
        if n is None or n < 0:
            raise LinkError("hid write failed; bridge unplugged?")

    def _read_report(self, timeout_s: float) -> bytes | None:
        dev = self._require()
        ms = math.ceil(timeout_s * 1000) if timeout_s > 0 else 0  # 0: a poll (the device is non-blocking)
        try:
            data = dev.read(self.report_size, ms)
        except (OSError, ValueError) as exc:
            raise LinkError(f"hid read failed ({exc}); bridge unplugged?") from None
        return bytes(data) if data else None
