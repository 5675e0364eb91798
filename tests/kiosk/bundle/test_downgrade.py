"""Versions only go forward in the store: an older bundle is refused (and logged) unless the operator allows the
downgrade; rollback stays the explicit way back. A full disk during install says so."""
from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import pytest

from kiosk.bundle.manifest import BundleError
from kiosk.bundle.store import BundleStore, DowngradeError, StoreError
from tests.kiosk.bundle_factory import base_manifest, make_bundle

from ..full_disk import small_disk

ROOT = Path(__file__).resolve().parents[3]
OLD, NEW, NEWER = "2026.11.21-1", "2026.11.22-1", "2026.11.22-10"


@pytest.fixture(scope="module")
def bundles(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("downgrade-bundles")
    out = {}
    for v in (OLD, NEW, NEWER):
        out[v], trusted = make_bundle(tmp, name=f"denim-{v}.vtb", manifest=base_manifest(model_version=v))
    out["trusted"] = trusted
    return out


def test_an_older_bundle_is_refused_logged_and_allowed_on_request(tmp_path, bundles, caplog):
    store = BundleStore(tmp_path / "store", bundles["trusted"])
    store.install(bundles[NEW], activate_if_first=True)
    with caplog.at_level(logging.WARNING, logger="kiosk.bundle.store"):
        with pytest.raises(DowngradeError) as e:
            store.install(bundles[OLD])
    msg = str(e.value)
    assert "\n" not in msg and f"refusing to install denim-shorts {OLD}: it is older than the installed {NEW}" in msg
    assert "--allow-downgrade" in msg
    logged = [r for r in caplog.records if r.levelno == logging.WARNING and "refusing to install" in r.getMessage()]
    assert logged and logged[0].GARMENT == "denim-shorts" and logged[0].VERSION == OLD and logged[0].NEWEST == NEW
    assert [s.version for s in store.list()] == [NEW]              # nothing of the old one is in the store
    # allowed: installed, but activating it is a downgrade too
    store.install(bundles[OLD], allow_downgrade=True)
    with pytest.raises(DowngradeError, match=f"refusing to activate denim-shorts {OLD}"):
        store.activate("denim-shorts", OLD)
    assert store.links("denim-shorts") == (NEW, None)
    assert store.activate("denim-shorts", OLD, allow_downgrade=True).active
    assert store.links("denim-shorts") == (OLD, NEW)
    # newer versions go in freely, "-10" ranks above "-1" (not a string comparison)
    store.install(bundles[NEWER])
    assert store.activate("denim-shorts", NEWER).active


def test_rollback_still_goes_back(tmp_path, bundles):
    store = BundleStore(tmp_path / "store", bundles["trusted"])
    store.install(bundles[OLD], activate_if_first=True)
    store.install(bundles[NEW])
    store.activate("denim-shorts", NEW)
    assert store.rollback("denim-shorts").version == OLD        # no flag needed: the operator's explicit step
    assert store.links("denim-shorts") == (OLD, None)
    assert store.activate("denim-shorts", NEW).active   # forward again is an ordinary activation


def test_the_command_refuses_in_one_line_and_allows_with_the_flag(tmp_path, bundles):
    common = ["--store", str(tmp_path / "store"), "--trusted-keys", str(bundles["trusted"]), "--control-socket",
              str(tmp_path / "none.sock"), "--threads", "1"]

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "vtkiosk", "bundle", *map(str, args), *common], cwd=ROOT,
                              capture_output=True, text=True, timeout=300)

    assert cli("install", bundles[NEW], "--activate").returncode == 0
    proc = cli("install", bundles[OLD], "--activate")
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "older than the installed" in proc.stderr
    assert "Traceback" not in proc.stderr and "activated" not in proc.stdout
    proc = cli("install", bundles[OLD], "--activate", "--allow-downgrade")
    assert proc.returncode == 0 and f"activated denim-shorts {OLD} (previous: {NEW})" in proc.stdout, proc.stderr


def test_a_full_disk_during_install_says_no_space_left(tmp_path, bundles):
    with small_disk(tmp_path / "disk", size_kib=512) as disk:
        store = BundleStore(disk.folder / "store", bundles["trusted"])
        store.root.mkdir()
        disk.fill(slack=0)
        with pytest.raises((BundleError, StoreError)) as e:
            store.install(bundles[NEW])
        assert "no space left" in str(e.value) and "\n" not in str(e.value), e.value
        disk.free()
        assert store.install(bundles[NEW]).version == NEW
