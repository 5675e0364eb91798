"""`type: usb`: the bridge over USB bulk endpoints via pyusb with the libusb-1.0 backend from `libusb-package`.

pyusb is imported lazily; tests inject the emulator's look-alike: `UsbTransport(config, usb_api=emu.usb_api(),
clock=emu.clock)`. Endpoints come from config (`ep_out`, `ep_in`, default 0x01 / 0x81). Bulk packets are not
padded: a report is at most `report_size` bytes. A read timeout is not an error (returns None); any other
USBError (ENODEV on unplug) is a LinkError.
"""
from __future__ import annotations

from types import SimpleNamespace

from ..config import BridgeConfig
from ..errors import LinkError, NoDeviceError
from .base import Candidate, ReportTransport
from .hid import UDEV_HINT


class UsbTransport(ReportTransport):
    name = "usb"
    pad = False

    def __init__(self, config: BridgeConfig, usb_api=None, clock=None) -> None:
        super().__init__(config, clock)
        self._usb = usb_api
        self._dev = None

    def _api(self):
        if self._usb is None:
            try:
                import libusb_package
                import usb.core
                import usb.util
            except ImportError as exc:
                raise LinkError(f"pyusb/libusb-package not installed ({exc}); pip install pyusb libusb-package") \
                    from None
            self._usb = SimpleNamespace(core=usb.core, util=usb.util, backend=libusb_package.get_libusb1_backend())
        return self._usb

    def _find(self) -> list:
        api, c = self._api(), self.config
        try:
            devs = list(api.core.find(find_all=True, idVendor=c.vid, idProduct=c.pid, backend=api.backend) or [])
        except (api.core.USBError, ValueError, OSError):
            return []
        except Exception as exc:  # noqa: BLE001 - pyusb raises NoBackendError (a plain ValueError subclass) and more
            if type(exc).__name__ == "NoBackendError":
                return []
            raise
        if c.serial is None:
            return devs
        out = []
        for d in devs:
            try:
                if d.serial_number == c.serial:
                    out.append(d)
            except (api.core.USBError, ValueError):
                continue  # no permission to read the string descriptor: cannot be ours to use anyway
        return out

    def probe(self) -> list[Candidate]:
        out = []
        for d in self._find():
            try:
                serial = d.serial_number
            except (self._api().core.USBError, ValueError):
                serial = None
            out.append(Candidate("usb", d.idVendor, d.idProduct, serial,
                                 f"bus {getattr(d, 'bus', '?')} address {getattr(d, 'address', '?')}"))
        return out

    def open(self) -> None:
        self.close()
        c, api = self.config, self._api()
        devs = self._find()
        if not devs:
            raise NoDeviceError(f"no bridge found (looked for VID:PID {c.vid:04x}:{c.pid:04x}"
                                f"{' serial ' + c.serial if c.serial else ''} over usb)")
        dev = devs[0]
        try:
            try:
                attached = dev.is_kernel_driver_active(c.interface)
            except api.core.USBError:
                raise
            except Exception:  # noqa: BLE001 - backends without kernel drivers (macOS, Windows) cannot tell
                attached = False
            if attached:
                dev.detach_kernel_driver(c.interface)
            dev.set_configuration()
        except api.core.USBError as exc:
            raise LinkError(f"cannot claim usb bridge {c.vid:04x}:{c.pid:04x} ({exc}); {UDEV_HINT}") from None
        self._dev = dev
        self._reset_framing()

    @property
    def is_open(self) -> bool:
        return self._dev is not None

    def close(self) -> None:
        dev, self._dev = self._dev, None
        if dev is not None:
            try:
                self._api().util.dispose_resources(dev)
            except Exception:  # noqa: BLE001 - releasing a vanished device must never fail the caller
                pass

    def _require(self):
        if self._dev is None:
            raise LinkError("usb transport is not open")
        return self._dev

    def _write_report(self, report: bytes) -> None:
        dev, core = self._require(), self._api().core
        ms = max(1, int(self.config.ack_timeout_s * 1000))
        try:
            dev.write(self.config.ep_out, report, ms)
        except core.USBTimeoutError:
            return  # the endpoint stalled: the report is lost, ack/retry recovers it
        except core.USBError as exc:
            raise LinkError(f"usb write failed ({exc}); bridge unplugged?") from None

    def _read_report(self, timeout_s: float) -> bytes | None:
        dev, core = self._require(), self._api().core
        ms = max(1, int(round(timeout_s * 1000)))  # 0 would mean "no timeout" to pyusb
        try:
            data = dev.read(self.config.ep_in, self.report_size, ms)
        except core.USBTimeoutError:
            return None
        except core.USBError as exc:
            raise LinkError(f"usb read failed ({exc}); bridge unplugged?") from None
        return bytes(data) if len(data) else None
