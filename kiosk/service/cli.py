"""`vtkiosk serve --config kiosk.yaml` | `vtkiosk serve --bundle FILE --device emulated`: run the kiosk daemon.

Serves the drawing page and its API on loopback, drives the haptic screen, tells systemd when it is ready and
healthy. SIGTERM (or Ctrl-C) stops it cleanly (the haptic output is blanked); SIGHUP reloads the bundles (load
beside, probe, swap, or keep the old one and log why). Never imports torch.
"""
from __future__ import annotations

import argparse
import logging
import signal
from pathlib import Path

from kiosk.ops.logsetup import configure_logging, say_line
from kiosk.ops.signals import on_signals

log = logging.getLogger("vtkiosk.serve")


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.splitlines()[0])
    p.add_argument("--config", type=Path, default=None, help="kiosk YAML (see configs/kiosk.example.yaml)")
    p.add_argument("--bundle", type=Path, action="append", default=[],
                   help="serve this bundle file or folder (repeatable; replaces the config's bundles list)")
    p.add_argument("--device", choices=("emulated", "hid", "usb"), default=None, help="haptic device transport")
    p.add_argument("--host", default=None, help="listen address (loopback unless the config allows others)")
    p.add_argument("--port", type=int, default=None, help="listen port (0: any free port)")
    p.add_argument("--trusted-keys", type=Path, default=None, help="folder of trusted *.pub keys")
    p.add_argument("--allow-unsigned", action="store_true", help="development only: serve unsigned bundles")
    p.add_argument("--control-socket", type=Path, default=None, help="operator control socket path")
    p.add_argument("--log-level", default=None, choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    p.add_argument("--exit-after-ready", action="store_true",
                   help="start, report readiness, and stop (a smoke test of the whole start-up)")
    return p


def overrides_from_args(args: argparse.Namespace) -> dict:
    o: dict = {}
    if args.bundle:
        o["bundles"] = [str(b.resolve()) for b in args.bundle]
    if args.device:
        o["device"] = {"type": args.device}
        if args.device == "emulated":
            o["device"]["report_size"] = 1024  # the emulator models high-speed HID
    server = {k: v for k, v in (("host", args.host), ("port", args.port)) if v is not None}
    if server:
        o["server"] = server
    store = {}
    if args.trusted_keys:
        store["trusted_keys"] = str(args.trusted_keys.resolve())
    if args.allow_unsigned:
        store["allow_unsigned"] = True
    if store:
        o["store"] = store
    if args.control_socket:
        o["control"] = {"socket": str(args.control_socket.resolve())}
    if args.log_level:
        o["log_level"] = args.log_level
    return o


def run(daemon, *, exit_after_ready: bool = False, out=say_line) -> int:
    """Start `daemon`, print its URL, and serve until SIGTERM/SIGINT; SIGHUP reloads."""
    with on_signals(signal.SIGHUP) as signals:
        try:
            daemon.start()
            out(f"kiosk serving {', '.join(sorted(daemon.bundles))} at {daemon.server.url}")
            if exit_after_ready:
                return 0
            while not signals.stop:
                signals.wait(1.0)
                if signals.take(signal.SIGHUP) and not signals.stop:
                    report = daemon.reload()
                    log.info("SIGHUP reload: serving %s", report.get("serving"))
            return 0
        finally:
            daemon.stop()


def main(argv: list[str], prog: str = "vtkiosk serve") -> int:
    args = build_parser(prog).parse_args(argv)
    from kiosk.service.config import load_config
    from kiosk.service.daemon import KioskDaemon

    config = load_config(args.config, overrides_from_args(args))
    configure_logging(level=config.log_level)
    return run(KioskDaemon(config), exit_after_ready=args.exit_after_ready)
