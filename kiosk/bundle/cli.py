"""`vtkiosk bundle inspect|verify|install|list|activate|rollback|remove`: look into bundles, check them the way a
kiosk does, and operate the kiosk's bundle store.

The store's location, the trusted keys and the daemon's control socket come from the kiosk config
(`--config`, default /etc/vtkiosk/kiosk.yaml when it exists: `store.root`, `store.trusted_keys`,
`store.allow_unsigned`, `control.socket`), each overridable by an option. `activate` and `rollback` switch the
store atomically, then ask the running daemon to reload; if the daemon refuses the new version (it failed to load
or to answer its probe within the latency budget), the store is switched back and the command fails with the
daemon's reason. With no daemon running, the switch stands and the daemon serves it when it starts.

`install` and `activate` refuse a version older than the garment's newest installed one (see
`kiosk.bundle.version` for the order) unless `--allow-downgrade`; `rollback` is the explicit way back. Refusals and
allowed downgrades are logged to the systemd journal where the machine has one; the terminal gets one line.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import shutil
import sys
import tempfile
from pathlib import Path

from kiosk.contract.errors import KioskError
from kiosk.contract.garment import garment_id

DEFAULT_CONFIG = Path("/etc/vtkiosk/kiosk.yaml")
DEFAULT_STORE = Path("/var/lib/vtkiosk/bundles")
DEFAULT_CONTROL = Path("/run/vtkiosk/control.sock")
JOURNAL_SOCKET = Path("/run/systemd/journal/socket")


def _panel(args) -> tuple[float, str]:
    """The panel pitch (mm/px) to show a bundle against, and where it came from: --panel-pitch-mm, else the
    kiosk config's panel (--config, or the default config file when present), else the default known panel."""
    if getattr(args, "panel_pitch_mm", None) is not None:
        v = float(args.panel_pitch_mm)
        if not (0.01 <= v <= 10.0):
            from kiosk.contract.errors import InputError

            raise InputError(f"--panel-pitch-mm must be from 0.01 to 10 mm per pixel; got {args.panel_pitch_mm}")
        return v, "--panel-pitch-mm"
    from kiosk.service.config import PanelConfig, load_config

    path = args.config if getattr(args, "config", None) is not None else (
        DEFAULT_CONFIG if DEFAULT_CONFIG.is_file() else None)
    if path is not None:
        panel = load_config(path).panel
        return panel.pitch_mm, f"{panel.model or 'panel'} in {path}"
    panel = PanelConfig()
    return panel.pitch_mm, f"{panel.model} (default panel)"


def _summary(bundle, panel: tuple[float, str] | None = None) -> str:
    m = bundle.manifest
    consts = ", ".join(f"{k} {v:.4g}" for k, v in sorted(m.friction_constants.items()))
    lines = [f"bundle      {m.garment_id} ({m.display_name}) model {m.model_version}, method {m.method}",
             f"created     {m.created_at} by exporter {m.exporter_version}",
             f"friction    {m.friction_normalization} mapping, scale {m.friction_scale:g}"
             + (f"; constants {consts}" if consts else ""),
             f"pitch       bundle {m.pixel_pitch_mm:.4g} mm/px (what its model learned at)"
             + (f"; panel {panel[0]:.4g} mm/px ({panel[1]}): inferred at {panel[0] / m.pixel_pitch_mm:.3f} "
                f"model px per screen px" if panel else ""),
             f"panel       {m.panel_size[0]}x{m.panel_size[1]}",
             ("branches    2: visual-only and tactile-only renders run a one-branch graph" if m.branches == 2 else
              "branches    1: one network computes visual and tactile; a visual-only or tactile-only render runs "
              "the full graph and costs as much as both"),
             f"signed by   {bundle.key_id or 'NOT CHECKED'}"]
    for kind, g in m.graphs.items():
        sizes = ", ".join(f"{w}x{h}" for w, h in g.sizes)
        lines.append(f"graph       {kind:8} {g.precision:5} {g.file}  sizes {sizes}")
    for w in sorted({g.weights for g in m.graphs.values() if g.weights}):
        users = [k for k, g in m.graphs.items() if g.weights == w]
        lines.append(f"weights     {w}  {bundle.path(w).stat().st_size / 1e6:.2f} MB, read by {', '.join(users)}")
    for prec, errs in m.errors.items():
        against = "PyTorch" if prec == "fp32" else "fp32"
        lines.append(f"error       {prec:5} vs {against}: " + ", ".join(f"{k} {v:.4g}" for k, v in errs.items()))
    for k, v in m.metrics.items():
        lines.append(f"metric      {k} {v:.4g}")
    return "\n".join(lines)


def _inspect_or_verify(args) -> int:
    from kiosk.bundle.archive import open_bundle
    from kiosk.bundle.signature import load_trusted_keys

    trusted = load_trusted_keys(args.trusted_keys) if args.trusted_keys else None
    allow_unsigned = args.allow_unsigned or (args.action == "inspect" and trusted is None)
    workdir = Path(tempfile.mkdtemp(prefix="vtkiosk-bundle-"))
    try:
        bundle = open_bundle(args.file, trusted, workdir=workdir, allow_unsigned=allow_unsigned)
        print(_summary(bundle, _panel(args)))
        if args.action == "verify":
            from kiosk.bundle.probe import probe_bundle

            def show(r) -> None:
                print(f"probe       {r.graph:8} {r.size[0]}x{r.size[1]} {r.precision}: loads in {r.load_ms:.0f} ms, "
                      f"runs in {r.run_ms:.0f} ms, outputs finite", flush=True)

            probe_bundle(bundle, threads=args.threads, every_size=True, report=show)   # every declared size
            print("verified    ok")
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return 0


# -- the store ---------------------------------------------------------------------------------------------------

class StoreMissing(KioskError):
    """`bundle list` on a folder that holds no store: a typo, not an empty kiosk."""


class _Settings:
    """Store root, trusted keys, unsigned policy and control socket: options over the kiosk config over defaults."""

    def __init__(self, args):
        cfg = None
        path = args.config if args.config is not None else (DEFAULT_CONFIG if DEFAULT_CONFIG.is_file() else None)
        if path is not None:
            from kiosk.service.config import load_config

            cfg = load_config(path)
        self.root = args.store or (cfg.store.root if cfg and cfg.store.root else DEFAULT_STORE)
        self.trusted_keys = args.trusted_keys or (cfg.store.trusted_keys if cfg else None)
        self.allow_unsigned = bool(args.allow_unsigned or (cfg.store.allow_unsigned if cfg else False))
        self.control = args.control_socket or (cfg.control.socket if cfg and cfg.control.socket else DEFAULT_CONTROL)

    def store(self, threads: int = 2):
        from kiosk.bundle.store import BundleStore

        return BundleStore(self.root, self.trusted_keys, allow_unsigned=self.allow_unsigned, probe_threads=threads)


def _precision_text(precisions: dict[str, str]) -> str:
    kinds = set(precisions.values())
    if len(kinds) == 1:
        return kinds.pop()
    return " ".join(f"{k}:{v}" for k, v in sorted(precisions.items())) or "-"


def _list(settings: _Settings, as_json: bool) -> int:
    if not Path(settings.root).is_dir():
        raise StoreMissing(f"no bundle store at {settings.root} (install a bundle there first, or name the store "
                           "with --store or store.root in the config)")
    items = settings.store().list()
    if as_json:
        print(json.dumps([s.to_json() for s in items], indent=1))
        return 0
    if not items:
        print(f"no bundles installed in {settings.root}")
        return 0
    rows = [("GARMENT", "VERSION", "STATE", "SIGNED BY", "PRECISION", "INSTALLED")]
    for s in items:
        state = "active" if s.active else "previous" if s.previous else "-"
        rows.append((s.garment, s.version, state, s.key_id or "UNSIGNED", _precision_text(s.precisions),
                     (s.installed_at or "?")[:19].replace("T", " ")))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip())
    return 0


def _tell_daemon(settings: _Settings, garment: str, version: str, undo) -> int:
    """Ask the daemon to reload; on refusal for this garment, run `undo` (restore the store) and fail."""
    from kiosk.ops.control import NoDaemonError, send_control

    try:
        reply = send_control(settings.control, {"op": "reload"}, timeout_s=120.0)
    except NoDaemonError:
        print(f"no kiosk daemon is running (nothing listens on {settings.control}); "
              f"it will serve {garment} {version} when it starts")
        return 0
    mine = [e for e in reply.get("kept", []) + reply.get("failed", [])
            if e.get("garment") == garment or str(e.get("source", "")).startswith(f"store:{garment}/")]
    if mine:
        undo()
        why = "; ".join(e.get("reason", "?") for e in mine)
        print(f"the daemon refused {garment} {version} and keeps serving what it served: {why}", file=sys.stderr)
        print(f"store switched back; {garment} {version} stays installed but inactive", file=sys.stderr)
        return 1
    if not reply.get("ok", False) and "error" in reply and not any(k in reply for k in ("kept", "failed")):
        print(f"the daemon could not reload: {reply['error']}", file=sys.stderr)
        return 1
    serving = reply.get("serving", {})
    print(f"daemon reloaded: serving {', '.join(f'{g} ({k})' for g, k in serving.items()) or 'nothing'}")
    for e in reply.get("kept", []) + reply.get("failed", []):  # other garments' trouble: say it, don't fail
        print(f"warning: {e.get('garment') or e.get('source')}: {e.get('reason')}", file=sys.stderr)
    return 0


def _switch(settings: _Settings, args, action: str) -> int:
    store = settings.store(args.threads)
    before = {g: store.links(g) for g in store.active()}
    if action == "activate":
        now = store.activate(args.garment, args.version, allow_downgrade=args.allow_downgrade)
    else:
        now = store.rollback(args.garment)
    old = before.get(now.garment)
    if action == "rollback":
        print(f"rolled back {now.garment} to {now.version}" + (f" (from {old[0]})" if old and old[0] else "")
              + f"; history: {' -> '.join(store.history(now.garment)) or now.version}")
    elif old is not None and old[0] == now.version:
        print(f"{now.garment} {now.version} is already active")
    else:
        print(f"activated {now.garment} {now.version}" + (f" (previous: {old[0]})" if old else ""))
    if args.no_reload:
        return 0

    def undo() -> None:
        store.restore(now.garment, current=old[0] if old else None, previous=old[1] if old else None)

    return _tell_daemon(settings, now.garment, now.version, undo)


def _store_action(args) -> int:
    settings = _Settings(args)
    if args.action == "list":
        return _list(settings, args.json)
    store = settings.store(args.threads)
    if args.action == "install":
        for f in args.files:
            s = store.install(f, allow_downgrade=args.allow_downgrade)
            print(f"installed {s.garment} {s.version} (signed by {s.key_id or 'nobody: UNSIGNED'}, "
                  f"{_precision_text(s.precisions)}) into {s.path}")
            if args.activate:
                args.garment, args.version = s.garment, s.version
                rc = _switch(settings, args, "activate")
                if rc:
                    return rc
        return 0
    if args.action in ("activate", "rollback"):
        return _switch(settings, args, args.action)
    if args.action == "remove":
        store.remove(args.garment, args.version)
        print(f"removed {args.garment} {args.version}")
        return 0
    raise AssertionError(args.action)


def build_parser(prog: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="action", required=True)
    for name, text in (("inspect", "print the manifest summary (schema-checked, signature not required)"),
                       ("verify", "check signature, hashes, schema, and probe every graph in ONNX Runtime")):
        p = sub.add_parser(name, help=text)
        p.add_argument("file", type=Path)
        p.add_argument("--trusted-keys", type=Path, default=None, help="folder of trusted *.pub keys")
        p.add_argument("--allow-unsigned", action="store_true", help="development only: skip the signature")
        p.add_argument("--threads", type=int, default=2)
        p.add_argument("--config", type=Path, default=None,
                       help=f"kiosk config whose panel the bundle's pitch is shown against (default {DEFAULT_CONFIG} "
                            "if present, else the default known panel)")
        p.add_argument("--panel-pitch-mm", type=float, default=None, help="show against this panel pitch instead")

    def store_parser(name: str, text: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=text, description=text)
        p.add_argument("--config", type=Path, default=None,
                       help=f"kiosk config for store/keys/control socket (default {DEFAULT_CONFIG} if present)")
        p.add_argument("--store", type=Path, default=None, help=f"bundle store folder (default {DEFAULT_STORE})")
        p.add_argument("--trusted-keys", type=Path, default=None, help="folder of trusted *.pub keys")
        p.add_argument("--allow-unsigned", action="store_true", help="development only: accept unsigned bundles")
        p.add_argument("--control-socket", type=Path, default=None,
                       help=f"the daemon's control socket (default {DEFAULT_CONTROL})")
        p.add_argument("--threads", type=int, default=2, help="ONNX Runtime threads for the install probe")
        return p

    p = store_parser("install", "verify bundles (signature, hashes, ORT probe) and add them to the store")
    p.add_argument("files", type=Path, nargs="+")
    p.add_argument("--activate", action="store_true", help="activate each one after installing it")
    p.add_argument("--allow-downgrade", action="store_true",
                   help="install (and activate) a version older than the garment's newest installed one")
    p.add_argument("--no-reload", action="store_true", help="with --activate: do not tell the daemon")
    p = store_parser("list", "installed versions: active, previous, signing key, precision")
    p.add_argument("--json", action="store_true")
    p = store_parser("activate", "make a version the active one and tell the daemon")
    p.add_argument("garment")
    p.add_argument("version")
    p.add_argument("--allow-downgrade", action="store_true",
                   help="activate a version older than the garment's newest installed one")
    p.add_argument("--no-reload", action="store_true", help="switch the store only")
    p = store_parser("rollback", "go one step back in the activation history and tell the daemon")
    p.add_argument("garment")
    p.set_defaults(allow_downgrade=True)   # rolling back is the operator's explicit step back
    p.add_argument("--no-reload", action="store_true", help="switch the store only")
    p = store_parser("remove", "delete an installed version (not the active one)")
    p.add_argument("garment")
    p.add_argument("version")
    return parser


def _log_store_decisions() -> None:
    """The store's decisions (a refused downgrade above all) go to the journal where the machine has one, so they
    are on record however the command was run; the terminal gets the one-line result only."""
    if logging.getLogger().handlers:
        return   # logging is set up already (a daemon or a test runs us)
    if JOURNAL_SOCKET.exists() and importlib.util.find_spec("systemd") is not None:
        from kiosk.ops.logsetup import configure_logging

        configure_logging(level="INFO", journal=True)
    else:
        logging.getLogger("kiosk.bundle").addHandler(logging.NullHandler())


def main(argv: list[str], prog: str = "vtkiosk bundle") -> int:
    args = build_parser(prog).parse_args(argv)
    if getattr(args, "garment", None):
        args.garment = garment_id(args.garment)   # DenimShorts and the dataset folder name work too
    if args.action in ("inspect", "verify"):
        return _inspect_or_verify(args)
    _log_store_decisions()
    return _store_action(args)
