"""Framing: split protocol messages into fixed-size reports and reassemble them, resynchronising after garbage.

The same messages travel over 64-byte HID reports (full speed), 1024-byte HID reports (high speed) and bulk
packets. Each report is::

    offset size field
    0      1    marker   0xA5
    1      1    flags    bit0 START (first chunk of a message), bit1 END (last chunk)
    2      2    length   u16 LE, chunk bytes in this report (1 .. report_size-4)
    4      n    chunk
    4+n    ..   zero padding up to report_size (HID: always; bulk: omitted)

Reassembly is a small state machine (IDLE -> IN_MESSAGE -> IDLE). A report with a bad marker, bad flags or bad
length, a continuation without a START, or a START in the middle of a message discards the partial message and
counts one resync; the message CRC (protocol.py) catches what the report checks cannot (a lost or reordered middle
chunk). Nothing here raises on bad input: garbage is counted and dropped.
"""
from __future__ import annotations

import struct

from .protocol import MAX_PAYLOAD, OVERHEAD

MARKER = 0xA5
START = 0x01
END = 0x02
REPORT_HEADER = struct.Struct("<BBH")
MIN_REPORT = 8
MAX_REPORT = 65535
MAX_MESSAGE = OVERHEAD + MAX_PAYLOAD


def check_report_size(report_size: int) -> int:
    if not isinstance(report_size, int) or not MIN_REPORT <= report_size <= MAX_REPORT:
        raise ValueError(f"report_size must be an int in [{MIN_REPORT}, {MAX_REPORT}], got {report_size!r}")
    return report_size


def split(message: bytes, report_size: int, pad: bool = True) -> list[bytes]:
    """One message -> reports of `report_size` bytes (the last one zero-padded when `pad`).

    Shape: len(result) == ceil(len(message) / (report_size - 4)); each report is report_size bytes if pad.
    """
    check_report_size(report_size)
    if not message:
        raise ValueError("cannot frame an empty message")
    cap = report_size - REPORT_HEADER.size
    reports = []
    for off in range(0, len(message), cap):
        chunk = message[off: off + cap]
        flags = (START if off == 0 else 0) | (END if off + cap >= len(message) else 0)
        rep = REPORT_HEADER.pack(MARKER, flags, len(chunk)) + chunk
        if pad and len(rep) < report_size:
            rep += bytes(report_size - len(rep))
        reports.append(rep)
    return reports


def wire_bytes(message_len: int, report_size: int, pad: bool = True) -> int:
    """Bytes on the wire for a message of `message_len` bytes (what the link bandwidth is spent on)."""
    cap = report_size - REPORT_HEADER.size
    n = -(-message_len // cap)
    return n * report_size if pad else message_len + n * REPORT_HEADER.size


class Reassembler:
    """Feed reports, get complete message byte strings. Counts `resyncs` (discarded reports or partial messages)."""

    def __init__(self, report_size: int) -> None:
        self.report_size = check_report_size(report_size)
        self._buf = bytearray()
        self._active = False
        self.resyncs = 0
        self.messages = 0

    def reset(self) -> None:
        if self._active:
            self.resyncs += 1
        self._buf.clear()
        self._active = False

    def feed(self, report: bytes | bytearray | memoryview) -> bytes | None:
        """One report -> the completed message it ends, or None (more needed, or the report was garbage)."""
        report = bytes(report)
        if len(report) < REPORT_HEADER.size or len(report) > self.report_size:
            return self._garbage()
        marker, flags, length = REPORT_HEADER.unpack_from(report, 0)
        if marker != MARKER or flags & ~(START | END) or length == 0 \
                or length > len(report) - REPORT_HEADER.size:
            return self._garbage()
        chunk = report[REPORT_HEADER.size: REPORT_HEADER.size + length]
        if flags & START:
            if self._active:
                self.resyncs += 1  # a new message began before the old one ended: the old one is lost
            self._buf = bytearray(chunk)
            self._active = True
        elif not self._active:
            return self._garbage()  # continuation of a message whose start we never saw
        else:
            self._buf += chunk
        if len(self._buf) > MAX_MESSAGE:
            return self._garbage()
        if flags & END:
            msg = bytes(self._buf)
            self._buf.clear()
            self._active = False
            self.messages += 1
            return msg
        return None

    def _garbage(self) -> None:
        self.resyncs += 1
        self._buf.clear()
        self._active = False
        return None
