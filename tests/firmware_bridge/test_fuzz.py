"""Fuzz: random and mutated bytes into both parsers (host and device side): protocol errors only, no crash/hang."""
from __future__ import annotations

import random

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_bridge import protocol as P
from firmware_bridge.clock import VirtualClock
from firmware_bridge.config import EmulatorConfig
from firmware_bridge.emulator.controller import Controller
from firmware_bridge.errors import ProtocolError
from firmware_bridge.framing import Reassembler, split

from .conftest import build

VALID = [
    P.encode(P.Hello(1)), P.encode(P.Begin(2, 1, P.FULL_BASE, 4)), P.encode(P.Commit(3, 1, 4, 123)),
    P.encode(P.Tile(4, 1, 0, 0, P.Codec.ZLIB, 5, b"x\x9c" + bytes(40))), P.encode(P.Status(5, 1, 2, 3, 4, 5, 6, 7, 8)),
    P.encode(P.Info(6, serial="abc")), P.encode(P.Ack(7, 1, 1)), P.encode(P.Nack(8, 1, 2, 3)),
]


def mutate(data: bytes, rng: random.Random) -> bytes:
    buf = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(4)
        if op == 0 and buf:
            buf[rng.randrange(len(buf))] = rng.randrange(256)
        elif op == 1 and buf:
            del buf[rng.randrange(len(buf))]
        elif op == 2:
            buf.insert(rng.randrange(len(buf) + 1), rng.randrange(256))
        else:
            buf = buf[: rng.randrange(len(buf) + 1)]
    return bytes(buf)


def _parse_only_protocol_errors(data: bytes) -> None:
    try:
        P.parse(data)
    except ProtocolError:
        pass


@settings(max_examples=1500, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_parse_or_protocol_error(data):
    _parse_only_protocol_errors(data)


@settings(max_examples=1500, deadline=None)
@given(st.sampled_from(VALID), st.randoms(use_true_random=False))
def test_mutated_messages_parse_or_protocol_error(data, rng):
    out = mutate(data, rng)
    _parse_only_protocol_errors(out)
    # and with a CRC recomputed, so the mutation reaches the field parsers
    if len(out) >= P.OVERHEAD:
        _parse_only_protocol_errors(out[:-4] + P.CRC.pack(P.crc32(out[:-4])))


def test_device_parser_survives_random_and_mutated_messages_with_valid_crc():
    """The controller (device-side parser and state machine) answers or ignores, never raises."""
    ctl = Controller(EmulatorConfig(panel_w=200, panel_h=100, tile_w=32, tile_h=32), VirtualClock())
    rng = random.Random(7)
    for i in range(20000):
        base = rng.choice(VALID)
        data = mutate(base, rng)
        if rng.random() < 0.7 and len(data) >= P.OVERHEAD:
            head = bytearray(data[:-4])
            if len(head) >= 8:  # fix up length too, so most messages reach the handlers
                head[6:8] = (len(head) - 8).to_bytes(2, "little")
            data = bytes(head) + P.CRC.pack(P.crc32(bytes(head)))
        reply = ctl.handle(data)
        if reply is not None:
            assert isinstance(P.parse(reply), (P.Ack, P.Nack, P.Info, P.Status))
    assert ctl.active.shape == (100, 200)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.binary(min_size=0, max_size=70), max_size=30))
def test_reassembler_never_raises_on_garbage_reports(reports):
    r = Reassembler(64)
    for rep in reports:
        out = r.feed(rep)
        if out is not None:
            _parse_only_protocol_errors(out)


def test_garbage_on_the_line_then_the_link_still_works():
    """Random reports written to the device, then a real upload: the device resynchronises."""
    disp, emu = build(transport="hid", report_size=64, link="none", panel=(128, 64), tile=32)
    disp.open()
    rng = random.Random(3)
    dev = emu.hid_api().device()
    dev.open(emu.vid, emu.pid)
    for _ in range(500):
        valid = split(rng.choice(VALID), 64)
        rep = mutate(rng.choice(valid), rng)[:64] or b"\x00"
        dev.write(b"\x00" + rep)
    while dev.read(64, 1):
        pass
    frame = np.random.default_rng(0).integers(0, 255, (64, 128), dtype=np.uint8)
    disp.present(frame)
    assert np.array_equal(emu.active_frame, frame)
    disp.close()


@pytest.mark.timeout(30)
def test_host_parser_survives_garbage_replies():
    """Garbage replies reach the host transport/session: counted, retried, never a crash."""
    disp, emu = build(transport="emulated", report_size=64, link="none", panel=(64, 64), tile=32)
    disp.open()
    rng = random.Random(11)
    orig = emu.controller.handle

    def noisy(data):
        reply = orig(data)
        if reply is not None and rng.random() < 0.5:
            return mutate(reply, rng) or reply
        return reply

    emu.controller.handle = noisy
    frame = np.full((64, 64), 9, np.uint8)
    frame[10:20, 5:50] = 200
    disp.present(frame)
    assert np.array_equal(emu.active_frame, frame)
    assert disp.session.stats["bad_replies"] + disp.session.stats["retransmits"] > 0
    disp.close()
