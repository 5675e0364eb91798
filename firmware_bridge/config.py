"""Typed bridge configuration, loadable from a YAML mapping.

Example (the `bridge:` block of a kiosk config)::

    type: hid              # hid | usb | emulated (the transport plugin, see transports/)
    vid: 0x1209            # placeholder pid.codes VID/PID for our bridge controller; set yours
    pid: 0x0001
    serial: null           # pick one controller when several are plugged in
    report_size: 64        # 64 = full-speed HID; 1024 = high-speed HID or bulk
    ack_timeout_s: 0.05
    max_retries: 5

Units: seconds for every *_s field, bytes for sizes. Unknown keys and wrong types are errors that name the key
(the project's one loader, carried here as `config_loader` because this package imports nothing of ours).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import config_loader
from .errors import ConfigError

DEFAULT_VID = 0x1209  # pid.codes open-source VID: a placeholder until the bridge controller has its own
DEFAULT_PID = 0x0001  # pid.codes test PID: placeholder, configurable


def _usb_number(value: Any) -> int:
    """USB ids and endpoint addresses are written in hex in every datasheet, so '0x1209' is accepted too."""
    if isinstance(value, str):
        try:
            return int(value, 0)
        except ValueError:
            raise ValueError(f"must be an int or a hex string like '0x1209', got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"must be an int or a hex string like '0x1209', got {value!r}")
    return value


_HEX = {"parse": _usb_number}


@dataclass(frozen=True)
class FaultConfig:
    """Per-report fault probabilities of the emulated link (each direction), seeded by `seed`.

    delay_s: a delayed report arrives this many seconds late; stall_s: a stall makes the device deaf and mute
    for this long. All probabilities in [0, 1].
    """

    seed: int = 0
    drop: float = 0.0
    corrupt: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    delay: float = 0.0
    delay_s: float = 0.02
    stall: float = 0.0
    stall_s: float = 0.05

    def __post_init__(self) -> None:
        for name in ("drop", "corrupt", "duplicate", "reorder", "delay", "stall"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ConfigError(f"faults.{name} is a probability in [0, 1], got {v}")
        for name in ("delay_s", "stall_s"):
            if getattr(self, name) < 0:
                raise ConfigError(f"faults.{name} must be >= 0 seconds, got {getattr(self, name)}")

    @property
    def any(self) -> bool:
        return any(getattr(self, n) > 0 for n in ("drop", "corrupt", "duplicate", "reorder", "delay", "stall"))


@dataclass(frozen=True)
class EmulatorConfig:
    """The emulated controller: panel and tile size in pixels, identity, link model and faults.

    link: 'fs-hid' (64 KB/s, 1 ms frames), 'hs-hid' (~24 MB/s, 125 us microframes), 'hs-bulk' (~35 MB/s) or
    'none' (no modelled cost). modelled_time: use a virtual clock (tests, bench) instead of real time.
    host_timeout_s: the device blanks itself (watchdog) when no host message arrives for this long.
    """

    panel_w: int = 1280
    panel_h: int = 800
    tile_w: int = 64
    tile_h: int = 64
    serial: str = "EMU-0001"
    firmware: str = "1.0.0"
    link: str = "hs-hid"
    modelled_time: bool = False
    host_timeout_s: float = 1.0
    faults: FaultConfig = field(default_factory=FaultConfig)

    def __post_init__(self) -> None:
        for name in ("panel_w", "panel_h", "tile_w", "tile_h"):
            v = getattr(self, name)
            if not 0 < v <= 65535:
                raise ConfigError(f"emulator.{name} must be in [1, 65535] pixels, got {v}")
        if self.tile_w * self.tile_h > 16000:
            raise ConfigError(f"emulator tile {self.tile_w}x{self.tile_h} too big for one message (<= 16000 px)")
        parts = self.firmware.split(".")
        if len(parts) != 3 or not all(p.isdigit() and int(p) < 256 for p in parts):
            raise ConfigError(f"emulator.firmware must look like '1.2.3' (each < 256), got {self.firmware!r}")
        if len(self.serial.encode()) > 64:
            raise ConfigError("emulator.serial must be at most 64 bytes")


@dataclass(frozen=True)
class BridgeConfig:
    """How the kiosk reaches the haptic bridge controller.

    report_size: 64 (full-speed HID) or 1024 (high-speed HID reports / bulk packets); window: tiles in flight
    before waiting for ACKs; max_retries: retransmissions of one message before the link is declared failed;
    frame_retries: whole-frame retries after a NACKed commit; link_loss_after: missed heartbeats before the link is
    declared down; compression: 'zlib' or 'none'; delta: send only tiles that differ from the device's frame.
    """

    type: str = "emulated"
    vid: int = field(default=DEFAULT_VID, metadata=_HEX)
    pid: int = field(default=DEFAULT_PID, metadata=_HEX)
    serial: str | None = None
    report_size: int = 64
    ep_out: int = field(default=0x01, metadata=_HEX)
    ep_in: int = field(default=0x81, metadata=_HEX)
    interface: int = 0
    socket: str | None = None
    ack_timeout_s: float = 0.05
    max_retries: int = 5
    window: int = 16
    frame_retries: int = 2
    handshake_timeout_s: float = 0.3
    heartbeat_interval_s: float = 0.25
    heartbeat_timeout_s: float = 0.1
    link_loss_after: int = 2
    reconnect_interval_s: float = 0.1
    background: bool = True
    compression: str = "zlib"
    zlib_level: int = 1
    delta: bool = True
    blank_on_close: bool = True
    emulator: EmulatorConfig = field(default_factory=EmulatorConfig)

    def __post_init__(self) -> None:
        if self.type not in ("hid", "usb", "emulated") and not _registered(self.type):
            raise ConfigError(f"type must be one of hid, usb, emulated (or a registered plugin), got {self.type!r}")
        for name in ("vid", "pid"):
            v = getattr(self, name)
            if not 0 <= v <= 0xFFFF:
                raise ConfigError(f"{name} must be a 16-bit USB id (0..0xFFFF), got {v}")
        if not 8 <= self.report_size <= 16384:
            raise ConfigError(f"report_size must be in [8, 16384] bytes (64 or 1024 usually), got {self.report_size}")
        for name in ("ack_timeout_s", "handshake_timeout_s", "heartbeat_interval_s", "heartbeat_timeout_s",
                     "reconnect_interval_s"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"{name} must be > 0 seconds, got {getattr(self, name)}")
        for name, lo in (("max_retries", 0), ("window", 1), ("frame_retries", 0), ("link_loss_after", 1)):
            if getattr(self, name) < lo:
                raise ConfigError(f"{name} must be >= {lo}, got {getattr(self, name)}")
        if self.compression not in ("zlib", "none"):
            raise ConfigError(f"compression must be 'zlib' or 'none', got {self.compression!r}")
        if not 0 <= self.zlib_level <= 9:
            raise ConfigError(f"zlib_level must be in [0, 9], got {self.zlib_level}")

    @classmethod
    def from_mapping(cls, data: dict[str, Any] | None) -> "BridgeConfig":
        """Build from a plain mapping (e.g. parsed YAML). Hex strings are accepted for vid/pid/ep_*."""
        return config_loader.build(cls, data, error=ConfigError)

    @classmethod
    def from_yaml(cls, path: str | Path, key: str | None = None) -> "BridgeConfig":
        """Load a YAML file; `key` selects a sub-mapping (e.g. 'bridge')."""
        data: Any = config_loader.load_yaml(path, error=ConfigError, what="bridge config")
        if key is not None:
            if key not in data:
                raise ConfigError(f"{path}: no '{key}' mapping")
            data = data[key]
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: expected a mapping of bridge settings")
        base = Path(path).parent
        return config_loader.build(cls, data, error=ConfigError, base_dir=base, where=str(path))

    def replace(self, **changes: Any) -> "BridgeConfig":
        return dataclasses.replace(self, **changes)


def _registered(type_name: str) -> bool:
    from .transports import TRANSPORTS

    return type_name in TRANSPORTS
