"""`vtkiosk fleet init|publish|promote|withdraw|rotate-key|refresh|status|sync`: publish bundles to a TUF update
repository (operator) and pull them onto a kiosk (sync). The walkthrough is docs/fleet.md.

Publishing commands take `--repo` (the folder a static web server serves), `--keys` (online keys: snapshot,
timestamp, canary, stable) and, for the key ceremony and rotations, `--offline-keys` (root, targets). `sync` and
kiosk-side `status` read the kiosk config (`--config`, default /etc/vtkiosk/kiosk.yaml): its `fleet`, `store` and
`control` sections.

Exit status of `sync`: 0 when it finished ok, 75 when the repository could not be reached (the kiosk keeps serving;
the timer tries again), 1 when something was refused (an attack, or a bundle that failed its checks).
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from datetime import datetime, timezone
from pathlib import Path

from kiosk.fleet.layout import CHANNELS, FleetError, rollout_bucket

DEFAULT_CONFIG = Path("/etc/vtkiosk/kiosk.yaml")
EXIT_OFFLINE = 75  # EX_TEMPFAIL


def _repo(args):
    from kiosk.fleet.repo import FleetRepository

    return FleetRepository(args.repo, keys=getattr(args, "keys", None), offline_keys=getattr(args, "offline_keys", None))


def _init(args) -> int:
    anchor = _repo(args).init()
    print(f"created the fleet repository in {args.repo} (serve this folder; never the key folders)")
    print(f"online keys:  {args.keys}/{{snapshot,timestamp,canary,stable}}.key (stay on the publishing host)")
    print(f"offline keys: {args.offline_keys}/{{root,targets}}.key (move to offline media now)")
    print(f"trust anchor: {anchor} (copy to every kiosk as fleet.root, e.g. /etc/vtkiosk/fleet-root.json)")
    return 0


def _publish(args) -> int:
    from kiosk.bundle.archive import open_bundle
    from kiosk.bundle.signature import load_trusted_keys

    workdir = Path(tempfile.mkdtemp(prefix="vtkiosk-fleet-"))
    try:
        # The kiosks will check the bundle's own signature too: refuse here what they would refuse there.
        m = open_bundle(args.bundle, load_trusted_keys(args.trusted_keys), workdir=workdir).manifest
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    r = _repo(args).publish(args.bundle, args.channel, garment=m.garment_id, version=m.model_version,
                            rollout=args.rollout, min_runtime=args.min_runtime)
    print(f"published {r.garment} {r.version} to {r.channel} ({r.rollout}% of its kiosks, runtime >= "
          f"{r.min_runtime}) as {r.path}")
    return 0


def _promote(args) -> int:
    r = _repo(args).promote(args.garment, args.version, rollout=args.rollout)
    print(f"{r.garment} {r.version} is on {r.channel} for {r.rollout}% of its kiosks")
    return 0


def _withdraw(args) -> int:
    channels = CHANNELS if args.channel == "all" else (args.channel,)
    for r in _repo(args).withdraw(args.garment, args.version, channels):
        print(f"withdrew {r.garment} {r.version} from {r.channel}: its kiosks go back to the newest installed "
              "version that is not withdrawn at their next sync")
    return 0


def _rotate(args) -> int:
    old, new, retired = _repo(args).rotate_key(args.role)
    print(f"rotated the {args.role} key: {old[:16]} -> {new[:16]}; old key file moved to {retired} (destroy it)")
    return 0


def _refresh(args) -> int:
    repo = _repo(args)
    print(f"re-signed: {', '.join(repo.refresh())}")
    for w in repo.offline_expiry_warnings():
        print(f"warning: {w}", file=sys.stderr)
    return 0


def _when(dt: datetime) -> str:
    left = dt - datetime.now(timezone.utc)
    days = left.total_seconds() / 86400
    return f"{dt.isoformat()} ({days:.1f} days left)" if days >= 0 else f"{dt.isoformat()} (EXPIRED)"


def _status_repo(args) -> int:
    repo = _repo(args)
    bucket = rollout_bucket(args.kiosk_id) if args.kiosk_id else None
    if args.json:
        doc = {"roles": [{"role": s.role, "version": s.version, "expires": s.expires.isoformat(),
                          "keyids": list(s.keyids)} for s in repo.status()],
               "releases": [r.__dict__ for c in CHANNELS for r in repo.releases(c)]}
        if bucket is not None:
            doc["kiosk"] = {"id": args.kiosk_id, "bucket": bucket}
        print(json.dumps(doc, indent=1))
        return 0
    print(f"{'ROLE':10} {'VERSION':>7}  KEY           EXPIRES")
    for s in repo.status():
        print(f"{s.role:10} {s.version:>7}  {s.keyids[0][:12]}  {_when(s.expires)}")
    rows = [("CHANNEL", "GARMENT", "VERSION", "ROLLOUT", "RUNTIME", "STATE")]
    for c in CHANNELS:
        for r in repo.releases(c):
            state = "withdrawn" if r.withdrawn else ("reaches this kiosk" if bucket is not None and r.reaches(
                args.kiosk_id) else ("not this kiosk" if bucket is not None else "live"))
            rows.append((c, r.garment, r.version, f"{r.rollout}%", f">={r.min_runtime}", state))
    print()
    if len(rows) == 1:
        print("no bundles published yet")
    else:
        widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
        for row in rows:
            print("  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip())
    for w in repo.offline_expiry_warnings():
        print(f"warning: {w}", file=sys.stderr)
    if bucket is not None:
        print(f"\nkiosk {args.kiosk_id} is in rollout bucket {bucket} (a rollout of P% reaches it when {bucket} < P)")
    return 0


def _kiosk_config(args):
    from kiosk.service.config import load_config

    path = args.config if args.config is not None else DEFAULT_CONFIG
    cfg = load_config(path)
    if not cfg.fleet.enabled:
        raise FleetError(f"{path}: no fleet.url; this kiosk takes no part in a fleet (see docs/fleet.md)")
    if cfg.store.root is None:
        raise FleetError(f"{path}: fleet sync needs store.root (where the bundles are installed)")
    return cfg


def _status_kiosk(args) -> int:
    from kiosk.fleet.state import STATE_FILE, load_state, section

    cfg = _kiosk_config(args)
    path = cfg.fleet.state_dir / STATE_FILE
    s = section(path, cfg.fleet.stale_after_s)
    st = load_state(path)
    if args.json:
        print(json.dumps({"fleet": s, "garments": st.get("last_garments", [])}, indent=1))
        return 0
    age = "never synced" if s["metadata_age_s"] is None else f"{s['metadata_age_s']:.0f} s"
    print(f"kiosk       {cfg.fleet.kiosk_id} on {cfg.fleet.channel} (rollout bucket "
          f"{rollout_bucket(cfg.fleet.kiosk_id)}), repository {cfg.fleet.url}")
    print(f"metadata    {age} old{' (STALE)' if s['stale'] else ''}, timestamp v{s['timestamp_version']}")
    print(f"last sync   {s['last_result']}: {s['last_detail']} ({s['consecutive_failures']} failures in a row)")
    for g in st.get("last_garments", []):
        print(f"garment     {g['garment']}: {g['outcome']}, active {g['active']}: {g['detail']}")
    return 0


def _sync(args) -> int:
    from kiosk.bundle.store import BundleStore
    from kiosk.fleet.sync import FleetSync
    from kiosk.ops.logsetup import configure_logging, stderr_is_journal

    cfg = _kiosk_config(args)
    # Under systemd the log records (with structured fields) are the report; on a terminal the lines below are,
    # and only warnings (retries, refusals) are logged beside them.
    journal = stderr_is_journal()
    configure_logging(level=cfg.log_level if journal else "WARNING")
    if cfg.store.trusted_keys is None:
        raise FleetError("fleet sync needs store.trusted_keys: fleet bundles are always signature-checked")
    store = BundleStore(cfg.store.root, cfg.store.trusted_keys, probe_threads=cfg.inference.threads)
    report = FleetSync(cfg.fleet, store, control_socket=cfg.control.socket).run()
    if args.json:
        print(json.dumps(report.to_json(), indent=1))
    elif not journal:
        for g in report.garments:
            print(f"{g.garment}: {g.outcome}: {g.detail}")
        print(f"sync {report.result}: {report.detail}")
    return {"ok": 0, "offline": EXIT_OFFLINE}.get(report.result, 1)


def build_parser(prog: str) -> argparse.ArgumentParser:
    from kiosk.fleet.repo import ROLES

    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="action", required=True)

    def repo_parser(name: str, text: str, *, offline: bool = False) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=text, description=text)
        p.add_argument("--repo", type=Path, required=True, help="the repository folder (what the web server serves)")
        p.add_argument("--keys", type=Path, required=name != "status", help="folder of the online role keys")
        if offline:
            p.add_argument("--offline-keys", type=Path, required=name == "init",
                           help="folder of the offline keys (root, targets)")
        return p

    repo_parser("init", "key ceremony: make every role's key and version 1 of the repository", offline=True)
    p = repo_parser("publish", "add a bundle to a channel (canary first)")
    p.add_argument("bundle", type=Path)
    p.add_argument("--channel", choices=CHANNELS, default="canary")
    p.add_argument("--rollout", type=int, default=100, help="percentage of the channel's kiosks (default 100)")
    p.add_argument("--min-runtime", default="0", help="oldest vtkiosk runtime version that may install it")
    p.add_argument("--trusted-keys", type=Path, required=True,
                   help="the bundle keys the kiosks trust (*.pub); the bundle's signature is checked against them")
    p = repo_parser("promote", "put a canary release on stable, or change its stable rollout percentage")
    p.add_argument("garment")
    p.add_argument("version")
    p.add_argument("--rollout", type=int, default=100, help="percentage of stable kiosks (default 100)")
    p = repo_parser("withdraw", "emergency rollback: kiosks running this version go back to their previous one")
    p.add_argument("garment")
    p.add_argument("version")
    p.add_argument("--channel", choices=(*CHANNELS, "all"), default="all")
    p = repo_parser("rotate-key", "replace a role's key (needs --offline-keys: root signs the top-level roles' keys, "
                    "targets the channels')",
                    offline=True)
    p.add_argument("role", choices=ROLES)
    repo_parser("refresh", "re-sign the timestamp and the roles near expiry (root and targets with --offline-keys); "
                "run it hourly", offline=True)
    p = sub.add_parser("status", help="the repository's roles and releases (--repo), or this kiosk's sync state")
    p.add_argument("--repo", type=Path, default=None, help="show this repository (operator side)")
    p.add_argument("--kiosk-id", default=None, help="with --repo: which releases reach this kiosk")
    p.add_argument("--config", type=Path, default=None, help=f"kiosk side: the kiosk config (default {DEFAULT_CONFIG})")
    p.add_argument("--json", action="store_true")
    p = sub.add_parser("sync", help="kiosk: fetch what the repository offers this kiosk and install it")
    p.add_argument("--config", type=Path, default=None, help=f"the kiosk config (default {DEFAULT_CONFIG})")
    p.add_argument("--json", action="store_true", help="print the sync report as JSON")
    return parser


def main(argv: list[str], prog: str = "vtkiosk fleet") -> int:
    try:
        import tuf  # noqa: F401 - the one dependency this room adds
    except ModuleNotFoundError:
        print(f"{prog}: python-tuf is not installed (pip install 'vtkiosk[fleet]')", file=sys.stderr)
        return 2
    args = build_parser(prog).parse_args(argv)
    if args.action == "status":
        return _status_repo(args) if args.repo is not None else _status_kiosk(args)
    return {"init": _init, "publish": _publish, "promote": _promote, "withdraw": _withdraw, "rotate-key": _rotate,
            "refresh": _refresh, "sync": _sync}[args.action](args)
