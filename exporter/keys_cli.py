"""`vtkiosk keys generate --out DIR [--name NAME]`: an operator's Ed25519 signing key pair."""
from __future__ import annotations

import argparse
from pathlib import Path


def main(argv: list[str], prog: str = "vtkiosk keys") -> int:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__)
    sub = parser.add_subparsers(dest="action", required=True)
    gen = sub.add_parser("generate", help="make a key pair: NAME.key (private, 0600) and NAME.pub")
    gen.add_argument("--out", type=Path, required=True, help="folder for the key files")
    gen.add_argument("--name", default="operator", help="file name stem (default: operator)")
    args = parser.parse_args(argv)
    from exporter.keys import generate_keypair
    from kiosk.bundle.signature import key_id, load_public_key

    priv, pub = generate_keypair(args.out, args.name)
    print(f"private key: {priv} (keep it on the signing workstation)")
    print(f"public key:  {pub} (copy to each kiosk's trusted-keys folder)")
    print(f"key id:      {key_id(load_public_key(pub))}")
    return 0
