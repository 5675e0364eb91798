"""Device emulator: the bridge controller's side of protocol v1 behind hidapi- and pyusb-shaped surfaces.

    emu = DeviceEmulator(EmulatorConfig(modelled_time=True, link="hs-hid"), report_size=1024)
    transport = HidTransport(config, hid_api=emu.hid_api(), clock=emu.clock)

`emu.active_frame` is the committed frame, `emu.felt()` what a finger feels, `emu.committed` the log of every
frame that became active, `emu.unplug()` / `emu.replug()` simulate the cable, `emu.set_faults()` the line noise.
"""
from __future__ import annotations

import numpy as np

from ..clock import RealClock, VirtualClock
from ..config import DEFAULT_PID, DEFAULT_VID, EmulatorConfig, FaultConfig
from .controller import Controller
from .hid_surface import EmulatedHidApi
from .link import LINK_MODELS, DeviceGone, EmulatedLink, LinkModel
from .usb_surface import EmulatedUsbApi

__all__ = ["DeviceEmulator", "DeviceGone", "LINK_MODELS", "LinkModel"]


class DeviceEmulator:
    def __init__(self, config: EmulatorConfig | None = None, *, report_size: int = 64, pad: bool = True,
                 clock=None, vid: int = DEFAULT_VID, pid: int = DEFAULT_PID) -> None:
        self.config = config or EmulatorConfig()
        if self.config.link not in LINK_MODELS:
            raise ValueError(f"emulator link must be one of {sorted(LINK_MODELS)}, got {self.config.link!r}")
        self.clock = clock or (VirtualClock() if self.config.modelled_time else RealClock())
        self.vid, self.pid = vid, pid
        self.controller = Controller(self.config, self.clock, report_size)
        self.link = EmulatedLink(self.controller, report_size, pad, self.config.faults, self.clock,
                                 LINK_MODELS[self.config.link])

    def hid_api(self) -> EmulatedHidApi:
        """An object shaped like the `hid` module (enumerate, device) for HidTransport(hid_api=...)."""
        return EmulatedHidApi(self)

    def usb_api(self) -> EmulatedUsbApi:
        """An object shaped like the `usb` package (core.find, util.dispose_resources) for UsbTransport."""
        return EmulatedUsbApi(self)

    def unplug(self) -> None:
        self.link.unplug()

    def replug(self) -> None:
        self.link.replug()

    def set_faults(self, faults: FaultConfig) -> None:
        self.link.set_faults(faults)

    @property
    def active_frame(self) -> np.ndarray:
        return self.controller.active.copy()

    @property
    def committed(self) -> list[tuple[int, int]]:
        return list(self.controller.committed)

    def felt(self) -> np.ndarray:
        return self.controller.felt()

    def fault_counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for prefix, inj in (("out", self.link.out_faults), ("in", self.link.in_faults)):
            for k, v in inj.counts.items():
                out[f"{prefix}.{k}"] = v
        return out
