"""Exceptions of the haptic bridge.

Every expected failure is a `BridgeError`; its class attribute `user_facing = True` tells the `vtkiosk`
dispatcher to print the message as one line (no traceback). Messages say what an operator can do.
"""
from __future__ import annotations


class BridgeError(Exception):
    """Base of all expected bridge failures (bad config, no device, link down, protocol violations)."""

    user_facing = True


class ConfigError(BridgeError):
    """The bridge configuration is invalid (unknown key, wrong type, out-of-range value)."""


class ProtocolError(BridgeError):
    """Bytes that are not a valid protocol v1 message or report (bad magic, length, CRC, field value)."""


class NoDeviceError(BridgeError):
    """No bridge controller matched the configured VID/PID/serial."""


class LinkError(BridgeError):
    """The link failed: I/O error, unplug, or no answer after the configured retries."""


class LinkDownError(LinkError):
    """The link is down (detected by heartbeat or I/O error); the current frame is re-sent on reconnect."""


class CommitError(BridgeError):
    """The device refused to commit a frame (the previous frame stays active)."""
