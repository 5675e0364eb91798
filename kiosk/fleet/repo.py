"""The operator's TUF repository on disk: metadata with python-tuf's Metadata API, served by any static server.

    <repo>/metadata/<N>.root.json        every root version (kiosks walk the chain from the one they trust)
    <repo>/metadata/timestamp.json       the only unversioned file: replaced last, atomically, on every change
    <repo>/metadata/<N>.<role>.json      snapshot, targets, canary, stable (consistent snapshots)
    <repo>/targets/<channel>/<garment>/<sha256>.<garment>-<version>.vtb   bundles, named by their hash
    <repo>/targets/<channel>/<sha256>.index.json                          each channel's list of bundles

Roles: root and targets are signed by offline keys; targets delegates `canary/*` and `stable/*` to the channel
roles, whose keys are online with the snapshot and timestamp keys. A publish writes the new files first and the
timestamp last, and old versions stay, so a kiosk reading in the middle of a publish sees the old state or the new
one. Expiry: timestamp 1 day, snapshot 7 days, channels 30 days, targets and root 1 year; `refresh` re-signs the
online roles before they run out (run it hourly), the offline ones need a key ceremony.
"""
from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path

from tuf.api.metadata import (DelegatedRole, Delegations, Metadata, MetaFile, Root, Snapshot, TargetFile, Targets,
                              Timestamp)
from tuf.api.serialization.json import JSONSerializer

from kiosk.bundle.version import compare
from kiosk.fleet import keys as rolekeys
from kiosk.bundle.durable import atomic_write
from kiosk.fleet.layout import (CHANNELS, FleetError, Release, check_channel, check_rollout, index_bytes, index_path,
                                release_from_custom, target_path)

TOP = ("root", "targets", "snapshot", "timestamp")
ROLES = (*TOP, *CHANNELS)
EXPIRY = {"root": timedelta(days=365), "targets": timedelta(days=365), "snapshot": timedelta(days=7),
          "timestamp": timedelta(days=1), "canary": timedelta(days=30), "stable": timedelta(days=30)}
_VERSIONED = re.compile(r"\A([1-9][0-9]{0,9})\.([a-z]+)\.json\Z")


def _utc_now() -> datetime:
    return datetime.now(timezone.utc).replace(microsecond=0)


@dataclass(frozen=True)
class RoleStatus:
    role: str
    version: int
    expires: datetime
    keyids: tuple[str, ...]


class FleetRepository:
    """One repository folder. `keys` holds the online role keys, `offline_keys` root and targets (each only needed
    by the operations that sign with them)."""

    def __init__(self, repo: Path, *, keys: Path | None = None, offline_keys: Path | None = None, clock=_utc_now):
        self.repo = Path(repo)
        self.meta_dir = self.repo / "metadata"
        self.targets_dir = self.repo / "targets"
        self.keys = Path(keys) if keys is not None else None
        self.offline_keys = Path(offline_keys) if offline_keys is not None else None
        self._clock = clock
        self._serializer = JSONSerializer(compact=False)

    # -- reading -----------------------------------------------------------------------------------------------
    def _key_dir(self, role: str) -> Path | None:
        return self.offline_keys if role in rolekeys.OFFLINE_ROLES else self.keys

    def exists(self) -> bool:
        return self.meta_dir.is_dir() and any(self.meta_dir.glob("*.root.json"))

    def _versions(self, role: str) -> list[int]:
        if not self.meta_dir.is_dir():
            return []
        out = []
        for p in self.meta_dir.iterdir():
            m = _VERSIONED.match(p.name)
            if m and m.group(2) == role:
                out.append(int(m.group(1)))
        return sorted(out)

    def _path(self, role: str, version: int) -> Path:
        return self.meta_dir / ("timestamp.json" if role == "timestamp" else f"{version}.{role}.json")

    def open(self, role: str) -> Metadata:
        """The newest version of a role's metadata."""
        if not self.exists():
            raise FleetError(f"{self.repo} is not a fleet repository (no metadata/1.root.json); run `vtkiosk fleet "
                             "init` first")
        if role == "timestamp":
            return Metadata.from_file(str(self._path(role, 0)))
        versions = self._versions(role)
        if not versions:
            raise FleetError(f"{self.repo}: no {role} metadata")
        return Metadata.from_file(str(self._path(role, versions[-1])))

    def releases(self, channel: str) -> list[Release]:
        targets = self.open(check_channel(channel)).signed
        return sorted((release_from_custom(p, t.custom) for p, t in targets.targets.items()
                       if not p.endswith("/index.json")), key=lambda r: (r.garment, r.path))

    def status(self) -> list[RoleStatus]:
        root = self.open("root").signed
        top = self.open("targets").signed
        out = []
        for role in ROLES:
            signed = self.open(role).signed
            keyids = root.roles[role].keyids if role in root.roles else top.delegations.roles[role].keyids
            out.append(RoleStatus(role, signed.version, signed.expires, tuple(keyids)))
        return out

    # -- signing and writing -------------------------------------------------------------------------------------
    def _authorized(self, role: str) -> tuple[list[str], object]:
        if role in TOP:
            r = self.open("root").signed.roles[role]
        else:
            r = self.open("targets").signed.delegations.roles[role]
        return list(r.keyids), r

    def _signer(self, role: str):
        signer = rolekeys.load(self._key_dir(role), role)
        keyids, _ = self._authorized(role)
        if signer.public_key.keyid not in keyids:
            path = rolekeys.key_file(self._key_dir(role), role)
            raise FleetError(f"{path} (key {signer.public_key.keyid[:12]}) is not a key of the {role} role "
                             f"(its keys: {', '.join(k[:12] for k in keyids)}); was it rotated?")
        return signer

    def _bump(self, signed, role: str) -> None:
        signed.version += 1
        signed.expires = self._clock() + EXPIRY[role]

    def _write(self, role: str, md: Metadata, *signers) -> bytes:
        for i, signer in enumerate(signers):
            md.sign(signer, append=i > 0)
        data = md.to_bytes(self._serializer)
        atomic_write(self._path(role, md.signed.version), data)
        return data

    def _metafile(self, role: str, data: bytes, version: int) -> MetaFile:
        return MetaFile(version=version, length=len(data), hashes={"sha256": hashlib.sha256(data).hexdigest()})

    def _snapshot_and_timestamp(self, changed: dict[str, tuple[int, bytes]]) -> None:
        """New snapshot listing the changed targets roles, then the new timestamp (the commit point)."""
        snap = self.open("snapshot")
        for role, (version, data) in changed.items():
            snap.signed.meta[f"{role}.json"] = self._metafile(role, data, version)
        self._bump(snap.signed, "snapshot")
        snap_data = self._write("snapshot", snap, self._signer("snapshot"))
        self._timestamp(snap.signed.version, snap_data)

    def _timestamp(self, snapshot_version: int, snapshot_data: bytes) -> None:
        ts = self.open("timestamp")
        ts.signed.snapshot_meta = self._metafile("snapshot", snapshot_data, snapshot_version)
        self._bump(ts.signed, "timestamp")
        self._write("timestamp", ts, self._signer("timestamp"))

    # -- operations ----------------------------------------------------------------------------------------------
    def init(self) -> Path:
        """Key ceremony: generate every role's key and write version 1 of every role. Returns the trust anchor
        (metadata/1.root.json) that kiosks are provisioned with."""
        if self.exists():
            raise FleetError(f"{self.repo} already holds a fleet repository; refusing to overwrite it")
        if self.keys is None or self.offline_keys is None:
            raise FleetError("init needs both --keys DIR (online keys) and --offline-keys DIR (root, targets)")
        for role in ROLES:
            if rolekeys.key_file(self._key_dir(role), role).exists():
                raise FleetError(f"{rolekeys.key_file(self._key_dir(role), role)} already exists; init makes new "
                                 "keys and never reuses or overwrites one")
        signers = {role: rolekeys.generate(self._key_dir(role), role) for role in ROLES}
        now = self._clock()
        root = Root(version=1, expires=now + EXPIRY["root"], consistent_snapshot=True)
        for role in TOP:
            root.add_key(signers[role].public_key, role)
        # TUF path patterns match one segment per "*": the index, and <channel>/<garment>/<file>.
        roles = {c: DelegatedRole(c, [signers[c].public_key.keyid], 1, True, paths=[f"{c}/*", f"{c}/*/*"])
                 for c in CHANNELS}
        top = Targets(version=1, expires=now + EXPIRY["targets"],
                      delegations=Delegations({signers[c].public_key.keyid: signers[c].public_key for c in CHANNELS},
                                              roles))
        self.meta_dir.mkdir(parents=True, exist_ok=True)
        self.targets_dir.mkdir(parents=True, exist_ok=True)
        changed = {}
        for c in CHANNELS:
            md = Metadata(Targets(version=1, expires=now + EXPIRY[c]))
            md.signed.targets[index_path(c)] = self._store_file(index_path(c), index_bytes(c, []))
            changed[c] = (1, self._write(c, md, signers[c]))
        changed["targets"] = (1, self._write("targets", Metadata(top), signers["targets"]))
        snap = Snapshot(version=1, expires=now + EXPIRY["snapshot"],
                        meta={f"{r}.json": self._metafile(r, d, v) for r, (v, d) in changed.items()})
        snap_data = self._write("snapshot", Metadata(snap), signers["snapshot"])
        ts = Timestamp(version=1, expires=now + EXPIRY["timestamp"],
                       snapshot_meta=self._metafile("snapshot", snap_data, 1))
        self._write("timestamp", Metadata(ts), signers["timestamp"])
        # Root last: until it exists, `exists()` is false and a crashed init can simply be run again.
        self._write("root", Metadata(root), signers["root"])
        return self._path("root", 1)

    def _store_file(self, path: str, data: bytes) -> TargetFile:
        """Write a target under its hash-prefixed name (what ngclient asks for with consistent snapshots)."""
        info = TargetFile.from_data(path, data, ["sha256"])
        folder, _, name = path.rpartition("/")
        dest = self.targets_dir / folder / f"{info.hashes['sha256']}.{name}"
        if not dest.exists():
            atomic_write(dest, data)
        return info

    def _edit_channel(self, channel: str, change) -> Release:
        """Run `change(targets) -> Release` on a new version of the channel role, rewrite its index, and publish."""
        md = self.open(channel)
        signer = self._signer(channel)
        for role in ("snapshot", "timestamp"):  # fail before writing anything when a key is missing
            self._signer(role)
        release = change(md.signed)
        paths = [p for p in md.signed.targets if p != index_path(channel)]
        md.signed.targets[index_path(channel)] = self._store_file(index_path(channel), index_bytes(channel, paths))
        self._bump(md.signed, channel)
        data = self._write(channel, md, signer)
        self._snapshot_and_timestamp({channel: (md.signed.version, data)})
        return release

    def publish(self, bundle: Path, channel: str, *, garment: str, version: str, rollout: int = 100,
                min_runtime: str = "0") -> Release:
        """Add a bundle file (already checked by the caller) to a channel. Refuses a version that is not newer
        than every version of the garment in that channel: kiosks never downgrade, so it would reach nobody."""
        check_channel(channel)
        check_rollout(rollout)
        path = target_path(channel, garment, version)
        data = Path(bundle).read_bytes()

        def change(targets: Targets) -> Release:
            for r in (release_from_custom(p, t.custom) for p, t in targets.targets.items()
                      if p != index_path(channel)):
                if r.garment == garment and compare(version, r.version) <= 0:
                    raise FleetError(f"channel {channel} already has {garment} {r.version}, which is not older than "
                                     f"{version}; kiosks never downgrade, so publish a newer version")
            release = Release(path, garment, version, channel, rollout, min_runtime, False,
                              self._clock().isoformat())
            info = self._store_file(path, data)
            info.unrecognized_fields["custom"] = release.custom()
            targets.targets[path] = info
            return release

        return self._edit_channel(channel, change)

    def promote(self, garment: str, version: str, *, rollout: int = 100, source: str = "canary",
                dest: str = "stable") -> Release:
        """Put a canary release on stable (same bytes), or change the rollout percentage of one already there."""
        check_rollout(rollout)
        src_path, dest_path = target_path(source, garment, version), target_path(dest, garment, version)
        src = self.open(source).signed.targets.get(src_path)
        if src is None:
            raise FleetError(f"{garment} {version} is not on channel {source}; publish it there first")
        src_release = release_from_custom(src_path, src.custom)
        if src_release.withdrawn:
            raise FleetError(f"{garment} {version} was withdrawn from {source}; it cannot be promoted")
        folder, _, name = src_path.rpartition("/")
        data = (self.targets_dir / folder / f"{src.hashes['sha256']}.{name}").read_bytes()

        def change(targets: Targets) -> Release:
            for p, t in targets.targets.items():
                if p == index_path(dest) or p == dest_path:
                    continue
                r = release_from_custom(p, t.custom)
                if r.garment == garment and compare(version, r.version) < 0:
                    raise FleetError(f"channel {dest} already has the newer {garment} {r.version}")
            old = targets.targets.get(dest_path)
            published = release_from_custom(dest_path, old.custom).published_at if old else self._clock().isoformat()
            release = Release(dest_path, garment, version, dest, rollout, src_release.min_runtime, False, published)
            info = self._store_file(dest_path, data)
            info.unrecognized_fields["custom"] = release.custom()
            targets.targets[dest_path] = info
            return release

        return self._edit_channel(dest, change)

    def withdraw(self, garment: str, version: str, channels=CHANNELS) -> list[Release]:
        """Mark a release withdrawn: kiosks that run it go back to the newest installed version that is not
        withdrawn, and no kiosk installs it any more. The target stays listed, so its withdrawal is signed."""
        done = []
        for channel in channels:
            path = target_path(channel, garment, version)
            if path not in self.open(channel).signed.targets:
                continue

            def change(targets: Targets, path=path) -> Release:
                t = targets.targets[path]
                r = release_from_custom(path, t.custom)
                r = Release(r.path, r.garment, r.version, r.channel, r.rollout, r.min_runtime, True, r.published_at)
                t.unrecognized_fields["custom"] = r.custom()
                return r

            done.append(self._edit_channel(channel, change))
        if not done:
            raise FleetError(f"{garment} {version} is on no channel ({', '.join(channels)})")
        return done

    def rotate_key(self, role: str) -> tuple[str, str, Path]:
        """Replace a role's key: (old keyid, new keyid, where the old key file went). A top-level role's key changes
        in a new root version (signed by the old and the new root key when root itself rotates), a channel's key in a
        new targets version; the role is then re-signed with its new key, and snapshot and timestamp follow."""
        if role not in ROLES:
            raise FleetError(f"unknown role {role!r} (roles: {', '.join(ROLES)})")
        old = self._signer(role)
        parent = "root" if role in TOP else "targets"
        parent_signer = old if role == "root" else self._signer(parent)
        for r in ("snapshot", "timestamp"):  # every key this needs, before anything changes
            self._signer(r)
        folder = self._key_dir(role)
        retired = rolekeys.retire(folder, role, old.public_key.keyid)
        try:
            new = rolekeys.generate(folder, role)
        except BaseException:
            os.replace(retired, rolekeys.key_file(folder, role))
            raise
        md = self.open(parent)
        md.signed.revoke_key(old.public_key.keyid, role)
        md.signed.add_key(new.public_key, role)
        self._bump(md.signed, parent)
        data = self._write(parent, md, *([old, new] if role == "root" else [parent_signer]))
        changed = {} if parent == "root" else {"targets": (md.signed.version, data)}
        if role in ("targets", *CHANNELS):
            again = self.open(role)
            self._bump(again.signed, role)
            changed[role] = (again.signed.version, self._write(role, again, new))
        if role == "timestamp":
            snapshot = self._versions("snapshot")[-1]
            self._timestamp(snapshot, self._path("snapshot", snapshot).read_bytes())
        elif role != "root":
            self._snapshot_and_timestamp(changed)
        return old.public_key.keyid, new.public_key.keyid, retired

    def refresh(self, *, offline_within: timedelta = timedelta(days=30)) -> list[str]:
        """Re-sign the online roles that have less than half their life left (the timestamp always), so kiosks
        never see expired metadata from an honest repository; with the offline keys at hand, also root and targets
        when they expire within `offline_within`. Returns what was re-signed."""
        now = self._clock()
        done, changed = [], {}
        if self.offline_keys is not None:
            for role in rolekeys.OFFLINE_ROLES:
                md = self.open(role)
                if md.signed.expires - now < offline_within:
                    self._bump(md.signed, role)
                    data = self._write(role, md, self._signer(role))
                    if role == "targets":
                        changed["targets"] = (md.signed.version, data)
                    done.append(role)
        for channel in CHANNELS:
            md = self.open(channel)
            if md.signed.expires - now < EXPIRY[channel] / 2:
                self._bump(md.signed, channel)
                changed[channel] = (md.signed.version, self._write(channel, md, self._signer(channel)))
                done.append(channel)
        snap = self.open("snapshot")
        if changed or snap.signed.expires - now < EXPIRY["snapshot"] / 2:
            self._snapshot_and_timestamp(changed)
            done += ["snapshot", "timestamp"]
        else:
            version = snap.signed.version
            self._timestamp(version, self._path("snapshot", version).read_bytes())
            done.append("timestamp")
        return done

    def offline_expiry_warnings(self, within: timedelta = timedelta(days=30)) -> list[str]:
        now = self._clock()
        out = []
        for role in rolekeys.OFFLINE_ROLES:
            exp = self.open(role).signed.expires
            if exp - now < within:
                out.append(f"{role} metadata expires {exp.isoformat()}: bring the offline keys and run `vtkiosk "
                           "fleet refresh --offline-keys DIR` before then")
        return out
