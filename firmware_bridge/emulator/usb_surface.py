"""A pyusb-shaped surface over the emulated link, so `transports/usb.py` runs unchanged against it.

`EmulatedUsbApi` mirrors what the transport uses of the `usb` package: `core.find(find_all=, idVendor=,
idProduct=, backend=)`, `core.USBError`, `core.USBTimeoutError` and `util.dispose_resources`. Devices offer
`serial_number`, `is_kernel_driver_active`, `detach_kernel_driver`, `set_configuration`, and bulk
`write(endpoint, data, timeout)` / `read(endpoint, size, timeout) -> array('B')`. The exception classes are
pyusb's own when pyusb is installed, so the transport's `except` clauses are exercised for real.
"""
from __future__ import annotations

import errno
from array import array
from types import SimpleNamespace

from .link import DeviceGone

try:  # pyusb is a dependency; fall back to look-alikes so the emulator still imports without it
    from usb.core import USBError, USBTimeoutError
except ImportError:  # pragma: no cover - exercised only where pyusb is absent
    class USBError(IOError):
        def __init__(self, strerror, error_code=None, errno=None):
            super().__init__(errno, strerror)
            self.backend_error_code = error_code

    class USBTimeoutError(USBError):
        pass

EP_OUT = 0x01
EP_IN = 0x81


def _gone() -> USBError:
    return USBError("No such device (it may have been disconnected)", None, errno.ENODEV)


class EmulatedUsbDevice:
    def __init__(self, emulator) -> None:
        self._emu = emulator
        self._gen = emulator.link.generation
        self.idVendor = emulator.vid
        self.idProduct = emulator.pid
        self.bus, self.address = 1, 7
        self.manufacturer = "vtkiosk"
        self.product = "haptic bridge (emulated)"
        self.configured = False
        self.disposed = False

    def _alive(self) -> None:
        try:
            self._emu.link.check(self._gen)
        except DeviceGone:
            raise _gone() from None

    @property
    def serial_number(self) -> str:
        self._alive()
        return self._emu.config.serial

    def is_kernel_driver_active(self, interface: int) -> bool:
        self._alive()
        return False

    def detach_kernel_driver(self, interface: int) -> None:
        self._alive()

    def set_configuration(self, configuration=None) -> None:
        self._alive()
        self.configured = True

    def write(self, endpoint: int, data, timeout: int | None = None) -> int:
        self._alive()
        if not self.configured:
            raise USBError("Resource busy (set_configuration first)", None, errno.EBUSY)
        if endpoint != EP_OUT:
            raise USBError(f"Invalid endpoint 0x{endpoint:02x}", None, errno.EINVAL)
        data = bytes(data)
        try:
            return self._emu.link.write(data, self._gen)
        except DeviceGone:
            raise _gone() from None
        except ValueError:
            raise USBError("Overflow", None, errno.EOVERFLOW) from None

    def read(self, endpoint: int, size_or_buffer, timeout: int | None = None) -> array:
        self._alive()
        if not self.configured:
            raise USBError("Resource busy (set_configuration first)", None, errno.EBUSY)
        if endpoint != EP_IN:
            raise USBError(f"Invalid endpoint 0x{endpoint:02x}", None, errno.EINVAL)
        size = size_or_buffer if isinstance(size_or_buffer, int) else len(size_or_buffer)
        t = 1.0 if timeout is None else (3600.0 if timeout == 0 else timeout / 1000)
        try:
            rep = self._emu.link.read(t, self._gen)
        except DeviceGone:
            raise _gone() from None
        if rep is None:
            raise USBTimeoutError("Operation timed out", None, errno.ETIMEDOUT)
        if len(rep) > size:
            raise USBError("Overflow", None, errno.EOVERFLOW)
        return array("B", rep)


class EmulatedUsbApi:
    """The `usb` package surface the USB transport uses, answering for one emulated controller."""

    def __init__(self, emulator) -> None:
        self._emu = emulator
        self.core = SimpleNamespace(find=self.find, USBError=USBError, USBTimeoutError=USBTimeoutError)
        self.util = SimpleNamespace(dispose_resources=self.dispose_resources)
        self.backend = None

    def find(self, find_all: bool = False, backend=None, idVendor: int | None = None, idProduct: int | None = None,
             **_: object):
        e = self._emu
        match = e.link.plugged and idVendor in (None, e.vid) and idProduct in (None, e.pid)
        devs = [EmulatedUsbDevice(e)] if match else []
        return iter(devs) if find_all else (devs[0] if devs else None)

    @staticmethod
    def dispose_resources(device) -> None:
        device.disposed = True
        device.configured = False
