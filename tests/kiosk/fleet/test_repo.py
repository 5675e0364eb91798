"""The publisher: what it refuses (so that the operator hears it at the desk, not from the kiosks), its CLI, and
key handling."""
from __future__ import annotations

import os

import pytest

from kiosk.fleet.layout import FleetError
from vtkiosk.cli import main as vtkiosk


def test_publish_refuses_what_kiosks_would_never_install(fleet):
    fleet.publish("denim-shorts", "2")
    with pytest.raises(FleetError, match="not older than 1; kiosks never downgrade"):
        fleet.publish("denim-shorts", "1")
    with pytest.raises(FleetError, match="not on channel canary"):
        fleet.repo.promote("denim-shorts", "3")
    with pytest.raises(FleetError, match="rollout must be a whole percentage"):
        fleet.repo.promote("denim-shorts", "2", rollout=150)
    fleet.repo.withdraw("denim-shorts", "2")
    with pytest.raises(FleetError, match="withdrawn"):
        fleet.repo.promote("denim-shorts", "2")
    with pytest.raises(FleetError, match="on no channel"):
        fleet.repo.withdraw("silk-scarf", "1")


def test_keys_are_private_and_must_be_the_roles_keys(fleet):
    key = fleet.tmp / "keys" / "canary.key"
    assert os.stat(key).st_mode & 0o077 == 0
    os.chmod(key, 0o644)
    with pytest.raises(FleetError, match="readable by group or others"):
        fleet.publish("denim-shorts", "1")
    os.chmod(key, 0o600)
    fleet.repo.rotate_key("canary")
    retired = next((fleet.tmp / "keys").glob("canary.key.retired-*"))
    os.replace(retired, key)  # someone puts the old key back
    with pytest.raises(FleetError, match="is not a key of the canary role"):
        fleet.publish("denim-shorts", "1")
    with pytest.raises(FleetError, match="already holds a fleet repository"):
        fleet.repo.init()


def test_cli_publish_checks_the_bundle_signature_and_errors_are_one_line(fleet, capsys):
    files, trusted = fleet.files, fleet.trusted
    common = ["--repo", str(fleet.tmp / "repo"), "--keys", str(fleet.tmp / "keys")]
    assert vtkiosk(["fleet", "publish", str(files[("denim-shorts", "4")]), *common,
                    "--trusted-keys", str(trusted)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not among the trusted keys" in err
    assert vtkiosk(["fleet", "publish", str(files[("denim-shorts", "1")]), *common,
                    "--trusted-keys", str(trusted), "--rollout", "20"]) == 0
    assert "published denim-shorts 1 to canary (20% of its kiosks" in capsys.readouterr().out
    assert vtkiosk(["fleet", "status", "--repo", str(fleet.tmp / "repo"), "--kiosk-id", "store-1"]) == 0
    out = capsys.readouterr().out
    assert "canary   denim-shorts  1" in out and "rollout bucket" in out
    assert vtkiosk(["fleet", "promote", "denim-shorts", "9", *common]) == 2
    assert "not on channel canary" in capsys.readouterr().err


def test_refresh_re_signs_what_runs_out_and_kiosks_accept_it(fleet):
    from datetime import timedelta

    fleet.publish("denim-shorts", "1")
    k = fleet.kiosk("k", "canary")
    assert k.sync.run().result == "ok"
    before = {s.role: s.version for s in fleet.repo.status()}
    assert fleet.repo.refresh() == ["timestamp"]  # fresh repository: only the timestamp
    assert fleet.repo.offline_expiry_warnings(within=timedelta(days=400))  # root and targets within 400 days
    # With the offline keys, roles close to expiry (here: within 400 days, i.e. all) are re-signed for a year.
    done = fleet.repo.refresh(offline_within=timedelta(days=400))
    assert done[:2] == ["root", "targets"] and done[-2:] == ["snapshot", "timestamp"]
    after = {s.role: s.version for s in fleet.repo.status()}
    assert after["root"] == before["root"] + 1 and after["targets"] == before["targets"] + 1
    assert k.sync.run().result == "ok"
    assert (k.sync.state_dir / "metadata" / "root_history" / f"{after['root']}.root.json").is_file()
