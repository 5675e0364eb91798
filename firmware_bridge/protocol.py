"""Protocol v1 messages: byte layouts, encode and parse, CRC-32.

A message on the wire (before framing into reports) is, little-endian::

    offset size field
    0      2    magic   b"VB"
    2      1    version 1
    3      1    type    (MsgType)
    4      2    seq     u16, host-assigned; the device echoes it in ACK/NACK/INFO/STATUS
    6      2    length  u16, payload bytes (<= MAX_PAYLOAD)
    8      n    payload (per-type layout, see each class)
    8+n    4    crc32   zlib.crc32 of bytes [0, 8+n)

`parse(buf)` returns a message object or raises `ProtocolError`; no other exception escapes, whatever the
bytes. `encode(msg)` is its inverse (round trip tested with hypothesis). Full byte layouts: docs/bridge-protocol.md.
"""
from __future__ import annotations

import enum
import struct
import zlib
from dataclasses import dataclass
from typing import ClassVar

from .errors import ProtocolError

MAGIC = b"VB"
VERSION = 1
HEADER = struct.Struct("<2sBBHH")
CRC = struct.Struct("<I")
MAX_PAYLOAD = 16384  # a 64x64 raw tile (4096 B) plus its 13-byte header fits with room for 128x128 tiles
OVERHEAD = HEADER.size + CRC.size
FULL_BASE = 0xFFFFFFFF  # BEGIN.base_id meaning "not a delta: every tile of the frame follows"
U32 = 0xFFFFFFFF


def crc32(data: bytes | bytearray | memoryview) -> int:
    """CRC-32 (IEEE 802.3, as zlib.crc32) of `data` as an unsigned 32-bit int."""
    return zlib.crc32(data) & U32


class MsgType(enum.IntEnum):
    HELLO = 0x01
    INFO = 0x02
    BEGIN = 0x10
    TILE = 0x11
    COMMIT = 0x12
    ABORT = 0x13
    SET_GAIN = 0x20
    CLEAR = 0x21
    BLANK = 0x22
    HEARTBEAT = 0x30
    STATUS = 0x31
    ACK = 0x40
    NACK = 0x41


class Codec(enum.IntEnum):
    """How a TILE's data encodes its tile_w*tile_h friction bytes."""

    RAW = 0  # the bytes themselves
    ZLIB = 1  # zlib stream (RFC 1950); must inflate to exactly tile_w*tile_h bytes
    FILL = 2  # one byte: every pixel of the tile has this value


class NackCode(enum.IntEnum):
    BAD_VERSION = 1  # HELLO offered no version the device speaks
    STALE = 2  # frame_id is not the pending frame (old or unknown)
    BASE_MISMATCH = 3  # BEGIN.base_id is not the device's active frame: send a full frame
    BAD_TILE = 4  # tile index outside the panel
    DECODE = 5  # tile data did not decode to exactly tile_w*tile_h bytes
    TILE_CRC = 6  # decoded tile's CRC differs from TILE.raw_crc
    INCOMPLETE = 7  # COMMIT before all announced tiles arrived
    FRAME_CRC = 8  # COMMIT.frame_crc differs from the back buffer's CRC
    BAD_VALUE = 9  # a field is out of range (gain > 1000, ...)
    NO_FRAME = 10  # TILE/COMMIT without a BEGIN


class Cap(enum.IntFlag):
    """Capability bits in INFO."""

    ZLIB = 1
    FILL = 2
    DELTA = 4
    GAIN = 8
    WATCHDOG = 16  # the device blanks itself when host heartbeats stop


STATUS_BLANKED = 1
STATUS_WATCHDOG = 2
STATUS_PENDING = 4


@dataclass(frozen=True)
class Message:
    """Base: every message has a 16-bit sequence number in its header."""

    TYPE: ClassVar[MsgType]
    FMT: ClassVar[struct.Struct]
    seq: int

    def fields(self) -> tuple:
        return ()

    def tail(self) -> bytes:
        return b""

    @classmethod
    def _from(cls, seq: int, values: tuple, tail: bytes) -> "Message":
        if tail:
            raise ProtocolError(f"{cls.TYPE.name}: {len(tail)} unexpected trailing payload bytes")
        return cls(seq, *values)


@dataclass(frozen=True)
class Hello(Message):
    """host->device: open a session. Payload: min_version u8, max_version u8, report_size u16."""

    TYPE = MsgType.HELLO
    FMT = struct.Struct("<BBH")
    min_version: int = VERSION
    max_version: int = VERSION
    report_size: int = 64

    def fields(self) -> tuple:
        return (self.min_version, self.max_version, self.report_size)


@dataclass(frozen=True)
class Info(Message):
    """device->host: device info, the answer to HELLO.

    Payload: version u8, panel_w u16, panel_h u16, max_texture_w u16, max_texture_h u16, tile_w u16, tile_h u16,
    fw_major u8, fw_minor u8, fw_patch u8, capabilities u32, max_payload u16, serial_len u8, serial (UTF-8).
    """

    TYPE = MsgType.INFO
    FMT = struct.Struct("<BHHHHHHBBBIHB")
    version: int = VERSION
    panel_w: int = 1280
    panel_h: int = 800
    max_texture_w: int = 1280
    max_texture_h: int = 800
    tile_w: int = 64
    tile_h: int = 64
    fw_major: int = 1
    fw_minor: int = 0
    fw_patch: int = 0
    capabilities: int = 0
    max_payload: int = MAX_PAYLOAD
    serial: str = ""

    def fields(self) -> tuple:
        raw = self.serial.encode("utf-8")
        return (self.version, self.panel_w, self.panel_h, self.max_texture_w, self.max_texture_h, self.tile_w,
                self.tile_h, self.fw_major, self.fw_minor, self.fw_patch, self.capabilities, self.max_payload,
                len(raw))

    def tail(self) -> bytes:
        return self.serial.encode("utf-8")

    @classmethod
    def _from(cls, seq: int, values: tuple, tail: bytes) -> "Info":
        *head, serial_len = values
        if len(tail) != serial_len:
            raise ProtocolError(f"INFO: serial length {serial_len} but {len(tail)} bytes follow")
        try:
            serial = tail.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ProtocolError(f"INFO: serial is not UTF-8 ({exc})") from None
        info = cls(seq, *head, serial=serial)
        if info.tile_w == 0 or info.tile_h == 0 or info.panel_w == 0 or info.panel_h == 0:
            raise ProtocolError("INFO: panel and tile sizes must be positive")
        return info

    @property
    def firmware(self) -> str:
        return f"{self.fw_major}.{self.fw_minor}.{self.fw_patch}"


@dataclass(frozen=True)
class Begin(Message):
    """host->device: start frame `frame_id` in the back buffer.

    Payload: frame_id u32, base_id u32, n_tiles u16. base_id == the device's active frame id: a delta, tiles not
    sent keep the active frame's bytes; base_id == FULL_BASE: the back buffer starts at 0 and all tiles follow.
    """

    TYPE = MsgType.BEGIN
    FMT = struct.Struct("<IIH")
    frame_id: int = 0
    base_id: int = FULL_BASE
    n_tiles: int = 0

    def fields(self) -> tuple:
        return (self.frame_id, self.base_id, self.n_tiles)


@dataclass(frozen=True)
class Tile(Message):
    """host->device: one tile of frame `frame_id`. Payload: frame_id u32, tx u16, ty u16, codec u8, raw_crc u32, data.

    (tx, ty) is the tile index (column, row); the tile covers pixels [ty*tile_h, ...) x [tx*tile_w, ...), clipped at
    the panel edge. raw_crc is the CRC-32 of the decoded tile bytes (row-major, clipped size).
    """

    TYPE = MsgType.TILE
    FMT = struct.Struct("<IHHBI")
    frame_id: int = 0
    tx: int = 0
    ty: int = 0
    codec: int = Codec.RAW
    raw_crc: int = 0
    data: bytes = b""

    def fields(self) -> tuple:
        return (self.frame_id, self.tx, self.ty, self.codec, self.raw_crc)

    def tail(self) -> bytes:
        return self.data

    @classmethod
    def _from(cls, seq: int, values: tuple, tail: bytes) -> "Tile":
        if values[3] not in Codec._value2member_map_:
            raise ProtocolError(f"TILE: unknown codec {values[3]}")
        return cls(seq, *values, data=bytes(tail))


@dataclass(frozen=True)
class Commit(Message):
    """host->device: make frame `frame_id` active. Payload: frame_id u32, n_tiles u16, frame_crc u32.

    The device swaps buffers only if it holds n_tiles distinct verified tiles of this frame and the CRC-32 of the
    whole back buffer (panel_h*panel_w bytes, row-major) equals frame_crc; otherwise NACK and the old frame stays.
    """

    TYPE = MsgType.COMMIT
    FMT = struct.Struct("<IHI")
    frame_id: int = 0
    n_tiles: int = 0
    frame_crc: int = 0

    def fields(self) -> tuple:
        return (self.frame_id, self.n_tiles, self.frame_crc)


@dataclass(frozen=True)
class Abort(Message):
    """host->device: drop the pending frame `frame_id`; the active frame stays. Payload: frame_id u32."""

    TYPE = MsgType.ABORT
    FMT = struct.Struct("<I")
    frame_id: int = 0

    def fields(self) -> tuple:
        return (self.frame_id,)


@dataclass(frozen=True)
class SetGain(Message):
    """host->device: output gain in 1/1000 (0..1000); felt friction = frame * gain / 1000. Payload: u16."""

    TYPE = MsgType.SET_GAIN
    FMT = struct.Struct("<H")
    permille: int = 1000

    def fields(self) -> tuple:
        return (self.permille,)


@dataclass(frozen=True)
class Clear(Message):
    """host->device: make an all-zero frame active atomically, with id `frame_id`. Payload: frame_id u32."""

    TYPE = MsgType.CLEAR
    FMT = struct.Struct("<I")
    frame_id: int = 0

    def fields(self) -> tuple:
        return (self.frame_id,)


@dataclass(frozen=True)
class Blank(Message):
    """host->device: on=1 forces all friction off (the safe state) keeping the frame; on=0 restores. Payload: u8."""

    TYPE = MsgType.BLANK
    FMT = struct.Struct("<B")
    on: int = 1

    def fields(self) -> tuple:
        return (self.on,)


@dataclass(frozen=True)
class Heartbeat(Message):
    """host->device: I am alive; the device answers STATUS. Payload: counter u32."""

    TYPE = MsgType.HEARTBEAT
    FMT = struct.Struct("<I")
    counter: int = 0

    def fields(self) -> tuple:
        return (self.counter,)


@dataclass(frozen=True)
class Status(Message):
    """device->host: the device's heartbeat. Payload: counter u32, active_id u32, active_crc u32, pending_id u32,
    gain u16 (permille), flags u8 (1 blanked, 2 watchdog-blanked, 4 frame pending), uptime_ms u32, rx_errors u32."""

    TYPE = MsgType.STATUS
    FMT = struct.Struct("<IIIIHBII")
    counter: int = 0
    active_id: int = 0
    active_crc: int = 0
    pending_id: int = 0
    gain: int = 1000
    flags: int = 0
    uptime_ms: int = 0
    rx_errors: int = 0

    def fields(self) -> tuple:
        return (self.counter, self.active_id, self.active_crc, self.pending_id, self.gain, self.flags,
                self.uptime_ms, self.rx_errors)


@dataclass(frozen=True)
class Ack(Message):
    """device->host: request `seq` (header) of type acked_type succeeded. Payload: acked_type u8, frame_id u32."""

    TYPE = MsgType.ACK
    FMT = struct.Struct("<BI")
    acked_type: int = 0
    frame_id: int = 0

    def fields(self) -> tuple:
        return (self.acked_type, self.frame_id)


@dataclass(frozen=True)
class Nack(Message):
    """device->host: request `seq` failed. Payload: acked_type u8, code u8 (NackCode), frame_id u32."""

    TYPE = MsgType.NACK
    FMT = struct.Struct("<BBI")
    acked_type: int = 0
    code: int = 0
    frame_id: int = 0

    def fields(self) -> tuple:
        return (self.acked_type, self.code, self.frame_id)


MESSAGES: dict[int, type[Message]] = {
    cls.TYPE: cls for cls in (Hello, Info, Begin, Tile, Commit, Abort, SetGain, Clear, Blank, Heartbeat, Status,
                              Ack, Nack)
}


def encode(msg: Message) -> bytes:
    """Message -> bytes (header, payload, CRC). Raises ProtocolError if a field does not fit its width."""
    try:
        payload = msg.FMT.pack(*msg.fields()) + msg.tail()
        if len(payload) > MAX_PAYLOAD:
            raise ProtocolError(f"{msg.TYPE.name}: payload {len(payload)} B exceeds MAX_PAYLOAD {MAX_PAYLOAD}")
        head = HEADER.pack(MAGIC, VERSION, int(msg.TYPE), msg.seq, len(payload))
    except struct.error as exc:
        raise ProtocolError(f"{msg.TYPE.name}: field out of range ({exc})") from None
    body = head + payload
    return body + CRC.pack(crc32(body))


def parse(buf: bytes | bytearray | memoryview) -> Message:
    """Bytes -> message. Raises ProtocolError (never anything else) on any malformed input."""
    buf = bytes(buf)
    if len(buf) < OVERHEAD:
        raise ProtocolError(f"message too short: {len(buf)} B < {OVERHEAD} B header+CRC")
    magic, version, mtype, seq, length = HEADER.unpack_from(buf, 0)
    if magic != MAGIC:
        raise ProtocolError(f"bad magic {magic!r} (expected {MAGIC!r})")
    if version != VERSION:
        raise ProtocolError(f"unsupported protocol version {version} (this host speaks {VERSION})")
    if length > MAX_PAYLOAD or len(buf) != OVERHEAD + length:
        raise ProtocolError(f"length field {length} does not match message size {len(buf)} B")
    (crc,) = CRC.unpack_from(buf, HEADER.size + length)
    if crc != crc32(buf[: HEADER.size + length]):
        raise ProtocolError("CRC mismatch")
    cls = MESSAGES.get(mtype)
    if cls is None:
        raise ProtocolError(f"unknown message type 0x{mtype:02x}")
    payload = buf[HEADER.size: HEADER.size + length]
    if len(payload) < cls.FMT.size:
        raise ProtocolError(f"{cls.TYPE.name}: payload {len(payload)} B < {cls.FMT.size} B")
    values = cls.FMT.unpack_from(payload, 0)
    return cls._from(seq, values, payload[cls.FMT.size:])
