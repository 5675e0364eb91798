"""Protocol v1: every message round-trips; malformed bytes give ProtocolError only."""
from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_bridge import protocol as P
from firmware_bridge.errors import ProtocolError

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)

STRATEGIES = {
    P.Hello: st.builds(P.Hello, u16, u8, u8, u16),
    P.Info: st.builds(P.Info, u16, u8, st.integers(1, 0xFFFF), st.integers(1, 0xFFFF), u16, u16, st.integers(1, 0xFFFF),
              st.integers(1, 0xFFFF), u8, u8, u8, u32, u16, st.text(max_size=20)),
    P.Begin: st.builds(P.Begin, u16, u32, u32, u16),
    P.Tile: st.builds(P.Tile, u16, u32, u16, u16, st.sampled_from(list(P.Codec)), u32, st.binary(max_size=5000)),
    P.Commit: st.builds(P.Commit, u16, u32, u16, u32),
    P.Abort: st.builds(P.Abort, u16, u32),
    P.SetGain: st.builds(P.SetGain, u16, u16),
    P.Clear: st.builds(P.Clear, u16, u32),
    P.Blank: st.builds(P.Blank, u16, u8),
    P.Heartbeat: st.builds(P.Heartbeat, u16, u32),
    P.Status: st.builds(P.Status, u16, u32, u32, u32, u32, u16, u8, u32, u32),
    P.Ack: st.builds(P.Ack, u16, u8, u32),
    P.Nack: st.builds(P.Nack, u16, u8, u8, u32),
}
MESSAGES = st.one_of(*STRATEGIES.values())


@settings(max_examples=300, deadline=None)
@given(MESSAGES)
def test_every_message_round_trips(msg):
    data = P.encode(msg)
    back = P.parse(data)
    assert back == msg
    assert type(back) is type(msg)
    assert P.encode(back) == data


def test_every_type_is_covered_by_the_round_trip_strategy():
    assert set(STRATEGIES) == set(P.MESSAGES.values())
    assert set(P.MESSAGES) == {m.value for m in P.MsgType}


def test_header_layout_is_as_documented():
    data = P.encode(P.Commit(0x1234, frame_id=7, n_tiles=3, frame_crc=0xDEADBEEF))
    assert data[:2] == b"VB" and data[2] == 1 and data[3] == P.MsgType.COMMIT
    assert struct.unpack_from("<HH", data, 4) == (0x1234, 10)
    assert struct.unpack_from("<IHI", data, 8) == (7, 3, 0xDEADBEEF)
    assert struct.unpack_from("<I", data, 18)[0] == P.crc32(data[:18])
    assert len(data) == 22


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d[:5], "too short"),
    (lambda d: b"XX" + d[2:], "magic"),
    (lambda d: d[:2] + b"\x02" + d[3:], "version"),
    (lambda d: d[:-1] + bytes([d[-1] ^ 1]), "CRC"),
    (lambda d: d + b"\x00", "length"),
])
def test_malformed_messages_raise_protocol_error(mutate, match):
    data = P.encode(P.Heartbeat(1, 42))
    with pytest.raises(ProtocolError, match=match):
        P.parse(mutate(data))


def _with_crc(body: bytes) -> bytes:
    return body + struct.pack("<I", P.crc32(body))


def test_unknown_type_and_short_payload_with_valid_crc_are_protocol_errors():
    with pytest.raises(ProtocolError, match="unknown message type"):
        P.parse(_with_crc(P.HEADER.pack(b"VB", 1, 0x7F, 1, 0)))
    with pytest.raises(ProtocolError, match="payload"):
        P.parse(_with_crc(P.HEADER.pack(b"VB", 1, P.MsgType.COMMIT, 1, 2) + b"\x00\x00"))
    with pytest.raises(ProtocolError, match="codec"):
        P.parse(_with_crc(P.HEADER.pack(b"VB", 1, P.MsgType.TILE, 1, 13) + struct.pack("<IHHBI", 1, 0, 0, 9, 0)))
    with pytest.raises(ProtocolError, match="serial"):
        body = P.Info.FMT.pack(1, 10, 10, 10, 10, 8, 8, 1, 0, 0, 0, 100, 5) + b"ab"
        P.parse(_with_crc(P.HEADER.pack(b"VB", 1, P.MsgType.INFO, 1, len(body)) + body))


def test_encode_rejects_out_of_range_fields_with_protocol_error():
    with pytest.raises(ProtocolError, match="out of range"):
        P.encode(P.SetGain(1, 70000))
    with pytest.raises(ProtocolError, match="MAX_PAYLOAD"):
        P.encode(P.Tile(1, 1, 0, 0, P.Codec.RAW, 0, bytes(P.MAX_PAYLOAD)))
