"""The hid and usb transports run unchanged against the emulator's device surfaces; the socket emulator process."""
from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from firmware_bridge.config import BridgeConfig, EmulatorConfig
from firmware_bridge.display import HapticDisplay
from firmware_bridge.emulator import DeviceEmulator
from firmware_bridge.errors import ConfigError, LinkError, NoDeviceError
from firmware_bridge.transports import create_transport, register_transport, transport_class
from firmware_bridge.transports.hid import HidTransport
from firmware_bridge.transports.usb import UsbTransport

from .conftest import build


@pytest.mark.parametrize("kind, link, report_size", [
    ("hid", "fs-hid", 64), ("hid", "hs-hid", 1024), ("usb", "hs-bulk", 1024), ("usb", "hs-bulk", 512),
    ("emulated", "hs-hid", 1024),
])
def test_each_transport_uploads_bit_exact(kind, link, report_size):
    disp, emu = build(transport=kind, link=link, report_size=report_size, panel=(320, 200), tile=64)
    info = disp.open()
    assert info.transport == kind
    frame = np.random.default_rng(1).integers(0, 256, (200, 320), dtype=np.uint8)
    disp.present(frame)
    frame[0:5, 0:5] = 0
    disp.present(frame)
    assert np.array_equal(emu.active_frame, frame)
    assert disp.transport.bytes_out > 0 and disp.transport.reports_in > 0
    disp.close()


def test_hid_transport_uses_the_hidapi_surface_faithfully():
    emu = DeviceEmulator(EmulatorConfig(modelled_time=True), report_size=64)
    cfg = BridgeConfig(type="hid", report_size=64)
    tr = HidTransport(cfg, hid_api=emu.hid_api(), clock=emu.clock)
    assert [c.serial for c in tr.probe()] == ["EMU-0001"]
    assert tr.probe()[0].path == "emulated:bridge:0"
    assert HidTransport(cfg.replace(serial="other"), hid_api=emu.hid_api()).probe() == []
    with pytest.raises(NoDeviceError, match="1209:0001 serial other over hid"):
        HidTransport(cfg.replace(serial="other"), hid_api=emu.hid_api(), clock=emu.clock).open()
    with pytest.raises(LinkError, match="report_size: 64"):
        HidTransport(cfg.replace(report_size=1024), hid_api=emu.hid_api(), clock=emu.clock).open()
    tr.open()
    assert tr.is_open
    emu.unplug()
    with pytest.raises(LinkError, match="unplugged"):
        tr.send(b"\x01" * 10)
    emu.replug()
    with pytest.raises(LinkError):  # a handle from before the replug is dead, like a stale hidraw fd
        tr.recv(0.01)
    tr.open()
    tr.send(b"\x01" * 10)
    tr.close()
    tr.close()


def test_usb_transport_uses_the_pyusb_surface_faithfully():
    import usb.core

    emu = DeviceEmulator(EmulatorConfig(modelled_time=True, link="hs-bulk"), report_size=512, pad=False)
    api = emu.usb_api()
    assert api.core.USBTimeoutError is usb.core.USBTimeoutError
    cfg = BridgeConfig(type="usb", report_size=512)
    tr = UsbTransport(cfg, usb_api=api, clock=emu.clock)
    assert tr.probe()[0].serial == "EMU-0001"
    tr.open()
    assert tr.recv(0.01) is None  # a read timeout is not an error
    emu.unplug()
    with pytest.raises(LinkError, match="unplugged"):
        tr.recv(0.01)
    tr.close()
    with pytest.raises(NoDeviceError, match="over usb"):
        tr.open()
    dev = EmulatedDeviceProbe(emu)
    with pytest.raises(usb.core.USBError):
        dev.serial_number


def EmulatedDeviceProbe(emu):  # noqa: N802 - a device object made before a replug
    from firmware_bridge.emulator.usb_surface import EmulatedUsbDevice

    d = EmulatedUsbDevice(emu)
    emu.replug()
    return d


def test_real_backends_find_no_hardware_here_cleanly():
    """No bridge is plugged into CI: real hidapi/pyusb discovery must say so, not crash."""
    cfg = BridgeConfig(type="hid", vid=0x1209, pid=0x0001)
    assert HidTransport(cfg).probe() == []
    with pytest.raises(NoDeviceError, match=r"no bridge found \(looked for VID:PID 1209:0001"):
        HidTransport(cfg).open()
    assert UsbTransport(cfg.replace(type="usb")).probe() == []


def test_registry_is_keyed_by_config_type():
    assert transport_class("hid") is HidTransport
    assert isinstance(create_transport(BridgeConfig(type="usb")), UsbTransport)
    with pytest.raises(ConfigError, match="unknown transport type"):
        transport_class("tanvas")
    register_transport("loopback", "firmware_bridge.transports.emulated:EmulatedTransport")
    try:
        cfg = BridgeConfig(type="loopback")
        assert create_transport(cfg).name == "emulated"
    finally:
        from firmware_bridge.transports import TRANSPORTS
        TRANSPORTS.pop("loopback")
    with pytest.raises(ConfigError, match="module:Class"):
        register_transport("x", "nocolon")


@pytest.mark.timeout(30)
def test_the_emulators_socket_appears_only_once_it_listens(tmp_path, monkeypatch):
    """A client waits for the socket file and then connects; bind() creates the file before listen(), so the server
    binds a temporary name and renames it when listening (a loaded CI machine once hit that window)."""
    import socket

    from firmware_bridge.emulator.server import EmulatorServer
    path = tmp_path / "bridge.sock"
    seen = []
    real_listen = socket.socket.listen

    def listen(self, *a):
        seen.append(path.exists())
        return real_listen(self, *a)

    monkeypatch.setattr(socket.socket, "listen", listen)
    server = EmulatorServer(DeviceEmulator(EmulatorConfig(panel_w=64, panel_h=32, tile_w=32, tile_h=32)), path)
    server.start()
    try:
        assert seen == [False] and path.exists()
        assert sorted(p.name for p in tmp_path.iterdir()) == ["bridge.sock"]   # no temporary name left behind
        c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        c.connect(str(path))
        c.close()
    finally:
        server._sock.close()


def test_emulator_as_a_separate_process_over_a_unix_socket(tmp_path):
    sock = str(tmp_path / "bridge.sock")
    proc = subprocess.Popen([sys.executable, "-m", "firmware_bridge.cli", "emulate", "--socket", sock,
                             "--panel", "256x128", "--tile", "32", "--duration", "20"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for _ in range(200):
            if os.path.exists(sock):
                break
            time.sleep(0.05)
        assert os.path.exists(sock), proc.stderr.read() if proc.poll() is not None else "no socket"
        cfg = BridgeConfig(type="emulated", socket=sock, report_size=64, background=True,
                           heartbeat_interval_s=0.05)
        with HapticDisplay(cfg) as disp:
            assert (disp.info.panel_w, disp.info.panel_h) == (256, 128)
            frame = np.random.default_rng(2).integers(0, 256, (128, 256), dtype=np.uint8)
            r = disp.present(frame)
            assert r.tiles_sent == 32
            time.sleep(0.2)
            st = disp.heartbeat()
            assert st.active_id == r.frame_id and st.active_crc == __import__("zlib").crc32(frame.tobytes())
            assert disp.health().state == "up"
    finally:
        proc.terminate()
        out, err = proc.communicate(timeout=10)
    assert "listening on" in out and "1 frames committed" in out, err
