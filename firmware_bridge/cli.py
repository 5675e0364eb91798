"""`vtkiosk device probe|emulate|bench`: find the bridge, run the emulator as a process, measure the link.

Expected failures raise `BridgeError` subclasses (user_facing) that the dispatcher prints as one line.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .config import DEFAULT_PID, DEFAULT_VID, BridgeConfig, EmulatorConfig, FaultConfig
from .config_loader import build, load_yaml
from .errors import BridgeError, ConfigError, NoDeviceError
from .signals import on_signals


def _int(text: str) -> int:
    return int(text, 0)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT like 1280x800, got {text!r}") from None
    return w, h


def _load_config(args) -> BridgeConfig:
    if args.config:
        data = load_yaml(args.config, error=ConfigError, what="bridge config")
        if isinstance(data.get("bridge"), dict):
            data = data["bridge"]
        cfg = build(BridgeConfig, data, error=ConfigError, base_dir=Path(args.config).parent, where=args.config)
    else:
        cfg = BridgeConfig(type="hid")
    changes = {k: v for k, v in (("vid", args.vid), ("pid", args.pid), ("serial", args.serial),
                                 ("report_size", args.report_size), ("socket", args.socket)) if v is not None}
    if args.socket is not None and args.type is None:
        changes["type"] = "emulated"
    if args.type is not None:
        changes["type"] = args.type
    return cfg.replace(**changes, background=False, blank_on_close=False)


def cmd_probe(args) -> int:
    from .display import HapticDisplay
    from .transports import create_transport

    cfg = _load_config(args)
    types = [cfg.type] if (args.type or args.config or args.socket) else ["hid", "usb"]
    found = 0
    for t in types:
        tcfg = cfg.replace(type=t)
        transport = create_transport(tcfg)
        for cand in transport.probe():
            found += 1
            print(f"found: {cand}")
            disp = HapticDisplay(tcfg, transport=create_transport(tcfg))
            try:
                info = disp.open()
            except BridgeError as exc:
                print(f"  cannot talk to it: {exc}")
                continue
            try:
                print(f"  protocol v{info.protocol_version}, firmware {info.firmware}, serial {info.serial}")
                print(f"  panel {info.panel_w}x{info.panel_h}, max texture {info.max_texture_w}x{info.max_texture_h},"
                      f" tile {info.tile_w}x{info.tile_h}, report {tcfg.report_size} B")
                print(f"  capabilities: {', '.join(info.capabilities)}")
            finally:
                disp.close()
    if not found:
        raise NoDeviceError(f"no bridge found (looked for VID:PID {cfg.vid:04x}:{cfg.pid:04x}"
                            f"{' serial ' + cfg.serial if cfg.serial else ''} over {', '.join(types)})")
    return 0


def cmd_emulate(args) -> int:
    from .emulator import DeviceEmulator
    from .emulator.server import EmulatorServer

    w, h = args.panel
    faults = FaultConfig(seed=args.seed, drop=args.drop, corrupt=args.corrupt, duplicate=args.duplicate,
                         reorder=args.reorder, delay=args.delay, stall=args.stall)
    ecfg = EmulatorConfig(panel_w=w, panel_h=h, tile_w=args.tile, tile_h=args.tile, serial=args.serial,
                          link="none", faults=faults, host_timeout_s=args.host_timeout)
    emu = DeviceEmulator(ecfg, report_size=args.report_size)
    server = EmulatorServer(emu, args.socket)
    try:
        server.start()
    except OSError as exc:
        raise BridgeError(f"cannot listen on {args.socket} ({exc})") from None
    deadline = time.monotonic() + args.duration if args.duration > 0 else None
    with on_signals() as signals:
        print(f"emulated bridge listening on {args.socket} ({w}x{h} panel, {args.tile}x{args.tile} tiles, "
              f"{args.report_size} B reports, serial {args.serial}); Ctrl-C to stop", flush=True)
        server.serve_forever(should_stop=lambda: signals.stop or (deadline is not None
                                                                  and time.monotonic() >= deadline))
    print(f"emulated bridge stopped; {len(emu.committed)} frames committed", flush=True)
    return 0


def cmd_bench(args) -> int:
    from . import bench

    result = bench.run(edits=args.edits, seed=args.seed)
    command = "vtkiosk device bench" + (f" --edits {args.edits}" if args.edits != 20 else "") \
        + (f" --json {args.json}" if args.json else "")
    result["command"] = command
    print(bench.table(result))
    print(f"\n(command: {command}; link time is modelled on a virtual clock, host CPU is measured)")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(bench.dumps(result) + "\n")
        print(f"wrote {args.json}")
    return 0


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description="Probe, emulate and benchmark the haptic bridge.")
    sub = p.add_subparsers(dest="command", required=True)

    pr = sub.add_parser("probe", help="list matching bridge controllers and print their device info")
    pr.add_argument("--config", help="YAML with the bridge settings (a top-level 'bridge:' mapping or the settings)")
    pr.add_argument("--type", choices=["hid", "usb", "emulated"], help="only this transport (default: hid, usb)")
    pr.add_argument("--vid", type=_int, help=f"USB vendor id (default 0x{DEFAULT_VID:04x}, a placeholder)")
    pr.add_argument("--pid", type=_int, help=f"USB product id (default 0x{DEFAULT_PID:04x}, a placeholder)")
    pr.add_argument("--serial", help="only the controller with this serial number")
    pr.add_argument("--report-size", type=int, help="report size in bytes (64 full speed, 1024 high speed)")
    pr.add_argument("--socket", help="probe an emulator started with `device emulate --socket PATH`")
    pr.set_defaults(func=cmd_probe)

    em = sub.add_parser("emulate", help="run the emulated bridge controller on a unix socket")
    em.add_argument("--socket", required=True, help="unix socket path to listen on")
    em.add_argument("--panel", type=_size, default=(1280, 800), help="panel WIDTHxHEIGHT in pixels")
    em.add_argument("--tile", type=int, default=64, help="tile edge in pixels")
    em.add_argument("--report-size", type=int, default=64, help="report size in bytes")
    em.add_argument("--serial", default="EMU-0001")
    em.add_argument("--host-timeout", type=float, default=1.0, help="watchdog: blank after this many silent seconds")
    em.add_argument("--seed", type=int, default=0, help="fault injection seed")
    for name in ("drop", "corrupt", "duplicate", "reorder", "delay", "stall"):
        em.add_argument(f"--{name}", type=float, default=0.0, help=f"probability of '{name}' per report")
    em.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: run until killed)")
    em.set_defaults(func=cmd_emulate)

    be = sub.add_parser("bench", help="bytes and time per frame: raw vs delta vs delta+zlib over modelled links")
    be.add_argument("--json", help="also write the results as JSON to this path")
    be.add_argument("--edits", type=int, default=20, help="stroke edits to average over")
    be.add_argument("--seed", type=int, default=0)
    be.set_defaults(func=cmd_bench)
    return p


def main(argv: list[str], prog: str = "vtkiosk device") -> int:
    args = build_parser(prog).parse_args(argv)
    return int(args.func(args) or 0)

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
