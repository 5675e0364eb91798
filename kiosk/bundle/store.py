"""The bundle store on a kiosk: verified bundles installed side by side, one active version per garment.

Layout (every switch is one atomic rename, so a reader sees the old or the new state, never a mix):

    <root>/.lock                          flock: one mutating operation at a time (install/activate/...)
    <root>/.incoming/<random>/            an install in progress; never listed; cleaned by the next operation
    <root>/<garment>/<version>/           the extracted, verified bundle (exactly the manifest's files)
    <root>/<garment>/current -> <version> the active version (relative symlink, replaced by rename)
    <root>/<garment>/previous -> <version> what `rollback` goes back to
    <root>/<garment>/.meta/<version>.json when and from what it was installed, who signed it

Install verifies before anything becomes visible: the archive is unpacked as hostile input into `.incoming`,
checked (schema, signature against the trusted keys, the exact file set, every hash), probed in ONNX Runtime, and
only then renamed to `<garment>/<version>`. A crash at any point leaves either nothing or the complete bundle.
The daemon serves `current` of every garment; `vtkiosk bundle activate` switches it and asks the daemon to reload
(the daemon loads beside, probes, swaps or keeps the old one).

Versions only go forward: installing or activating a version that ranks below the garment's newest installed one
(`kiosk.bundle.version` defines the order) is refused unless the operator says `allow_downgrade`, so a signed but
old bundle cannot quietly replace a newer one. `rollback` is the operator's explicit step back and needs no flag.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import re
import secrets
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from kiosk.bundle.archive import MANIFEST, NO_SPACE, ArchiveLimits, Bundle, safe_extract, sha256_file, verify_directory
from kiosk.bundle.durable import atomic_write, fsync_dir
from kiosk.contract.errors import KioskError
from kiosk.bundle.manifest import BundleError
from kiosk.bundle.signature import load_trusted_keys
from kiosk.bundle.version import VERSION_RE, newest, parse_version

log = logging.getLogger(__name__)
CURRENT, PREVIOUS, META, INCOMING, LOCK = "current", "previous", ".meta", ".incoming", ".lock"
HISTORY = ".history"   # under META; cannot clash with a version's metadata file (<version>.json)
HISTORY_LENGTH = 64
GARMENT_RE = re.compile(r"\A[a-z0-9][a-z0-9._-]{0,63}\Z")
RESERVED = {CURRENT, PREVIOUS}


class StoreError(KioskError):
    """A store operation that cannot be done as asked; the message says why and what exists."""


class StoreBusyError(StoreError):
    """Another bundle operation holds the store lock."""


class DowngradeError(StoreError):
    """A version older than the garment's newest installed one, without `allow_downgrade`."""


@dataclass(frozen=True)
class StoredBundle:
    garment: str
    version: str
    path: Path  # the verified, extracted bundle directory
    active: bool
    previous: bool
    display_name: str = ""
    key_id: str | None = None  # who signed it (None: installed unsigned, development only)
    precisions: dict[str, str] = field(default_factory=dict)  # graph kind -> precision
    installed_at: str | None = None
    archive_sha256: str | None = None

    def to_json(self) -> dict:
        return {"garment": self.garment, "version": self.version, "path": str(self.path), "active": self.active,
                "previous": self.previous, "display_name": self.display_name, "key_id": self.key_id,
                "precisions": self.precisions, "installed_at": self.installed_at,
                "archive_sha256": self.archive_sha256}


def _fsync_tree(root: Path) -> None:
    for dirpath, _, files in os.walk(root):
        for name in files:
            fd = os.open(os.path.join(dirpath, name), os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        fsync_dir(Path(dirpath))


def _check_name(kind: str, value: str) -> None:
    pattern = GARMENT_RE if kind == "garment" else VERSION_RE
    if not isinstance(value, str) or not pattern.match(value) or value in RESERVED:
        raise StoreError(f"{value!r} is not a valid {kind} name")


class BundleStore:
    """Operate the store under `root`. Reading (`list`, `active`) needs no keys; install/activate verify against
    the `*.pub` keys in `trusted_keys_dir` (or, with `allow_unsigned`, accept unsigned bundles: development only)."""

    def __init__(self, root: Path, trusted_keys_dir: Path | None, *, allow_unsigned: bool = False,
                 probe_threads: int = 2, lock_timeout_s: float = 30.0, limits: ArchiveLimits = ArchiveLimits()):
        self.root = Path(root)
        self.trusted_keys_dir = Path(trusted_keys_dir) if trusted_keys_dir is not None else None
        self.allow_unsigned = allow_unsigned
        self.probe_threads = probe_threads
        self.lock_timeout_s = lock_timeout_s
        self.limits = limits

    # -- locking and housekeeping ------------------------------------------------------------------------------
    @contextlib.contextmanager
    def _locked(self) -> Iterator[None]:
        self.root.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.root / LOCK, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o640)
        try:
            self._adopt(self.root / LOCK)
            deadline = time.monotonic() + self.lock_timeout_s
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except OSError as exc:
                    if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                        raise
                    if time.monotonic() >= deadline:
                        raise StoreBusyError(f"another bundle operation holds {self.root / LOCK} "
                                             f"(waited {self.lock_timeout_s:g} s); try again when it is done") from None
                    time.sleep(0.05)
            self._clean_incoming()
            yield
        finally:
            os.close(fd)  # releases the lock

    def _clean_incoming(self) -> None:
        """Remove what crashed operations left (we hold the lock, so nothing is in progress): unpacked installs
        in .incoming, and version folders without their .meta record (a crash between install's two renames,
        or in the middle of a remove)."""
        incoming = self.root / INCOMING
        if incoming.is_dir():
            for p in incoming.iterdir():
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    p.unlink()
        for g in self._garments():
            gdir = self.root / g
            keep = {self._link(g, CURRENT), self._link(g, PREVIOUS)}
            for p in gdir.iterdir():
                if p.name.startswith(".") and p.name not in (META,) and p.is_symlink():
                    p.unlink()  # a link that a crash left before its rename
                elif (VERSION_RE.match(p.name) and p.name not in RESERVED and p.name not in keep
                      and p.is_dir() and not p.is_symlink() and not (gdir / META / f"{p.name}.json").is_file()):
                    shutil.rmtree(p, ignore_errors=True)

    def _adopt(self, path: Path) -> None:
        """Run as root (sudo vtkiosk bundle ...): give what we created to the store's owner (the vtkiosk user)."""
        if os.geteuid() != 0:
            return
        st = self.root.stat()
        if st.st_uid == 0 and st.st_gid == 0:
            return
        if path.is_symlink() or not path.is_dir():
            os.lchown(path, st.st_uid, st.st_gid)
            return
        for dirpath, dirs, files in os.walk(path):
            for name in [*dirs, *files]:
                os.lchown(os.path.join(dirpath, name), st.st_uid, st.st_gid)
        os.lchown(path, st.st_uid, st.st_gid)

    # -- reading -----------------------------------------------------------------------------------------------
    def _link(self, garment: str, name: str) -> str | None:
        link = self.root / garment / name
        try:
            target = os.readlink(link)
        except OSError:
            return None
        if "/" in target or not VERSION_RE.match(target) or not (self.root / garment / target).is_dir():
            return None  # dangling or not ours: treated as unset
        return target

    def _versions(self, garment: str) -> list[str]:
        gdir = self.root / garment
        out = []
        for p in gdir.iterdir():
            if p.name in RESERVED or p.name.startswith(".") or p.is_symlink() or not p.is_dir():
                continue
            if (gdir / META / f"{p.name}.json").is_file():
                out.append(p.name)
        return out

    def _garments(self) -> list[str]:
        if not self.root.is_dir():
            return []
        return sorted(p.name for p in self.root.iterdir()
                      if p.is_dir() and not p.is_symlink() and GARMENT_RE.match(p.name))

    def _stored(self, garment: str, version: str, current: str | None, previous: str | None) -> StoredBundle:
        meta_path = self.root / garment / META / f"{version}.json"
        try:
            meta = json.loads(meta_path.read_text())
        except (OSError, ValueError):
            meta = {}
        return StoredBundle(garment, version, self.root / garment / version, version == current,
                            version == previous, meta.get("display_name", ""), meta.get("key_id"),
                            dict(meta.get("precisions", {})), meta.get("installed_at"), meta.get("archive_sha256"))

    def list(self) -> list[StoredBundle]:
        """Every installed version, by garment, oldest install first."""
        out = []
        for g in self._garments():
            cur, prev = self._link(g, CURRENT), self._link(g, PREVIOUS)
            items = [self._stored(g, v, cur, prev) for v in self._versions(g)]
            out += sorted(items, key=lambda s: (s.installed_at or "", s.version))
        return out

    def active(self) -> dict[str, StoredBundle]:
        """garment id -> its active bundle (garments without an active version are left out)."""
        out = {}
        for g in self._garments():
            cur = self._link(g, CURRENT)
            if cur is not None and (self.root / g / META / f"{cur}.json").is_file():
                out[g] = self._stored(g, cur, cur, self._link(g, PREVIOUS))
        return out

    def get(self, garment: str, version: str) -> StoredBundle:
        _check_name("garment", garment)
        _check_name("version", version)
        if garment not in self._garments():
            known = ", ".join(self._garments()) or "none"
            raise StoreError(f"no garment {garment!r} in the store {self.root} (installed: {known})")
        versions = self._versions(garment)
        if version not in versions:
            raise StoreError(f"garment {garment} has no version {version!r} (installed: "
                             f"{', '.join(sorted(versions)) or 'none'})")
        return self._stored(garment, version, self._link(garment, CURRENT), self._link(garment, PREVIOUS))

    # -- verifying ---------------------------------------------------------------------------------------------
    def _trusted(self) -> dict | None:
        if self.trusted_keys_dir is None:
            if self.allow_unsigned:
                return None
            raise BundleError("no trusted keys configured: cannot check the bundle's signature "
                              "(give --trusted-keys DIR or store.trusted_keys, or --allow-unsigned for development)")
        return load_trusted_keys(self.trusted_keys_dir)

    def verify(self, path: Path, *, probe: bool = True) -> Bundle:
        """Signature, file set, hashes, and (probe=True) an ONNX Runtime probe of every graph."""
        bundle = verify_directory(path, self._trusted(), allow_unsigned=self.allow_unsigned)
        if probe:
            from kiosk.bundle.probe import probe_bundle

            probe_bundle(bundle, threads=self.probe_threads)
        return bundle

    # -- changing ----------------------------------------------------------------------------------------------
    def _refuse_downgrade(self, garment: str, version: str, action: str, allow_downgrade: bool) -> None:
        """Raise DowngradeError (and log it) when `version` ranks below the newest installed version of `garment`
        (other than itself)."""
        others = [v for v in self._versions(garment) if v != version]
        top = newest(others)
        if top is None or not parse_version(version).key < parse_version(top).key:
            return
        if allow_downgrade:
            log.warning("%s %s %s although %s is installed (downgrade allowed by the operator)", action, garment,
                        version, top, extra={"GARMENT": garment, "VERSION": version, "NEWEST": top})
            return
        msg = (f"refusing to {action} {garment} {version}: it is older than the installed {top} "
               f"(give --allow-downgrade to do it anyway, or roll back with `vtkiosk bundle rollback {garment}`)")
        log.warning(msg, extra={"GARMENT": garment, "VERSION": version, "NEWEST": top})
        raise DowngradeError(msg)

    def install(self, archive: Path, *, activate_if_first: bool = False,
                allow_downgrade: bool = False) -> StoredBundle:
        """Verify `archive` (a .vtb file or an unpacked folder) and add it to the store, inactive (or active when
        `activate_if_first` and the garment has no active version yet). A version older than the garment's newest
        installed one is refused unless `allow_downgrade`."""
        archive = Path(archive)
        if not archive.exists():
            raise StoreError(f"{archive}: no such bundle")
        with self._locked():
            incoming = self.root / INCOMING
            incoming.mkdir(exist_ok=True)
            self._adopt(incoming)
            work = incoming / secrets.token_hex(8)
            work.mkdir(mode=0o750)
            meta_tmp = incoming / f"{work.name}.json"
            try:
                if archive.is_dir():
                    self._copy_dir(archive, work)
                    digest = None
                else:
                    safe_extract(archive, work, self.limits)
                    digest = sha256_file(archive)
                bundle = self.verify(work)
                m = bundle.manifest
                _check_name("garment", m.garment_id)
                if not VERSION_RE.match(m.model_version) or m.model_version in RESERVED:
                    raise StoreError(f"bundle version {m.model_version!r} cannot name a store folder "
                                     "(letters, digits, '.', '_', '+', '-'; at most 64)")
                if m.garment_id in self._garments():
                    self._refuse_downgrade(m.garment_id, m.model_version, "install", allow_downgrade)
                gdir = self.root / m.garment_id
                dest = gdir / m.model_version
                if dest.exists() or dest.is_symlink():
                    old = dest / MANIFEST
                    same = old.is_file() and old.read_bytes() == (work / MANIFEST).read_bytes()
                    raise StoreError(f"{m.garment_id} version {m.model_version} is already installed"
                                     f"{' (the same bundle)' if same else ' with different content'}; "
                                     "a version is installed once: remove it first or export a new version")
                meta = {"garment": m.garment_id, "version": m.model_version, "display_name": m.display_name,
                        "key_id": bundle.key_id, "precisions": {k: g.precision for k, g in m.graphs.items()},
                        "installed_at": datetime.now(timezone.utc).isoformat(timespec="microseconds"),
                        "archive": archive.name, "archive_sha256": digest}
                meta_tmp.write_text(json.dumps(meta, indent=1) + "\n")
                _fsync_tree(incoming)
                (gdir / META).mkdir(parents=True, exist_ok=True)
                # The folder becomes visible first, but is listed only once its meta file is in place too.
                os.rename(work, dest)
                os.rename(meta_tmp, gdir / META / f"{m.model_version}.json")
                fsync_dir(gdir / META)
                fsync_dir(gdir)
                self._adopt(gdir)
                if activate_if_first and self._link(m.garment_id, CURRENT) is None:
                    self._set_link(m.garment_id, CURRENT, m.model_version)
                    self._adopt(gdir / CURRENT)
            except OSError as exc:
                if exc.errno in NO_SPACE:
                    raise StoreError(f"no space left in the bundle store {self.root} to install {archive.name} "
                                     f"({exc.strerror}); free disk space and try again (nothing was "
                                     "installed)") from None
                raise
            finally:
                shutil.rmtree(work, ignore_errors=True)
                meta_tmp.unlink(missing_ok=True)
            return self.get(m.garment_id, m.model_version)

    @staticmethod
    def _copy_dir(src: Path, dest: Path) -> None:
        for p in sorted(Path(src).rglob("*")):
            rel = p.relative_to(src)
            if p.is_symlink():
                raise BundleError(f"bundle folder holds a symbolic link ({rel}); only regular files are allowed")
            if p.is_dir():
                (dest / rel).mkdir(parents=True, exist_ok=True)
            elif p.is_file():
                (dest / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(p, dest / rel)
            else:
                raise BundleError(f"bundle folder holds a special file ({rel})")

    def _set_link(self, garment: str, name: str, version: str | None) -> None:
        """Point <garment>/<name> at `version` (None: remove it) with one atomic rename."""
        gdir = self.root / garment
        link = gdir / name
        if version is None:
            link.unlink(missing_ok=True)
        else:
            tmp = gdir / f".{name}.{secrets.token_hex(6)}"
            os.symlink(version, tmp)
            os.replace(tmp, link)
        fsync_dir(gdir)

    def activate(self, garment: str, version: str, *, allow_downgrade: bool = False) -> StoredBundle:
        """Make `version` the active one (the old active becomes `previous`). Re-verifies the stored copy first
        (signature and hashes), so a bundle damaged on disk is never activated. A version older than the garment's
        newest installed one is refused unless `allow_downgrade` (`rollback` is the way back)."""
        with self._locked():
            target = self.get(garment, version)
            if target.active:
                return target
            self._refuse_downgrade(garment, version, "activate", allow_downgrade)
            self.verify(target.path, probe=False)
            cur = self._link(garment, CURRENT)
            self._write_history(garment, [v for v in self.history(garment) if v != version] + [version])
            if cur is not None:
                self._set_link(garment, PREVIOUS, cur)
            self._set_link(garment, CURRENT, version)
            self._adopt(self.root / garment / CURRENT)
            if cur is not None:
                self._adopt(self.root / garment / PREVIOUS)
            return self.get(garment, version)

    def history(self, garment: str) -> list[str]:
        """The versions a garment was activated with, oldest first, the active one last; only versions still
        installed. A store written before the history existed reads as [previous, current]."""
        path = self.root / garment / META / HISTORY
        try:
            doc = json.loads(path.read_text())
        except FileNotFoundError:
            doc = [v for v in (self._link(garment, PREVIOUS), self._link(garment, CURRENT)) if v is not None]
        except (OSError, ValueError):
            raise StoreError(f"{path} is damaged; remove it to fall back to the current/previous links") from None
        if not (isinstance(doc, list) and all(isinstance(v, str) for v in doc)):
            raise StoreError(f"{path} is not a list of versions; remove it to fall back to the current/previous "
                             "links")
        installed = set(self._versions(garment))
        return [v for v in doc if v in installed]

    def _write_history(self, garment: str, versions: list[str]) -> None:
        path = self.root / garment / META / HISTORY
        atomic_write(path, json.dumps(versions[-HISTORY_LENGTH:]).encode())
        self._adopt(path)

    def rollback(self, garment: str) -> StoredBundle:
        """Go back one step in the activation history: rolling back twice goes two versions back (it does not flip
        between two), and `previous` becomes the version before the one now active."""
        with self._locked():
            _check_name("garment", garment)
            if garment not in self._garments():
                raise StoreError(f"no garment {garment!r} in the store {self.root}")
            cur = self._link(garment, CURRENT)
            hist = self.history(garment)
            if hist and hist[-1] == cur:
                hist = hist[:-1]
            if not hist:
                raise StoreError(f"{garment} has no earlier version in its history to roll back to"
                                 f"{f' (active: {cur})' if cur else ''}")
            prev = hist[-1]
            self.verify(self.root / garment / prev, probe=False)
            self._write_history(garment, hist)
            self._set_link(garment, PREVIOUS, hist[-2] if len(hist) > 1 else None)
            self._set_link(garment, CURRENT, prev)
            return self.get(garment, prev)

    def links(self, garment: str) -> tuple[str | None, str | None]:
        """(current, previous) version names of a garment (None where unset)."""
        return self._link(garment, CURRENT), self._link(garment, PREVIOUS)

    def restore(self, garment: str, *, current: str | None, previous: str | None) -> None:
        """Put a garment's links back as they were (undo of an activation the daemon refused)."""
        with self._locked():
            if current is not None:
                hist = self.history(garment)
                if current in hist:   # undo of an activation: drop what came after
                    hist = hist[:hist.index(current) + 1]
                else:                 # undo of a rollback: the version rolled back from is active again
                    hist.append(current)
                self._write_history(garment, hist)
            for name, version in ((PREVIOUS, previous), (CURRENT, current)):
                if version is not None:
                    self.get(garment, version)
                self._set_link(garment, name, version)

    def remove(self, garment: str, version: str) -> None:
        """Delete an installed version; the active one is refused (activate or roll back first)."""
        with self._locked():
            target = self.get(garment, version)
            if target.active:
                raise StoreError(f"{garment} {version} is the active version; activate another one (or roll "
                                 "back) before removing it")
            gdir = self.root / garment
            if target.previous:
                self._set_link(garment, PREVIOUS, None)
            (gdir / META / f"{version}.json").unlink()  # unlisted from here on
            trash = self.root / INCOMING
            trash.mkdir(exist_ok=True)
            gone = trash / f"removed-{secrets.token_hex(8)}"
            os.rename(target.path, gone)
            fsync_dir(gdir)
            shutil.rmtree(gone, ignore_errors=True)
            if not self._versions(garment) and self._link(garment, CURRENT) is None:
                shutil.rmtree(gdir, ignore_errors=True)

