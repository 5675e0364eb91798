"""Unix-socket server: the emulated controller as a separate process (`vtkiosk device emulate --socket PATH`).

Stream framing on the socket: each report is a u16 little-endian length followed by the report bytes (the socket
stands in for the USB cable; reports inside are exactly what the HID link carries). One client at a time; a new
client replaces the old one (like replugging the host side). Runs in real time.
"""
from __future__ import annotations

import os
import secrets
import selectors
import socket
import struct
import threading
from collections.abc import Callable
from pathlib import Path

from .link import DeviceGone

LEN = struct.Struct("<H")


class ReportStream:
    """Length-prefixed reports over a connected stream socket; `recv_report(timeout)` is bounded by the timeout."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self._buf = bytearray()

    def send_report(self, report: bytes) -> None:
        self.sock.sendall(LEN.pack(len(report)) + report)

    def pop(self) -> bytes | None:
        if len(self._buf) >= LEN.size:
            (n,) = LEN.unpack_from(self._buf, 0)
            if len(self._buf) >= LEN.size + n:
                rep = bytes(self._buf[LEN.size: LEN.size + n])
                del self._buf[: LEN.size + n]
                return rep
        return None

    def fill(self, timeout_s: float) -> bool:
        """Read what is available within timeout_s. False when the peer closed."""
        self.sock.settimeout(max(timeout_s, 1e-4))
        try:
            chunk = self.sock.recv(65536)
        except (TimeoutError, socket.timeout, BlockingIOError):
            return True
        if not chunk:
            return False
        self._buf += chunk
        return True


class EmulatorServer:
    """Serve `emulator` on a unix socket at `path` until `stop()` (or the process ends)."""

    def __init__(self, emulator, path: str | Path) -> None:
        self.emulator = emulator
        self.path = str(path)
        self._stop = threading.Event()
        self._sock: socket.socket | None = None

    def start(self) -> None:
        """Bind and listen under a temporary name, then rename: the path appears only once it accepts, so a client
        that waits for the file never meets a socket that refuses (bind creates the file before listen)."""
        if os.path.exists(self.path):
            os.unlink(self.path)
        # short, unique, in the same folder (a rename stays on one file system; a unix socket path has ~107 bytes)
        tmp = os.path.join(os.path.dirname(self.path), f".{secrets.token_hex(4)}.tmp")
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self._sock.bind(tmp)
            self._sock.listen(1)
            os.replace(tmp, self.path)
        except OSError:
            self._sock.close()
            self._sock = None
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise

    def stop(self) -> None:
        self._stop.set()

    def serve_forever(self, poll_s: float = 0.001, should_stop: Callable[[], bool] | None = None) -> None:
        """Serve until `stop()` or `should_stop()` (polled every few milliseconds, e.g. a signal flag)."""
        if self._sock is None:
            self.start()
        sel = selectors.DefaultSelector()
        sel.register(self._sock, selectors.EVENT_READ)
        client: ReportStream | None = None
        try:
            while not self._stop.is_set() and not (should_stop is not None and should_stop()):
                for key, _ in sel.select(timeout=poll_s if client else 0.05):
                    if key.fileobj is self._sock:
                        conn, _ = self._sock.accept()
                        if client is not None:
                            sel.unregister(client.sock)
                            client.sock.close()
                        client = ReportStream(conn)
                        sel.register(conn, selectors.EVENT_READ)
                        self.emulator.link.reset_reassembly()
                    elif client is not None:
                        if not client.fill(0.0):
                            sel.unregister(client.sock)
                            client.sock.close()
                            client = None
                if client is None:
                    continue
                try:
                    while (rep := client.pop()) is not None:
                        self.emulator.link.write(rep[: self.emulator.link.report_size])
                    while (out := self.emulator.link.read(0.0)) is not None:
                        client.send_report(out)
                except (DeviceGone, ValueError, OSError):
                    sel.unregister(client.sock)
                    client.sock.close()
                    client = None
        finally:
            sel.close()
            if client is not None:
                client.sock.close()
            self._sock.close()
            if os.path.exists(self.path):
                os.unlink(self.path)
