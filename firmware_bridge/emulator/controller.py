"""The bridge controller's side of protocol v1, as the firmware implements it.

State: an active frame (what the finger feels, times the gain, unless blanked) and at most one pending frame in the
back buffer. BEGIN opens a pending frame (a copy of the active one for a delta, zeros for a full frame), TILEs are
decoded (bounded), CRC-checked and written into it, COMMIT swaps buffers only when every announced tile arrived
and the back buffer's CRC-32 equals the host's: a finger never feels half a frame. ABORT, a new HELLO or a newer
BEGIN drop the pending frame; the active one stays. Duplicates (retransmissions) are answered again without
changing state. A host silent for `host_timeout_s` trips the watchdog: output blanked (the safe state) until
the host talks again.

Shapes: frames are uint8 (panel_h, panel_w), row-major.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import protocol as P
from ..config import EmulatorConfig
from ..errors import ProtocolError
from ..tiles import Grid, decode_tile

CAPABILITIES = P.Cap.ZLIB | P.Cap.FILL | P.Cap.DELTA | P.Cap.GAIN | P.Cap.WATCHDOG


@dataclass
class _Pending:
    frame_id: int
    n_tiles: int
    buffer: np.ndarray
    received: set = field(default_factory=set)


class Controller:
    """Protocol state machine of the device. `handle(message_bytes) -> reply bytes or None`."""

    def __init__(self, config: EmulatorConfig, clock, report_size: int | None = None) -> None:
        self.config = config
        self.clock = clock
        self.report_size = report_size   # the link's report size, which HELLO must match (None: not checked)
        self.grid = Grid(config.panel_w, config.panel_h, config.tile_w, config.tile_h)
        major, minor, patch = (int(p) for p in config.firmware.split("."))
        self._fw = (major, minor, patch)
        self.committed: list[tuple[int, int]] = []  # (frame_id, crc32) of every frame that became active
        self.rx_errors = 0
        self.boots = 0
        self.power_on()

    # -- power -------------------------------------------------------------------------------------------------
    def power_on(self) -> None:
        """Cold start: zero frame, gain 1, output on, nothing pending (what a replug does)."""
        self.active = np.zeros((self.grid.panel_h, self.grid.panel_w), np.uint8)
        self.active_id = 0
        self.active_crc = P.crc32(self.active.tobytes())
        self.pending: _Pending | None = None
        self.gain = 1000
        self.blanked = False
        self.watchdog_blanked = False
        self.boot_time = self.clock.now()
        self.last_host = self.boot_time
        self.boots += 1

    # -- what the finger feels -----------------------------------------------------------------------------------
    def check_watchdog(self) -> None:
        if self.clock.now() - self.last_host > self.config.host_timeout_s:
            self.watchdog_blanked = True

    def felt(self) -> np.ndarray:
        """The friction output now: active frame * gain, or zeros when blanked or the watchdog tripped."""
        self.check_watchdog()
        if self.blanked or self.watchdog_blanked:
            return np.zeros_like(self.active)
        if self.gain == 1000:
            return self.active.copy()
        return ((self.active.astype(np.uint32) * self.gain + 500) // 1000).astype(np.uint8)

    # -- protocol ------------------------------------------------------------------------------------------------
    def handle(self, data: bytes) -> bytes | None:
        """One reassembled message -> the encoded reply (None: nothing to say, e.g. the message was corrupt)."""
        try:
            msg = P.parse(data)
        except ProtocolError:
            self.rx_errors += 1
            return None
        self.check_watchdog()
        self.last_host = self.clock.now()
        self.watchdog_blanked = False
        handler = getattr(self, "_on_" + msg.TYPE.name.lower(), None)
        if handler is None:  # a device->host message sent to the device
            self.rx_errors += 1
            return None
        reply = handler(msg)
        return P.encode(reply) if reply is not None else None

    def _ack(self, msg: P.Message, frame_id: int = 0) -> P.Ack:
        return P.Ack(msg.seq, int(msg.TYPE), frame_id)

    def _nack(self, msg: P.Message, code: P.NackCode, frame_id: int = 0) -> P.Nack:
        return P.Nack(msg.seq, int(msg.TYPE), int(code), frame_id)

    def info(self, seq: int = 0) -> P.Info:
        g = self.grid
        serial = self.config.serial
        return P.Info(seq, P.VERSION, g.panel_w, g.panel_h, g.panel_w, g.panel_h, g.tile_w, g.tile_h, *self._fw,
                      int(CAPABILITIES), P.MAX_PAYLOAD, serial)

    def _on_hello(self, msg: P.Hello):
        if not msg.min_version <= P.VERSION <= msg.max_version:
            return self._nack(msg, P.NackCode.BAD_VERSION)
        if self.report_size is not None and msg.report_size != self.report_size:
            # Small messages survive a size mismatch, tiles do not: refuse here, saying the size this side uses.
            return self._nack(msg, P.NackCode.BAD_VALUE, self.report_size)
        self.pending = None  # a new session never inherits a half-sent frame
        return self.info(msg.seq)

    def _on_begin(self, msg: P.Begin):
        if self.pending is not None and msg.frame_id == self.pending.frame_id:
            return self._ack(msg, msg.frame_id)  # retransmitted BEGIN: keep the tiles already received
        newest = max(self.active_id, self.pending.frame_id if self.pending else 0)
        if msg.frame_id <= newest:
            return self._nack(msg, P.NackCode.STALE, msg.frame_id)
        if msg.base_id == P.FULL_BASE:
            if msg.n_tiles != self.grid.count:
                return self._nack(msg, P.NackCode.BAD_VALUE, msg.frame_id)
            buffer = np.zeros_like(self.active)
        elif msg.base_id == self.active_id:
            if msg.n_tiles > self.grid.count:
                return self._nack(msg, P.NackCode.BAD_VALUE, msg.frame_id)
            buffer = self.active.copy()
        else:
            return self._nack(msg, P.NackCode.BASE_MISMATCH, msg.frame_id)
        self.pending = _Pending(msg.frame_id, msg.n_tiles, buffer)
        return self._ack(msg, msg.frame_id)

    def _on_tile(self, msg: P.Tile):
        pend = self.pending
        if pend is None or msg.frame_id != pend.frame_id:
            return self._nack(msg, P.NackCode.STALE if pend else P.NackCode.NO_FRAME, msg.frame_id)
        try:
            y0, y1, x0, x1 = self.grid.bounds(msg.tx, msg.ty)
        except IndexError:
            return self._nack(msg, P.NackCode.BAD_TILE, msg.frame_id)
        try:
            raw = decode_tile(msg.codec, msg.data, (y1 - y0) * (x1 - x0))
        except ProtocolError:
            return self._nack(msg, P.NackCode.DECODE, msg.frame_id)
        if P.crc32(raw) != msg.raw_crc:
            return self._nack(msg, P.NackCode.TILE_CRC, msg.frame_id)
        pend.buffer[y0:y1, x0:x1] = np.frombuffer(raw, np.uint8).reshape(y1 - y0, x1 - x0)
        pend.received.add((msg.tx, msg.ty))
        return self._ack(msg, msg.frame_id)

    def _on_commit(self, msg: P.Commit):
        pend = self.pending
        if pend is None or msg.frame_id != pend.frame_id:
            if msg.frame_id == self.active_id and msg.frame_crc == self.active_crc:
                return self._ack(msg, msg.frame_id)  # retransmitted COMMIT of the frame already active
            return self._nack(msg, P.NackCode.STALE if pend else P.NackCode.NO_FRAME, msg.frame_id)
        if len(pend.received) != pend.n_tiles or msg.n_tiles != pend.n_tiles:
            return self._nack(msg, P.NackCode.INCOMPLETE, msg.frame_id)
        crc = P.crc32(pend.buffer.tobytes())
        if crc != msg.frame_crc:
            return self._nack(msg, P.NackCode.FRAME_CRC, msg.frame_id)
        self.active, self.active_id, self.active_crc = pend.buffer, pend.frame_id, crc  # the atomic swap
        self.pending = None
        self.committed.append((self.active_id, crc))
        return self._ack(msg, msg.frame_id)

    def _on_abort(self, msg: P.Abort):
        if self.pending is not None and self.pending.frame_id == msg.frame_id:
            self.pending = None
        return self._ack(msg, msg.frame_id)

    def _on_set_gain(self, msg: P.SetGain):
        if msg.permille > 1000:
            return self._nack(msg, P.NackCode.BAD_VALUE)
        self.gain = msg.permille
        return self._ack(msg)

    def _on_clear(self, msg: P.Clear):
        if msg.frame_id == self.active_id and not self.active.any():
            return self._ack(msg, msg.frame_id)  # retransmitted CLEAR
        if msg.frame_id <= max(self.active_id, self.pending.frame_id if self.pending else 0):
            return self._nack(msg, P.NackCode.STALE, msg.frame_id)
        self.pending = None
        self.active = np.zeros_like(self.active)
        self.active_id, self.active_crc = msg.frame_id, P.crc32(self.active.tobytes())
        self.committed.append((self.active_id, self.active_crc))
        return self._ack(msg, msg.frame_id)

    def _on_blank(self, msg: P.Blank):
        if msg.on not in (0, 1):
            return self._nack(msg, P.NackCode.BAD_VALUE)
        self.blanked = bool(msg.on)
        return self._ack(msg)

    def _on_heartbeat(self, msg: P.Heartbeat):
        return self.status(msg.seq, msg.counter)

    def status(self, seq: int = 0, counter: int = 0) -> P.Status:
        flags = (P.STATUS_BLANKED if self.blanked else 0) | (P.STATUS_WATCHDOG if self.watchdog_blanked else 0) \
            | (P.STATUS_PENDING if self.pending else 0)
        uptime = int((self.clock.now() - self.boot_time) * 1000) & P.U32
        return P.Status(seq, counter, self.active_id, self.active_crc, self.pending.frame_id if self.pending else 0,
                        self.gain, flags, uptime, self.rx_errors & P.U32)
