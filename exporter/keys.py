"""Operator signing keys: generate a pair, load the private half, sign a manifest.

Only the exporter (on the operator's workstation) holds private keys; kiosks get the `.pub` file in their
trusted-keys folder. Private keys are written 0600 and refused if group/world readable.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from kiosk.bundle.manifest import BundleError
from kiosk.bundle.signature import format_signature, key_id


def generate_keypair(folder: Path, name: str) -> tuple[Path, Path]:
    """Write `<name>.key` (PEM PKCS#8, mode 0600) and `<name>.pub` (PEM SubjectPublicKeyInfo). Never overwrites."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    priv_path, pub_path = folder / f"{name}.key", folder / f"{name}.pub"
    for p in (priv_path, pub_path):
        if p.exists():
            raise BundleError(f"{p} already exists; refusing to overwrite a key")
    key = Ed25519PrivateKey.generate()
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                            serialization.NoEncryption())
    fd = os.open(priv_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    pub_path.write_bytes(key.public_key().public_bytes(serialization.Encoding.PEM,
                                                       serialization.PublicFormat.SubjectPublicKeyInfo))
    return priv_path, pub_path


def load_private_key(path: Path) -> Ed25519PrivateKey:
    path = Path(path)
    mode = path.stat().st_mode
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise BundleError(f"{path} is readable by group or others (mode {stat.S_IMODE(mode):o}); chmod 600 it")
    try:
        key = serialization.load_pem_private_key(path.read_bytes(), password=None)
    except (ValueError, TypeError) as exc:
        raise BundleError(f"{path}: not an unencrypted PEM private key") from exc
    if not isinstance(key, Ed25519PrivateKey):
        raise BundleError(f"{path}: not an Ed25519 private key")
    return key


def sign_manifest(manifest_bytes: bytes, key: Ed25519PrivateKey) -> bytes:
    """The `manifest.sig` file content for these exact manifest bytes."""
    return format_signature(key_id(key.public_key()), key.sign(manifest_bytes))
