"""Framing over 64/1024-byte reports and tile codecs."""
from __future__ import annotations

import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_bridge import protocol as P
from firmware_bridge.errors import ProtocolError
from firmware_bridge.framing import MARKER, Reassembler, split, wire_bytes
from firmware_bridge.tiles import Grid, changed_tiles, decode_tile, encode_tile


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(min_size=1, max_size=3000), min_size=1, max_size=5), st.sampled_from([8, 64, 1024]),
       st.booleans())
def test_split_and_reassemble_round_trip(messages, report_size, pad):
    r = Reassembler(report_size)
    for m in messages:
        reports = split(m, report_size, pad)
        assert all(len(x) == report_size for x in reports) or not pad
        assert sum(len(x) for x in reports) == wire_bytes(len(m), report_size, pad)
        got = [r.feed(x) for x in reports]
        assert got[:-1] == [None] * (len(reports) - 1)
        assert got[-1] == m
    assert r.resyncs == 0


def test_resync_after_garbage_and_lost_middle_chunk():
    msg = P.encode(P.Tile(3, 1, 0, 0, P.Codec.RAW, 0, bytes(range(200))))
    reports = split(msg, 64)
    r = Reassembler(64)
    assert r.feed(b"\xff" * 64) is None  # garbage
    assert r.feed(reports[1]) is None  # continuation without a start
    for rep in reports[:2] + reports[3:]:  # a lost middle chunk: reassembles to the wrong bytes...
        out = r.feed(rep)
    with pytest.raises(ProtocolError):  # ...which the message CRC rejects
        P.parse(out)
    for rep in reports:  # and the next clean message gets through
        out = r.feed(rep)
    assert out == msg
    assert r.resyncs == 2


def test_start_in_the_middle_of_a_message_drops_the_partial_one():
    a, b = b"a" * 100, b"b" * 10
    ra, rb = split(a, 64), split(b, 64)
    r = Reassembler(64)
    assert r.feed(ra[0]) is None
    assert r.feed(rb[0]) == b
    assert r.resyncs == 1
    assert ra[0][0] == MARKER


def test_grid_geometry_clips_edge_tiles():
    g = Grid(1280, 800, 64, 64)
    assert (g.nx, g.ny, g.count) == (20, 13, 260)
    assert g.bounds(19, 12) == (768, 800, 1216, 1280)
    assert g.tile_len(0, 12) == 64 * 32
    with pytest.raises(IndexError):
        g.bounds(20, 0)
    with pytest.raises(ValueError, match="shape"):
        g.check_frame(np.zeros((10, 10), np.uint8))
    with pytest.raises(TypeError, match="uint8"):
        g.check_frame(np.zeros((800, 1280), np.float32))


def test_changed_tiles_finds_exactly_the_changed_tiles():
    g = Grid(130, 70, 32, 32)  # 5 x 3 tiles, clipped edges
    a = np.zeros((70, 130), np.uint8)
    b = a.copy()
    b[69, 129] = 1  # bottom-right corner tile
    b[0, 33] = 5  # tile (1, 0)
    assert changed_tiles(g, b, a) == [(1, 0), (4, 2)]
    assert changed_tiles(g, b, None) == g.all_tiles()
    assert changed_tiles(g, a, a) == []


@settings(max_examples=100, deadline=None)
@given(st.binary(min_size=1, max_size=4096), st.sampled_from(["none", "zlib"]))
def test_tile_codecs_round_trip(raw, compression):
    codec, data = encode_tile(raw, compression)
    if compression == "none":
        assert codec == P.Codec.RAW
    assert len(data) <= len(raw)
    assert decode_tile(codec, data, len(raw)) == raw


def test_constant_tile_is_one_byte_and_decode_is_bounded():
    assert encode_tile(bytes(4096)) == (P.Codec.FILL, b"\x00")
    bomb = zlib.compress(bytes(1 << 20))
    with pytest.raises(ProtocolError, match="exactly 4096"):
        decode_tile(P.Codec.ZLIB, bomb, 4096)
    with pytest.raises(ProtocolError, match="exactly 4096"):
        decode_tile(P.Codec.ZLIB, zlib.compress(bytes(100)), 4096)
    with pytest.raises(ProtocolError, match="inflate"):
        decode_tile(P.Codec.ZLIB, b"not zlib", 4096)
    with pytest.raises(ProtocolError):
        decode_tile(P.Codec.ZLIB, zlib.compress(bytes(4096)) + b"trailing", 4096)
    with pytest.raises(ProtocolError):
        decode_tile(P.Codec.RAW, b"abc", 4)
    with pytest.raises(ProtocolError):
        decode_tile(7, b"", 4)
