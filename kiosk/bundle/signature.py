"""Detached Ed25519 signatures over bundle manifests: the file format, trusted keys, verification.

The exporter signs (it holds the private key); the kiosk only verifies, against public keys an operator placed in
its trusted-keys folder. Since the manifest lists the SHA-256 of every other file, one signature covers the bundle.

`manifest.sig` is three lines of ASCII:
    vtkiosk-signature-v1
    key-id: <16 hex digits: the start of SHA-256 of the raw public key>
    ed25519: <base64 of the 64-byte signature over manifest.yaml's exact bytes>
"""
from __future__ import annotations

import base64
import binascii
import hashlib
import re
from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from kiosk.bundle.manifest import BundleError

MAGIC = "vtkiosk-signature-v1"
_KEY_ID_RE = re.compile(r"^[0-9a-f]{16}$")
MAX_KEY_FILE_BYTES = 16 << 10


def key_id(public_key: Ed25519PublicKey) -> str:
    raw = public_key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return hashlib.sha256(raw).hexdigest()[:16]


def format_signature(kid: str, signature: bytes) -> bytes:
    if not _KEY_ID_RE.match(kid) or len(signature) != 64:
        raise BundleError("a signature needs a 16-hex-digit key id and 64 signature bytes")
    return f"{MAGIC}\nkey-id: {kid}\ned25519: {base64.b64encode(signature).decode()}\n".encode()


def parse_signature(data: bytes) -> tuple[str, bytes]:
    """`manifest.sig` bytes -> (key id, 64-byte signature)."""
    try:
        lines = data.decode("ascii").strip().split("\n")
    except UnicodeDecodeError as exc:
        raise BundleError("manifest.sig is not ASCII text") from exc
    if len(lines) != 3 or lines[0] != MAGIC or not lines[1].startswith("key-id: ") \
            or not lines[2].startswith("ed25519: "):
        raise BundleError(f"manifest.sig is not a {MAGIC} signature file")
    kid = lines[1][len("key-id: "):]
    if not _KEY_ID_RE.match(kid):
        raise BundleError("manifest.sig has an invalid key id")
    try:
        sig = base64.b64decode(lines[2][len("ed25519: "):], validate=True)
    except (binascii.Error, ValueError) as exc:
        raise BundleError("manifest.sig has an invalid base64 signature") from exc
    if len(sig) != 64:
        raise BundleError(f"manifest.sig holds {len(sig)} signature bytes; Ed25519 needs 64")
    return kid, sig


def load_public_key(path: Path) -> Ed25519PublicKey:
    data = Path(path).read_bytes()
    if len(data) > MAX_KEY_FILE_BYTES:
        raise BundleError(f"{path}: too large to be a public key")
    try:
        key = serialization.load_pem_public_key(data)
    except ValueError as exc:
        raise BundleError(f"{path}: not a PEM public key") from exc
    if not isinstance(key, Ed25519PublicKey):
        raise BundleError(f"{path}: not an Ed25519 public key")
    return key


def load_trusted_keys(folder: Path) -> dict[str, Ed25519PublicKey]:
    """Every `*.pub` in `folder`, by key id. An empty or missing folder is an error: nothing could verify."""
    folder = Path(folder)
    if not folder.is_dir():
        raise BundleError(f"trusted-keys folder {folder} does not exist")
    keys = {}
    for path in sorted(folder.glob("*.pub")):
        key = load_public_key(path)
        keys[key_id(key)] = key
    if not keys:
        raise BundleError(f"trusted-keys folder {folder} holds no *.pub keys")
    return keys


def verify_signature(manifest_bytes: bytes, sig_bytes: bytes, trusted: dict[str, Ed25519PublicKey]) -> str:
    """Check the detached signature; return the signing key's id."""
    kid, sig = parse_signature(sig_bytes)
    key = trusted.get(kid)
    if key is None:
        raise BundleError(f"bundle is signed by key {kid}, which is not among the trusted keys "
                          f"({', '.join(sorted(trusted)) or 'none'})")
    try:
        key.verify(sig, manifest_bytes)
    except InvalidSignature as exc:
        raise BundleError(f"signature by key {kid} does not match the manifest (modified after signing?)") from exc
    return kid
