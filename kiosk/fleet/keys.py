"""The repository's role keys: Ed25519, one PEM file per role, written 0600 and refused when others can read it.

Root and targets keys are the offline keys (a separate folder, meant for removable media kept in a safe); the
snapshot, timestamp and channel keys are online (the publishing host uses them at every publish and refresh).
A rotated key's file is renamed `<role>.key.retired-<keyid>` and can then be destroyed.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from cryptography.hazmat.primitives.serialization import load_pem_private_key
from securesystemslib.signer import CryptoSigner

from kiosk.fleet.layout import FleetError

OFFLINE_ROLES = ("root", "targets")
ONLINE_ROLES = ("snapshot", "timestamp", "canary", "stable")


def key_file(folder: Path, role: str) -> Path:
    return Path(folder) / f"{role}.key"


def generate(folder: Path, role: str) -> CryptoSigner:
    """A new key for `role` in `folder`; never overwrites an existing key file."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    path = key_file(folder, role)
    signer = CryptoSigner.generate_ed25519()
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        raise FleetError(f"{path} already exists; refusing to overwrite a key") from None
    with os.fdopen(fd, "wb") as f:
        f.write(signer.private_bytes)
        f.flush()
        os.fsync(f.fileno())
    return signer


def load(folder: Path | None, role: str) -> CryptoSigner:
    if folder is None:
        where = "--offline-keys" if role in OFFLINE_ROLES else "--keys"
        raise FleetError(f"this needs the {role} key: give {where} DIR")
    path = key_file(folder, role)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise FleetError(f"{path}: no {role} key there") from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise FleetError(f"{path} is readable by group or others (mode {stat.S_IMODE(mode):o}); chmod 600 it")
    try:
        return CryptoSigner(load_pem_private_key(path.read_bytes(), password=None))
    except (ValueError, TypeError) as exc:
        raise FleetError(f"{path}: not an unencrypted PEM private key ({exc})") from None


def retire(folder: Path, role: str, keyid: str) -> Path:
    """Move the role's key file aside after a rotation (the operator destroys it)."""
    path = key_file(folder, role)
    dest = path.with_name(f"{path.name}.retired-{keyid[:12]}")
    os.replace(path, dest)
    return dest
