"""HapticDisplay against the emulator: concepts, delta, atomic commit, blank/gain/clear, heartbeat, watchdog."""
from __future__ import annotations

import numpy as np
import pytest

from firmware_bridge import protocol as P
from firmware_bridge.config import FaultConfig
from firmware_bridge.display import LinkState
from firmware_bridge.errors import CommitError, LinkDownError, LinkError
from firmware_bridge.framing import split


def noise(shape, seed=0):
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def test_open_reports_device_info(rig):
    disp, emu = rig()
    info = disp.open()
    assert (info.panel_w, info.panel_h, info.tile_w, info.tile_h) == (1280, 800, 64, 64)
    assert info.firmware == "1.0.0" and info.serial == "EMU-0001" and info.protocol_version == 1
    assert set(info.capabilities) >= {"ZLIB", "DELTA", "WATCHDOG"}
    assert disp.link_state is LinkState.UP


def test_full_then_delta_upload_is_bit_exact_and_sends_only_changed_tiles(rig):
    disp, emu = rig()
    disp.open()
    frame = noise((800, 1280))
    r1 = disp.present(frame)
    assert r1.full and r1.tiles_sent == 260
    assert np.array_equal(emu.active_frame, frame)
    frame2 = frame.copy()
    frame2[100:110, 70:140] = 7  # touches tiles (1,1) and (2,1)
    r2 = disp.present(frame2)
    assert not r2.full and r2.tiles_sent == 2 and r2.wire_bytes < r1.wire_bytes / 50
    assert np.array_equal(emu.active_frame, frame2)
    r3 = disp.present(frame2)
    assert r3.skipped and r3.tiles_sent == 0
    assert [fid for fid, _ in emu.committed] == [r1.frame_id, r2.frame_id]


def test_sprites_views_and_materials_compose_as_documented(rig):
    disp, emu = rig(panel=(256, 128), tile=32)
    disp.open()
    tex = np.arange(16, dtype=np.uint8).reshape(4, 4) * 10 + 1
    disp.upload_texture("weave", tex)
    disp.upload_texture("flat", np.full((8, 8), 200, np.uint8))
    disp.add_sprite("a", "weave", 10, 20)  # 1:1
    disp.add_sprite("b", "weave", 100, 0, width=8, height=8, material="zoom")
    disp.add_sprite("c", "weave", 200, 100, width=10, height=6, material="tile")
    disp.add_sprite("top", "flat", 12, 22, depth=5)  # over part of "a"
    disp.add_sprite("edge", "flat", 252, 124)  # clipped at the panel corner
    disp.commit()
    f = emu.active_frame
    assert np.array_equal(f[20:22, 10:14], tex[:2])
    assert np.all(f[22:30, 12:20] == 200)
    assert np.array_equal(f[0:8, 100:108], np.repeat(np.repeat(tex, 2, 0), 2, 1))
    assert np.array_equal(f[100:106, 200:210], np.tile(tex, (2, 3))[:6, :10])
    assert np.all(f[124:, 252:] == 200)
    assert int(f.astype(int).sum()) == int(disp.compose().astype(int).sum())
    disp.add_sprite("x", "flat", 0, 0, view="other")
    disp.show_view("other")
    disp.commit()
    assert emu.active_frame[:8, :8].min() == 200 and emu.active_frame[20:22, 10:14].max() == 0
    with pytest.raises(KeyError, match="upload_texture"):
        disp.add_sprite("y", "missing", 0, 0)
    with pytest.raises(TypeError, match="uint8"):
        disp.upload_texture("bad", np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="larger than the device"):
        disp.upload_texture("big", np.zeros((129, 10), np.uint8))
    with pytest.raises(ValueError, match="used by sprites"):
        disp.delete_texture("flat")


def test_gain_blank_unblank_clear_reach_the_felt_output(rig):
    disp, emu = rig(panel=(128, 64), tile=32)
    disp.open()
    frame = np.full((64, 128), 200, np.uint8)
    disp.present(frame)
    disp.set_gain(0.5)
    assert np.all(emu.felt() == 100)
    disp.blank()
    assert not emu.felt().any() and np.array_equal(emu.active_frame, frame)
    assert disp.heartbeat().flags & P.STATUS_BLANKED
    disp.unblank()
    assert np.all(emu.felt() == 100)
    disp.clear()
    assert not emu.active_frame.any()
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        disp.set_gain(1.5)
    disp.set_gain(1.0)
    disp.present(frame)  # the delta base after clear is the zero frame
    assert np.array_equal(emu.active_frame, frame)


def test_close_blanks_the_output(rig):
    disp, emu = rig(panel=(64, 64), tile=32)
    disp.open()
    disp.present(np.full((64, 64), 50, np.uint8))
    disp.close()
    assert not emu.felt().any()


def test_incomplete_frame_never_commits_and_abort_keeps_the_old_one(rig):
    disp, emu = rig(panel=(64, 64), tile=32, report_size=64, link="none")
    disp.open()
    old = np.full((64, 64), 5, np.uint8)
    disp.present(old)
    ctl = emu.controller
    new = np.full((64, 64), 9, np.uint8)
    fid = ctl.active_id + 1
    crc = P.crc32(new.tobytes())
    ans = lambda m: P.parse(ctl.handle(P.encode(m)))  # noqa: E731
    assert isinstance(ans(P.Begin(1, fid, P.FULL_BASE, 4)), P.Ack)
    tile = bytes([9]) * 1024
    assert isinstance(ans(P.Tile(2, fid, 0, 0, P.Codec.RAW, P.crc32(tile), tile)), P.Ack)
    assert isinstance(ans(P.Tile(3, fid, 1, 0, P.Codec.RAW, P.crc32(tile) ^ 1, tile)), P.Nack)  # bad tile CRC
    nack = ans(P.Commit(4, fid, 4, crc))
    assert isinstance(nack, P.Nack) and nack.code == P.NackCode.INCOMPLETE
    assert np.array_equal(ctl.active, old)
    assert isinstance(ans(P.Abort(5, fid)), P.Ack)
    assert ctl.pending is None and np.array_equal(ctl.active, old)
    # a delta on the wrong base is refused; a stale frame id too
    assert ans(P.Begin(6, fid + 1, 12345, 1)).code == P.NackCode.BASE_MISMATCH
    assert ans(P.Begin(7, ctl.active_id, P.FULL_BASE, 4)).code == P.NackCode.STALE
    # the host recovers from whatever we did behind its back
    disp.present(new)
    assert np.array_equal(ctl.active, new)


def test_frame_crc_mismatch_is_refused(rig):
    disp, emu = rig(panel=(64, 64), tile=32, link="none")
    disp.open()
    ctl = emu.controller
    fid = ctl.active_id + 1
    tile = bytes(1024)
    ctl.handle(P.encode(P.Begin(1, fid, P.FULL_BASE, 4)))
    for i, (tx, ty) in enumerate([(0, 0), (1, 0), (0, 1), (1, 1)]):
        ctl.handle(P.encode(P.Tile(2 + i, fid, tx, ty, P.Codec.RAW, P.crc32(tile), tile)))
    nack = P.parse(ctl.handle(P.encode(P.Commit(9, fid, 4, 1234))))
    assert nack.code == P.NackCode.FRAME_CRC and ctl.active_id != fid


def test_device_reset_behind_the_hosts_back_is_detected_by_heartbeat(rig):
    disp, emu = rig(panel=(128, 64), tile=32)
    disp.open()
    frame = noise((64, 128), 2)
    disp.present(frame)
    emu.controller.power_on()  # e.g. a brown-out: the device lost the frame but the link stayed up
    disp.poll()
    assert np.array_equal(emu.active_frame, frame)


def test_watchdog_blanks_when_host_goes_silent(rig):
    disp, emu = rig(panel=(64, 64), tile=32)
    disp.open()
    disp.present(np.full((64, 64), 80, np.uint8))
    assert emu.felt().max() == 80
    emu.clock.advance(emu.config.host_timeout_s + 0.01)
    assert not emu.felt().any()
    assert disp.heartbeat().flags & P.STATUS_WATCHDOG == 0  # the heartbeat itself re-arms the output
    assert emu.felt().max() == 80


def test_unplug_marks_link_down_and_replug_resends_current_frame(rig):
    disp, emu = rig(panel=(128, 64), tile=32)
    disp.open()
    disp.set_gain(0.8)
    a = noise((64, 128), 3)
    disp.present(a)
    emu.unplug()
    b = noise((64, 128), 4)
    with pytest.raises(LinkDownError, match="re-sent on reconnect"):
        disp.present(b)
    assert disp.link_state is LinkState.DOWN
    with pytest.raises(LinkDownError):
        disp.blank()
    assert not disp.reconnect(timeout_s=0.5)
    emu.replug()
    assert not emu.active_frame.any()  # cold start
    assert disp.reconnect(timeout_s=0.5)
    assert np.array_equal(emu.active_frame, b)
    assert emu.controller.gain == 800 and emu.controller.blanked  # wanted state restored
    assert disp.health().reconnects == 1


def test_heartbeat_misses_declare_link_down(rig):
    disp, emu = rig(panel=(64, 64), tile=32, link_loss_after=2)
    disp.open()
    emu.set_faults(FaultConfig(drop=1.0))
    assert disp.poll() is LinkState.UP  # one miss
    assert disp.poll() is LinkState.DOWN
    emu.set_faults(FaultConfig())
    assert disp.reconnect(timeout_s=1.0)
    h = disp.health()
    assert h.state == "up" and h.reconnects == 1 and h.last_error


def test_commit_error_when_device_keeps_refusing(rig):
    disp, emu = rig(panel=(64, 64), tile=32, frame_retries=1)
    disp.open()
    old = np.full((64, 64), 3, np.uint8)
    disp.present(old)
    emu.controller._on_commit = lambda m: P.Nack(m.seq, int(m.TYPE), int(P.NackCode.FRAME_CRC), m.frame_id)
    with pytest.raises(CommitError, match="previous frame stays active"):
        disp.present(np.full((64, 64), 4, np.uint8))
    assert np.array_equal(emu.active_frame, old)


def test_not_open_errors_are_clear(rig):
    disp, _ = rig()
    with pytest.raises(LinkError, match="open"):
        disp.present(np.zeros((800, 1280), np.uint8))
    with pytest.raises(LinkError, match="open"):
        _ = disp.info


def test_retransmission_recovers_from_a_lossy_line(rig):
    disp, emu = rig(panel=(256, 128), tile=32, report_size=64, link="fs-hid", max_retries=8,
                    faults=FaultConfig(seed=5, drop=0.005, corrupt=0.005, duplicate=0.005, reorder=0.005))
    disp.open()
    for seed in range(3):
        f = noise((128, 256), seed)
        disp.present(f)
        assert np.array_equal(emu.active_frame, f)
    assert disp.session.stats["retransmits"] > 0
    assert emu.fault_counts()


def test_reports_are_split_for_the_configured_size():
    assert all(len(r) == 64 for r in split(b"x" * 500, 64))
