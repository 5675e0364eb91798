"""Fixtures: a HapticDisplay wired to a DeviceEmulator through a chosen transport, in modelled time."""
from __future__ import annotations

import pytest

from firmware_bridge.config import BridgeConfig, EmulatorConfig, FaultConfig
from firmware_bridge.display import HapticDisplay
from firmware_bridge.emulator import DeviceEmulator
from firmware_bridge.transports.emulated import EmulatedTransport
from firmware_bridge.transports.hid import HidTransport
from firmware_bridge.transports.usb import UsbTransport


def build(transport: str = "hid", link: str = "hs-hid", report_size: int = 1024, faults: FaultConfig | None = None,
          modelled: bool = True, panel: tuple[int, int] = (1280, 800), tile: int = 64, **cfg):
    """(display, emulator): the transport's code runs unchanged against the emulator's device surface."""
    pad = transport != "usb"
    ecfg = EmulatorConfig(panel_w=panel[0], panel_h=panel[1], tile_w=tile, tile_h=tile, link=link,
                          modelled_time=modelled, faults=faults or FaultConfig())
    emu = DeviceEmulator(ecfg, report_size=report_size, pad=pad)
    config = BridgeConfig(type=transport, report_size=report_size, background=cfg.pop("background", False), **cfg)
    if transport == "hid":
        tr = HidTransport(config, hid_api=emu.hid_api(), clock=emu.clock)
    elif transport == "usb":
        tr = UsbTransport(config, usb_api=emu.usb_api(), clock=emu.clock)
    else:
        tr = EmulatedTransport(config, emulator=emu)
    return HapticDisplay(config, transport=tr), emu


@pytest.fixture
def rig():
    made = []

    def _make(**kw):
        disp, emu = build(**kw)
        made.append(disp)
        return disp, emu

    yield _make
    for d in made:
        d.close()
