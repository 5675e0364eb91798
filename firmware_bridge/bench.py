"""`vtkiosk device bench`: bytes on the wire and time per frame, raw vs delta vs delta+compression.

Frames are procedural 1280x800 friction maps (synth.py): one full-frame upload, then `edits` stroke edits. Each
mode runs over three emulated links modelled at their real bandwidths (emulator/link.py): full-speed interrupt HID
(64 B reports, 64 KB/s, 1 ms frames), high-speed interrupt HID (1024 B reports, ~24 MB/s, 125 us microframes) and
high-speed bulk (1024 B packets, ~35 MB/s). Two times per frame, never mixed up:
  - link time: modelled time on the virtual clock (what the USB link would take), the goal's measure;
  - host CPU: measured wall time of `present()` on this machine minus the in-process emulator's share
    (tiling, delta, compression, CRC, framing, ack bookkeeping).
Also a compression study: zlib levels and lzma on the same frames, tile by tile.
"""
from __future__ import annotations

import json
import lzma
import platform
import time
import zlib
from dataclasses import dataclass

import numpy as np

from . import synth
from .config import BridgeConfig, EmulatorConfig
from .display import HapticDisplay
from .emulator import LINK_MODELS, DeviceEmulator
from .tiles import Grid
from .transports.emulated import EmulatedTransport

LINKS = (("fs-hid", 64, True), ("hs-hid", 1024, True), ("hs-bulk", 1024, False))
MODES = (("raw", False, "none"), ("delta", True, "none"), ("delta+zlib", True, "zlib"))
GOAL_EDIT_FRACTION = 0.25
GOAL_FULL_HS_S = 0.030


@dataclass
class Row:
    link: str
    scenario: str
    mode: str
    wire_bytes: float
    payload_bytes: float
    raw_fraction: float
    link_ms: float
    host_cpu_ms: float
    tiles: float


def frames(edits: int, seed: int = 0) -> list[np.ndarray]:
    """The realistic sequence: one garment frame, then `edits` stroke edits of it."""
    frame, mask = synth.friction_frame(seed=seed)
    rng = np.random.default_rng(seed + 1)
    out = [frame]
    for _ in range(edits):
        frame, mask = synth.stroke_edit(frame, mask, rng)
        out.append(frame)
    return out


def compression_study(seq: list[np.ndarray], grid: Grid) -> list[dict]:
    """Compressed/raw ratio and encode/decode time per full frame, tile by tile, for zlib levels and lzma."""
    tiles = [grid.tile_bytes(f, tx, ty) for f in seq[:3] for tx, ty in grid.all_tiles()]
    raw = sum(len(t) for t in tiles)
    codecs = [(f"zlib-{lv}", lambda b, lv=lv: zlib.compress(b, lv), zlib.decompress) for lv in (1, 3, 6, 9)]
    codecs.append(("lzma-0", lambda b: lzma.compress(b, preset=0), lzma.decompress))
    codecs.append(("lzma-6", lambda b: lzma.compress(b, preset=6), lzma.decompress))
    n_frames = len(seq[:3])
    out = []
    for name, enc, dec in codecs:
        t0 = time.perf_counter()
        packed = [enc(t) for t in tiles]
        t1 = time.perf_counter()
        for p in packed:
            dec(p)
        t2 = time.perf_counter()
        out.append({"codec": name, "ratio": sum(map(len, packed)) / raw,
                    "encode_ms_per_frame": (t1 - t0) * 1000 / n_frames,
                    "decode_ms_per_frame": (t2 - t1) * 1000 / n_frames})
    return out


def _run_link(link: str, report_size: int, pad: bool, mode: str, delta: bool, compression: str,
              seq: list[np.ndarray]) -> tuple[Row, Row]:
    ecfg = EmulatorConfig(modelled_time=True, link=link)
    emu = DeviceEmulator(ecfg, report_size=report_size, pad=pad)
    device_s = [0.0]
    handle = emu.controller.handle

    def timed(data: bytes):
        t = time.perf_counter()
        try:
            return handle(data)
        finally:
            device_s[0] += time.perf_counter() - t

    emu.controller.handle = timed
    cfg = BridgeConfig(type="emulated", report_size=report_size, background=False, delta=delta,
                       compression=compression, ack_timeout_s=1.0 if link == "fs-hid" else 0.05)
    tr = EmulatedTransport(cfg, emulator=emu)
    tr.pad = pad  # bulk packets are not padded: the same transport code, the usb transport's framing
    disp = HapticDisplay(cfg, transport=tr)
    disp.open()
    rows = []
    for name, frames_ in (("full frame", seq[:1]), ("stroke edit", seq[1:])):
        wire = payload = link_s = cpu_s = tiles = 0.0
        for f in frames_:
            device_s[0] = 0.0
            t = time.perf_counter()
            r = disp.present(f)
            cpu_s += time.perf_counter() - t - device_s[0]
            if not np.array_equal(emu.active_frame, f):
                raise AssertionError(f"bench: device frame differs from host frame on {link}/{mode}")
            wire += r.wire_bytes
            payload += r.payload_bytes
            link_s += r.link_time_s
            tiles += r.tiles_sent
            if not delta:
                disp._device_frame = None  # raw: never a delta base
        n = len(frames_)
        rows.append(Row(link, name, mode, wire / n, payload / n, 0.0, link_s / n * 1000, cpu_s / n * 1000, tiles / n))
    disp.close()
    return rows[0], rows[1]


def run(edits: int = 20, seed: int = 0) -> dict:
    seq = frames(edits, seed)
    grid = Grid(1280, 800, 64, 64)
    rows: list[Row] = []
    for link, rs, pad in LINKS:
        raw_rows = None
        for mode, delta, comp in MODES:
            full, edit = _run_link(link, rs, pad, mode, delta, comp, seq)
            if mode == "raw":
                raw_rows = (full.wire_bytes, edit.wire_bytes)
            full.raw_fraction = full.wire_bytes / raw_rows[0]
            edit.raw_fraction = edit.wire_bytes / raw_rows[1]
            rows += [full, edit]
    hs_full = next(r for r in rows if r.link == "hs-hid" and r.scenario == "full frame" and r.mode == "delta+zlib")
    edit_frac = max(r.raw_fraction for r in rows if r.scenario == "stroke edit" and r.mode == "delta+zlib")
    return {
        "frames": {"panel": "1280x800", "tile": "64x64", "stroke_edits": edits, "seed": seed},
        "links": {name: {"bandwidth_B_per_s": m.bandwidth, "latency_s": m.latency_s, "duplex": m.duplex,
                         "description": m.description} for name, m in LINK_MODELS.items() if name != "none"},
        "rows": [r.__dict__ for r in rows],
        "compression": compression_study(seq, grid),
        "goals": {"stroke_edit_fraction_of_raw": {"goal": GOAL_EDIT_FRACTION, "measured_worst_link": edit_frac,
                                                  "met": edit_frac <= GOAL_EDIT_FRACTION},
                  "full_frame_hs_hid_link_s": {"goal": GOAL_FULL_HS_S, "measured": hs_full.link_ms / 1000,
                                               "met": hs_full.link_ms / 1000 <= GOAL_FULL_HS_S}},
        "environment": {"python": platform.python_version(), "numpy": np.__version__, "zlib": zlib.ZLIB_VERSION,
                        "machine": platform.machine(), "processor": platform.processor() or "unknown"},
    }


def table(result: dict) -> str:
    """Markdown tables of a `run()` result."""
    lines = ["| link | frame | mode | wire bytes | % of raw | link time (modelled) | host CPU (measured) | tiles |",
             "|---|---|---|---:|---:|---:|---:|---:|"]
    for r in result["rows"]:
        lines.append(f"| {r['link']} | {r['scenario']} | {r['mode']} | {r['wire_bytes']:,.0f} | "
                     f"{100 * r['raw_fraction']:.1f} % | {r['link_ms']:.2f} ms | {r['host_cpu_ms']:.2f} ms | "
                     f"{r['tiles']:.1f} |")
    lines += ["", "| codec | compressed / raw | encode ms / frame | decode ms / frame |", "|---|---:|---:|---:|"]
    for c in result["compression"]:
        lines.append(f"| {c['codec']} | {c['ratio']:.3f} | {c['encode_ms_per_frame']:.1f} | "
                     f"{c['decode_ms_per_frame']:.1f} |")
    g = result["goals"]
    e, f = g["stroke_edit_fraction_of_raw"], g["full_frame_hs_hid_link_s"]
    lines += ["", f"Goals: stroke edit <= {100 * e['goal']:.0f} % of raw bytes: worst link "
                  f"{100 * e['measured_worst_link']:.1f} % ({'met' if e['met'] else 'NOT met'}); full frame on "
                  f"hs-hid <= {1000 * f['goal']:.0f} ms: {1000 * f['measured']:.1f} ms modelled link time "
                  f"({'met' if f['met'] else 'NOT met'})."]
    return "\n".join(lines)


def dumps(result: dict) -> str:
    return json.dumps(result, indent=2, sort_keys=False)
