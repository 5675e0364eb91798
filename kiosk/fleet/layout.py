"""What publisher and kiosk agree on: channels, target paths, the custom metadata of a bundle target, the index
of a channel, and the staged-rollout bucket of a kiosk.

A bundle is the TUF target `<channel>/<garment>/<garment>-<version>.vtb`, listed in the delegated targets role named
after its channel. Its `custom` field carries `{"vtkiosk": {...}}` (garment, version, min_runtime, channel, rollout,
withdrawn, published_at), signed with the role, so a mirror can change none of it. ngclient looks targets up by
path and offers no listing, so each channel also holds one target `<channel>/index.json`: the paths of that
channel's bundles. The index is a target like any other (hash and length signed), so it cannot be forged either.
"""
from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass

from kiosk.bundle.version import VersionError, parse_version
from kiosk.contract.errors import KioskError

CHANNELS = ("canary", "stable")
# A kiosk on a channel reads these channels' bundles (a canary kiosk also gets what is already stable).
READS = {"canary": ("canary", "stable"), "stable": ("stable",)}
INDEX = "index.json"
INDEX_SCHEMA = 1
MAX_INDEX_BYTES = 1 << 20
MAX_INDEX_ENTRIES = 4096
GARMENT_RE = re.compile(r"\A[a-z0-9][a-z0-9._-]{0,63}\Z")
KIOSK_ID_RE = re.compile(r"\A[A-Za-z0-9][A-Za-z0-9._:-]{0,127}\Z")
_ROLLOUT_SALT = b"vtkiosk-rollout\0"


class FleetError(KioskError):
    """A fleet operation that cannot be done as asked; the message says why."""


class RefusedError(FleetError):
    """Something the repository served was refused (an attack, or a mistake that looks like one)."""


def check_channel(channel: str) -> str:
    if channel not in CHANNELS:
        raise FleetError(f"unknown channel {channel!r} (channels: {', '.join(CHANNELS)})")
    return channel


def check_kiosk_id(kiosk_id: str) -> str:
    if not isinstance(kiosk_id, str) or not KIOSK_ID_RE.match(kiosk_id):
        raise FleetError(f"kiosk id {kiosk_id!r} is not valid (1 to 128 letters, digits, '.', '_', ':', '-')")
    return kiosk_id


def target_path(channel: str, garment: str, version: str) -> str:
    check_channel(channel)
    if not GARMENT_RE.match(garment):
        raise FleetError(f"{garment!r} is not a valid garment id")
    parse_version(version)
    return f"{channel}/{garment}/{garment}-{version}.vtb"


def index_path(channel: str) -> str:
    return f"{check_channel(channel)}/{INDEX}"


def rollout_bucket(kiosk_id: str) -> int:
    """The kiosk's place in every staged rollout, 0..99: a kiosk is in a rollout of P percent when its bucket is
    below P. A stable hash of the id, so raising P only ever adds kiosks, and a kiosk never flips back and forth."""
    digest = hashlib.sha256(_ROLLOUT_SALT + check_kiosk_id(kiosk_id).encode()).digest()
    return int.from_bytes(digest[:8], "big") % 100


def check_rollout(percent: object) -> int:
    if isinstance(percent, bool) or not isinstance(percent, int) or not 0 <= percent <= 100:
        raise FleetError(f"rollout must be a whole percentage from 0 to 100; got {percent!r}")
    return percent


@dataclass(frozen=True)
class Release:
    """The signed facts about one bundle target (its TUF custom metadata)."""

    path: str
    garment: str
    version: str
    channel: str
    rollout: int = 100
    min_runtime: str = "0"
    withdrawn: bool = False
    published_at: str = ""

    def custom(self) -> dict:
        return {"vtkiosk": {"garment": self.garment, "version": self.version, "channel": self.channel,
                            "rollout": self.rollout, "min_runtime": self.min_runtime, "withdrawn": self.withdrawn,
                            "published_at": self.published_at}}

    def reaches(self, kiosk_id: str) -> bool:
        return not self.withdrawn and rollout_bucket(kiosk_id) < self.rollout


def release_from_custom(path: str, custom: object) -> Release:
    """Parse and check a target's custom metadata; RefusedError when it does not describe the path it is on."""
    d = custom.get("vtkiosk") if isinstance(custom, dict) else None
    if not isinstance(d, dict):
        raise RefusedError(f"target {path}: no vtkiosk release metadata")
    try:
        garment, version, channel = d["garment"], d["version"], d["channel"]
        rollout, min_runtime = check_rollout(d["rollout"]), d["min_runtime"]
        withdrawn, published_at = d["withdrawn"], d.get("published_at", "")
        if not isinstance(withdrawn, bool) or not isinstance(published_at, str):
            raise FleetError("withdrawn must be true/false and published_at a string")
        parse_version(min_runtime)
        expected = target_path(channel, garment, version)
    except (KeyError, TypeError, FleetError, VersionError) as exc:
        raise RefusedError(f"target {path}: invalid release metadata ({exc})") from None
    if expected != path:
        raise RefusedError(f"target {path}: its metadata describes {expected} (a target moved to another path)")
    return Release(path, garment, version, channel, rollout, min_runtime, withdrawn, published_at)


def index_bytes(channel: str, paths: list[str]) -> bytes:
    return (json.dumps({"schema": INDEX_SCHEMA, "channel": check_channel(channel), "targets": sorted(paths)},
                       indent=1) + "\n").encode()


def parse_index(channel: str, data: bytes) -> list[str]:
    """The bundle target paths a channel index lists (each must lie in that channel)."""
    if len(data) > MAX_INDEX_BYTES:
        raise RefusedError(f"{index_path(channel)}: {len(data)} bytes is too large for an index")
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise RefusedError(f"{index_path(channel)}: not JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("schema") != INDEX_SCHEMA or doc.get("channel") != channel \
            or not isinstance(doc.get("targets"), list) or len(doc["targets"]) > MAX_INDEX_ENTRIES:
        raise RefusedError(f"{index_path(channel)}: not a schema-{INDEX_SCHEMA} index of channel {channel}")
    paths = doc["targets"]
    for p in paths:
        if not isinstance(p, str) or not p.startswith(f"{channel}/") or not p.endswith(".vtb") or ".." in p:
            raise RefusedError(f"{index_path(channel)}: entry {p!r} is not a bundle of channel {channel}")
    return list(paths)
