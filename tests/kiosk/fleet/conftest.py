"""A fleet in a temporary folder: a repository with fresh keys, served on loopback, and kiosks with real bundle
stores that sync from it. Bundles are real and small (tests/kiosk/bundle_factory.py)."""
from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import pytest

from kiosk.bundle.store import BundleStore
from kiosk.service.config import FleetConfig
from kiosk.fleet.layout import rollout_bucket
from kiosk.fleet.repo import FleetRepository
from kiosk.fleet.sync import FleetSync
from tests.kiosk.bundle_factory import base_manifest, make_bundle
from tests.kiosk.fleet.loopback import RepoServer


@pytest.fixture(scope="session")
def bundle_files(tmp_path_factory):
    """Signed bundles: denim-shorts 1, 2 and 3 and a second garment, all by the fleet's bundle key 'operator';
    and denim-shorts 4 signed by a key no kiosk trusts."""
    tmp = tmp_path_factory.mktemp("fleet-bundles")
    out = {}
    for garment, version in (("denim-shorts", "1"), ("denim-shorts", "2"), ("denim-shorts", "3"), ("silk-scarf", "1")):
        out[(garment, version)], trusted = make_bundle(
            tmp, name=f"{garment}-{version}.vtb", manifest=base_manifest(garment_id=garment, model_version=version))
    out[("denim-shorts", "4")], _ = make_bundle(tmp, name="denim-shorts-4-rogue.vtb", key_name="rogue",
                                                manifest=base_manifest(model_version="4"))
    trusted_only_operator = tmp / "kiosk-trusted"
    trusted_only_operator.mkdir()
    shutil.copy(trusted / "operator.pub", trusted_only_operator / "operator.pub")
    return out, trusted_only_operator


def kiosk_id_in_bucket(low: int, high: int, prefix: str = "kiosk") -> str:
    """A kiosk id whose rollout bucket lies in [low, high)."""
    for i in range(10000):
        kid = f"{prefix}-{i}"
        if low <= rollout_bucket(kid) < high:
            return kid
    raise AssertionError("no id found")


@dataclass
class Kiosk:
    name: str
    store: BundleStore
    sync: FleetSync

    def active(self, garment: str = "denim-shorts") -> str | None:
        a = self.store.active().get(garment)
        return a.version if a else None

    def installed(self, garment: str = "denim-shorts") -> list[str]:
        return sorted(s.version for s in self.store.list() if s.garment == garment)


class Fleet:
    def __init__(self, tmp: Path, bundles):
        self.tmp = tmp
        self.files, self.trusted = bundles
        self.repo = FleetRepository(tmp / "repo", keys=tmp / "keys", offline_keys=tmp / "offline")
        self.anchor = self.repo.init()
        self.server = RepoServer(tmp / "repo")
        self.url = self.server.url

    def publish(self, garment: str, version: str, channel: str = "canary", **kw):
        return self.repo.publish(self.files[(garment, version)], channel, garment=garment, version=version, **kw)

    def kiosk(self, name: str, channel: str = "stable", kiosk_id: str | None = None, **cfg) -> Kiosk:
        store = BundleStore(self.tmp / name / "bundles", self.trusted, probe_threads=1)
        conf = FleetConfig(url=self.url, root=self.anchor, kiosk_id=kiosk_id or name, channel=channel,
                           state_dir=self.tmp / name / "fleet", attempts=cfg.pop("attempts", 1),
                           backoff_s=cfg.pop("backoff_s", 0.0), timeout_s=cfg.pop("timeout_s", 5.0), **cfg)
        return Kiosk(name, store, FleetSync(conf, store, control_socket=None, sleep=lambda s: None))

    def snapshot_repo(self, name: str) -> Path:
        """A copy of the repository as it is now (what a mirror could replay later)."""
        dest = self.tmp / f"saved-{name}"
        shutil.copytree(self.tmp / "repo", dest)
        return dest


@pytest.fixture
def fleet(tmp_path, bundle_files):
    f = Fleet(tmp_path, bundle_files)
    yield f
    f.server.stop()
