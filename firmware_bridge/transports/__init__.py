"""Transport plugins, chosen by the config's `type` key (Frigate-style registry).

Built in: `hid` (hidapi), `usb` (pyusb bulk), `emulated` (in-process or unix-socket emulator). A vendor-engine
back-end registers beside them with `register_transport("tanvas", "package.module:Class")`. Modules are imported
only when their type is used, so the package imports without hidapi or pyusb.
"""
from __future__ import annotations

import importlib
from typing import Any

from ..errors import ConfigError

TRANSPORTS: dict[str, str] = {
    "hid": "firmware_bridge.transports.hid:HidTransport",
    "usb": "firmware_bridge.transports.usb:UsbTransport",
    "emulated": "firmware_bridge.transports.emulated:EmulatedTransport",
}


def register_transport(type_name: str, target: str) -> None:
    """Register a transport class as 'module:Class' under `type_name` (the config `type` value)."""
    if ":" not in target:
        raise ConfigError(f"transport target must look like 'package.module:Class', got {target!r}")
    TRANSPORTS[type_name] = target


def transport_class(type_name: str) -> type:
    if type_name not in TRANSPORTS:
        raise ConfigError(f"unknown transport type {type_name!r}; known: {sorted(TRANSPORTS)}")
    module, _, cls = TRANSPORTS[type_name].partition(":")
    return getattr(importlib.import_module(module), cls)


def create_transport(config, **inject: Any):
    """Instantiate the transport for `config.type`; `inject` passes device factories (hid_api=, usb_api=,
    emulator=) and clock= through to its constructor."""
    return transport_class(config.type)(config, **inject)
