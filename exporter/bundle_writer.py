"""Write a `.vtb` bundle: hash every file into the manifest, sign it, pack a deterministic tar atomically.

The format is defined by `kiosk/bundle/manifest.py` and `kiosk/bundle/archive.py` (the reader); this writer only fills it in.
"""
from __future__ import annotations

import dataclasses
import io
import os
import tarfile
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from exporter.keys import sign_manifest
from kiosk.bundle.archive import MANIFEST, SIGNATURE, sha256_file
from kiosk.bundle.manifest import PATH_RE, BundleError, Manifest, dump_manifest


def _add_bytes(tar: tarfile.TarFile, name: str, data: bytes, mtime: int) -> None:
    info = tarfile.TarInfo(name)
    info.size, info.mtime, info.mode = len(data), mtime, 0o644
    tar.addfile(info, io.BytesIO(data))


def write_bundle(out: Path, manifest: Manifest, sources: dict[str, Path], *,
                 signing_key: Ed25519PrivateKey | None, mtime: int = 0) -> Manifest:
    """Pack `sources` (bundle-relative name -> file on disk) with a manifest listing their SHA-256.

    `manifest.files` is replaced by the computed hashes. Without a signing key the bundle is unsigned (kiosks
    refuse it unless told --allow-unsigned). Written to a temporary name and renamed, so a crash never leaves a
    half bundle under the final name. Returns the manifest as written.
    """
    for rel, src in sources.items():
        if not PATH_RE.match(rel) or rel in (MANIFEST, SIGNATURE):
            raise BundleError(f"invalid bundle file name {rel!r}")
        if not Path(src).is_file():
            raise BundleError(f"bundle source {src} is not a file")
    manifest = dataclasses.replace(manifest, files={rel: sha256_file(Path(src)) for rel, src in sources.items()})
    data = dump_manifest(manifest)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    try:
        with tarfile.open(tmp, "w", format=tarfile.PAX_FORMAT) as tar:
            _add_bytes(tar, MANIFEST, data, mtime)
            if signing_key is not None:
                _add_bytes(tar, SIGNATURE, sign_manifest(data, signing_key), mtime)
            for rel in sorted(sources):
                with open(sources[rel], "rb") as f:
                    _add_bytes(tar, rel, f.read(), mtime)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return manifest
