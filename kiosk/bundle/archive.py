"""Bundles: unpack safely, verify (signature, hashes, schema) and open.

A bundle is a directory shipped as a `.vtb` file (a tar, optionally gzip-compressed) holding `manifest.yaml`,
`manifest.sig`, the ONNX graphs and reference assets, all at the archive's top level. The archive comes from outside
the kiosk, so it is treated as hostile: only regular files and folders with plain relative names, no links, no
duplicates, bounded member count, sizes and expansion ratio; it is unpacked member by member into a fresh private
temporary folder and nothing is written anywhere else.
"""
from __future__ import annotations

import errno
import hashlib
import os
import shutil
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from kiosk.bundle.manifest import MAX_MANIFEST_BYTES, PATH_RE, BundleError, Manifest, parse_manifest
from kiosk.bundle.signature import verify_signature
from kiosk.bundle.weights import check_graph_weights

MANIFEST = "manifest.yaml"
SIGNATURE = "manifest.sig"
SUFFIX = ".vtb"
NO_SPACE = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)   # the disk (or a quota, or a file size limit) is full


@dataclass(frozen=True)
class ArchiveLimits:
    """What a bundle archive may contain; defaults fit a garment bundle with room to spare."""

    max_members: int = 128
    max_file_bytes: int = 256 << 20
    max_total_bytes: int = 768 << 20
    max_ratio: float = 200.0  # unpacked bytes per archive byte: beyond this it is a decompression bomb


@dataclass(frozen=True)
class Bundle:
    """A verified bundle on disk. `root` holds exactly the files the manifest lists (plus manifest and signature)."""

    root: Path
    manifest: Manifest
    key_id: str | None  # None only when opened with allow_unsigned

    def path(self, rel: str) -> Path:
        return self.root / rel

    def graph_path(self, kind: str) -> Path:
        return self.root / self.manifest.graph(kind).file

    def asset(self, name: str) -> np.ndarray:
        """A reference asset: 'sketch' (uint8), 'mask' (bool) or 'visual' (RGB uint8), at the training frame."""
        rel = self.manifest.assets.get(name)
        if rel is None:
            raise BundleError(f"bundle {self.manifest.garment_id} has no {name!r} reference asset")
        flag = cv2.IMREAD_COLOR if name == "visual" else cv2.IMREAD_GRAYSCALE
        img = cv2.imread(str(self.root / rel), flag)
        if img is None:
            raise BundleError(f"bundle asset {rel} is not a readable image")
        if name == "visual":
            return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        return img > 127 if name == "mask" else img


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _member_name(member: tarfile.TarInfo) -> str:
    name = member.name
    if name.startswith("./"):
        name = name[2:]
    name = name.rstrip("/") if member.isdir() else name
    if not name or name.startswith("/") or "\\" in name:
        raise BundleError(f"bundle member {member.name!r} has an absolute or malformed path")
    parts = name.split("/")
    if any(p in ("", ".", "..") for p in parts):
        raise BundleError(f"bundle member {member.name!r} tries to leave the bundle folder")
    if not PATH_RE.match(name):
        raise BundleError(f"bundle member {member.name!r} has characters outside [A-Za-z0-9._-]")
    return name


def safe_extract(archive: Path, dest: Path, limits: ArchiveLimits = ArchiveLimits()) -> list[str]:
    """Unpack `archive` into the empty folder `dest`; return the relative file names. Raises BundleError."""
    archive = Path(archive)
    size = archive.stat().st_size
    names: set[str] = set()
    files: list[str] = []
    total = 0
    try:
        with tarfile.open(archive, "r:*") as tar:
            for count, member in enumerate(iter(tar.next, None), start=1):
                if count > limits.max_members:
                    raise BundleError(f"bundle has more than {limits.max_members} members")
                name = _member_name(member)
                if name in names:
                    raise BundleError(f"bundle member {name!r} appears twice")
                names.add(name)
                target = dest / name
                if member.isdir():
                    target.mkdir(parents=True, exist_ok=True)
                    continue
                if not member.isreg():
                    kind = "link" if (member.issym() or member.islnk()) else "special file"
                    raise BundleError(f"bundle member {name!r} is a {kind}; only regular files are allowed")
                if member.size > limits.max_file_bytes:
                    raise BundleError(f"bundle member {name!r} is {member.size} bytes; the limit is "
                                      f"{limits.max_file_bytes}")
                total += member.size
                if total > limits.max_total_bytes:
                    raise BundleError(f"bundle unpacks to more than {limits.max_total_bytes} bytes")
                if total > limits.max_ratio * max(size, 1) and total > (1 << 20):
                    raise BundleError(f"bundle unpacks to over {limits.max_ratio:.0f}x its size: refusing a "
                                      "decompression bomb")
                target.parent.mkdir(parents=True, exist_ok=True)
                src = tar.extractfile(member)
                if src is None:
                    raise BundleError(f"bundle member {name!r} has no data")
                fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o640)
                written = 0
                with os.fdopen(fd, "wb") as out:
                    for chunk in iter(lambda: src.read(1 << 20), b""):
                        written += len(chunk)
                        if written > member.size:
                            raise BundleError(f"bundle member {name!r} holds more data than its header says")
                        out.write(chunk)
                files.append(name)
    except (tarfile.TarError, EOFError, OSError) as exc:
        if isinstance(exc, FileExistsError):
            raise BundleError(f"bundle member collides with another: {exc.filename}") from exc
        if isinstance(exc, OSError) and exc.errno in NO_SPACE:
            raise BundleError(f"no space left to unpack {archive.name} into {dest} ({exc.strerror}); free disk "
                              "space and try again (nothing was installed)") from None
        raise BundleError(f"{archive.name} is not a readable bundle archive ({exc})") from exc
    return files


def _listed_files(root: Path) -> set[str]:
    return {p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file() or p.is_symlink()}


def verify_directory(root: Path, trusted: dict | None, *, allow_unsigned: bool = False) -> Bundle:
    """Check an unpacked bundle: signature over the manifest's bytes, then the manifest schema, the exact file set,
    every hash, and every graph's external-data references (only into its shared weights file). The signature
    comes first so that an unsigned or foreign archive never reaches the YAML parser: only bytes a trusted key
    signed are parsed."""
    root = Path(root)
    mpath, spath = root / MANIFEST, root / SIGNATURE
    if not mpath.is_file():
        raise BundleError(f"bundle has no {MANIFEST}")
    if mpath.stat().st_size > MAX_MANIFEST_BYTES:
        raise BundleError(f"{MANIFEST} is {mpath.stat().st_size} bytes; the limit is {MAX_MANIFEST_BYTES}")
    manifest_bytes = mpath.read_bytes()
    kid = None
    if trusted:
        if not spath.is_file():
            raise BundleError(f"bundle is not signed (no {SIGNATURE})")
        kid = verify_signature(manifest_bytes, spath.read_bytes(), trusted)
    elif not allow_unsigned:
        raise BundleError("no trusted keys configured: cannot check the bundle's signature "
                          "(give --trusted-keys DIR, or --allow-unsigned for development)")
    manifest = parse_manifest(manifest_bytes)
    present = _listed_files(root) - {MANIFEST, SIGNATURE}
    listed = set(manifest.files)
    if listed - present:
        raise BundleError(f"bundle is missing file(s) listed in its manifest: {', '.join(sorted(listed - present))}")
    if present - listed:
        raise BundleError(f"bundle holds file(s) its manifest does not list: {', '.join(sorted(present - listed))}")
    for rel, digest in manifest.files.items():
        p = root / rel
        if p.is_symlink() or not p.is_file():
            raise BundleError(f"bundle file {rel} is not a regular file")
        if sha256_file(p) != digest:
            raise BundleError(f"bundle file {rel} does not match its SHA-256 in the manifest (corrupt or modified)")
    for spec in manifest.graphs.values():   # after the hashes: only signed bytes are parsed
        check_graph_weights(root / spec.file, None if spec.weights is None else root / spec.weights,
                            graph_name=spec.file, weights_name=spec.weights)
    return Bundle(root=root, manifest=manifest, key_id=kid)


def open_bundle(path: Path, trusted: dict | None, *, workdir: Path | None = None, allow_unsigned: bool = False,
                limits: ArchiveLimits = ArchiveLimits()) -> Bundle:
    """Verify a `.vtb` archive (unpacked into a new private folder under `workdir`) or an unpacked folder.

    On any failure the temporary folder is removed and BundleError is raised; nothing else is touched.
    """
    path = Path(path)
    if path.is_dir():
        return verify_directory(path, trusted, allow_unsigned=allow_unsigned)
    if not path.is_file():
        raise BundleError(f"{path}: no such bundle")
    if workdir is not None:
        Path(workdir).mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="vtb-", dir=workdir))
    try:
        safe_extract(path, tmp, limits)
        return verify_directory(tmp, trusted, allow_unsigned=allow_unsigned)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
