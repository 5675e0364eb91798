"""Each attack on the update path, played by a real HTTP server on loopback, against a kiosk with a real store.

Every test first lets the kiosk reach a known good state, then attacks, then checks three things: the sync says
what it refused (result and a one-line reason naming the attack), the active bundle is the one from before, and
nothing new was installed.
"""
from __future__ import annotations

import json
import shutil
from datetime import datetime, timedelta, timezone

from tuf.api.metadata import Metadata

from kiosk.fleet import keys as rolekeys
from tests.kiosk.fleet.loopback import ENDLESS_CAP, RepoServer


def synced(fleet, version="1", channel="canary"):
    """A canary kiosk that installed and runs denim-shorts `version`."""
    fleet.publish("denim-shorts", version, channel)
    k = fleet.kiosk("k", "canary")
    r = k.sync.run()
    assert r.result == "ok" and k.active() == version, r.to_json()
    return k


def untouched(kiosk, active="1", installed=("1",)):
    assert kiosk.active() == active
    assert kiosk.installed() == list(installed)


def replay(fleet, saved):
    """The mirror now serves an old copy of the repository."""
    shutil.rmtree(fleet.tmp / "repo")
    shutil.copytree(saved, fleet.tmp / "repo")


def target_file(fleet, channel, garment, version):
    t = fleet.repo.open(channel).signed.targets[f"{channel}/{garment}/{garment}-{version}.vtb"]
    return fleet.tmp / "repo" / "targets" / channel / garment / f"{t.hashes['sha256']}.{garment}-{version}.vtb"


def test_rollback_attack_old_timestamp_and_snapshot_is_refused(fleet):
    fleet.publish("denim-shorts", "1")
    old = fleet.snapshot_repo("v1")  # validly signed, unexpired, and older than what the kiosk will see
    k = synced(fleet, "2")
    replay(fleet, old)
    r = k.sync.run()
    assert r.result == "refused" and "rollback" in r.detail and "timestamp" in r.detail, r.detail
    untouched(k, "2", ["2"])
    assert k.sync._trusted_metadata()["timestamp_version"] == 3  # it still trusts the newer timestamp


def test_freeze_attack_expired_timestamp_is_refused(fleet):
    k = synced(fleet)
    fleet.publish("denim-shorts", "2")
    # The mirror serves a timestamp whose expiry has passed (what an old, once-valid timestamp is after a day).
    ts = Metadata.from_file(str(fleet.tmp / "repo/metadata/timestamp.json"))
    ts.signed.expires = datetime.now(timezone.utc).replace(microsecond=0) - timedelta(hours=1)
    ts.sign(rolekeys.load(fleet.tmp / "keys", "timestamp"))
    ts.to_file(str(fleet.tmp / "repo/metadata/timestamp.json"))
    r = k.sync.run()
    assert r.result == "refused" and "freeze" in r.detail and "expired" in r.detail.lower(), r.detail
    untouched(k)


def test_mix_and_match_of_metadata_is_refused(fleet):
    k = synced(fleet)
    fleet.publish("denim-shorts", "2")
    meta = fleet.tmp / "repo" / "metadata"
    newest = max(int(p.name.split(".")[0]) for p in meta.glob("*.canary.json"))
    # The new canary role's name, an older (validly signed) canary role's bytes.
    (meta / f"{newest}.canary.json").write_bytes((meta / f"{newest - 1}.canary.json").read_bytes())
    r = k.sync.run()
    assert r.result == "refused" and "canary" in r.detail and "mixed and matched" in r.detail, r.detail
    untouched(k)


def test_arbitrary_target_is_refused_even_when_it_is_a_validly_signed_bundle(fleet):
    k = synced(fleet)
    fleet.publish("denim-shorts", "2")
    # The mirror swaps in another bundle that carries a good bundle signature (version 3): TUF must still refuse.
    target_file(fleet, "canary", "denim-shorts", "2").write_bytes(fleet.files[("denim-shorts", "3")].read_bytes())
    r = k.sync.run()
    assert r.result == "refused", r.detail
    (g,) = r.garments
    assert g.outcome == "refused_target" and "denim-shorts-2.vtb" in g.detail and "tampered" in g.detail, g.detail
    untouched(k)


def test_tampered_target_is_refused(fleet):
    k = synced(fleet)
    fleet.publish("denim-shorts", "2")
    path = target_file(fleet, "canary", "denim-shorts", "2")
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    r = k.sync.run()
    (g,) = r.garments
    assert r.result == "refused" and g.outcome == "refused_target" and "hash" in g.detail.lower(), g.detail
    untouched(k)


def test_endless_data_is_cut_at_the_signed_length_and_refused(fleet):
    k = synced(fleet)
    fleet.publish("denim-shorts", "2")
    length = fleet.repo.open("canary").signed.targets["canary/denim-shorts/denim-shorts-2.vtb"].length
    fleet.server.hook(".denim-shorts-2.vtb", fleet.server.endless)
    r = k.sync.run()
    (g,) = r.garments
    assert r.result == "refused" and g.outcome == "refused_target" and "endless" in g.detail, g.detail
    assert fleet.server.sent < ENDLESS_CAP  # the kiosk hung up; it did not read until the server gave up
    assert fleet.server.sent >= length
    untouched(k)
    assert not list((k.sync.state_dir / "downloads").glob("*")) if (k.sync.state_dir / "downloads").exists() else True


def _forge_targets_with(fleet, signer):
    """What a thief of the targets key who also controls the publishing host can do: a new targets version signed
    with the stolen key, and snapshot and timestamp that vouch for it."""
    repo = fleet.repo
    md = repo.open("targets")
    md.signed.version += 1
    data = repo._write("targets", md, signer)
    repo._snapshot_and_timestamp({"targets": (md.signed.version, data)})


def test_revoked_and_rotated_targets_key_is_refused(fleet):
    k = synced(fleet)
    stolen = rolekeys.load(fleet.tmp / "offline", "targets")
    _forge_targets_with(fleet, stolen)
    assert k.sync.run().result == "ok"  # before the rotation the stolen key still works: the check below is real
    old_id, new_id, retired = fleet.repo.rotate_key("targets")
    assert old_id == stolen.public_key.keyid and retired.exists()
    fleet.publish("denim-shorts", "2")
    _forge_targets_with(fleet, stolen)
    r = k.sync.run()
    assert r.result == "refused" and "targets" in r.detail and "revoked key" in r.detail, r.detail
    untouched(k)
    # A kiosk that still trusts only the first root learns the rotation from the chain and refuses too.
    fresh = fleet.kiosk("fresh", "canary")
    assert fresh.sync.run().result == "refused" and fresh.active() is None


def test_root_key_rotation_is_followed_and_the_old_root_key_is_powerless(fleet):
    k = synced(fleet)
    old_root = rolekeys.load(fleet.tmp / "offline", "root")
    fleet.repo.rotate_key("root")
    fleet.publish("denim-shorts", "2")
    r = k.sync.run()
    assert r.result == "ok" and k.active() == "2", r.to_json()
    assert (k.sync.state_dir / "metadata" / "root_history" / "2.root.json").is_file()
    # The old root key signs a root version 3 that would hand the timestamp role to the thief.
    md = fleet.repo.open("root")
    md.signed.version += 1
    thief = rolekeys.generate(fleet.tmp / "thief", "timestamp")
    for keyid in list(md.signed.roles["timestamp"].keyids):
        md.signed.revoke_key(keyid, "timestamp")
    md.signed.add_key(thief.public_key, "timestamp")
    md.sign(old_root)
    md.to_file(str(fleet.tmp / "repo" / "metadata" / f"{md.signed.version}.root.json"))
    r = k.sync.run()
    assert r.result == "refused" and "root" in r.detail and "not signed by the keys" in r.detail, r.detail
    untouched(k, "2", ["1", "2"])


def test_valid_tuf_metadata_does_not_make_an_untrusted_bundle_signature_acceptable(fleet):
    k = synced(fleet)
    fleet.publish("denim-shorts", "4")  # correctly published, but the bundle is signed by a key kiosks do not trust
    r = k.sync.run()
    (g,) = r.garments
    assert r.result == "refused" and g.outcome == "refused_bundle", g.detail
    assert "signed by key" in g.detail and "not among the trusted keys" in g.detail, g.detail
    untouched(k)


def test_repository_going_away_mid_download_keeps_serving_and_retries(fleet):
    fleet.publish("denim-shorts", "1")
    k = fleet.kiosk("k", "canary", attempts=3, backoff_s=0.5)
    delays = []
    k.sync._sleep = delays.append
    assert k.sync.run().result == "ok"
    fleet.publish("denim-shorts", "2")
    fleet.server.hook(".denim-shorts-2.vtb", fleet.server.vanish_midway)
    r = k.sync.run()
    assert r.result == "offline" and r.attempts == 3 and "unreachable" in r.detail, r.to_json()
    assert len(delays) == 2 and 0.25 <= delays[0] <= 0.5 and 0.5 <= delays[1] <= 1.0  # exponential, jittered
    assert fleet.server.sent > 0  # it did die in the middle of the bundle
    untouched(k)
    state = json.loads((k.sync.state_dir / "state.json").read_text())
    assert state["last_result"] == "offline" and state["consecutive_failures"] == 1 and "last_success" in state
    assert "metadata_verified_at" in state  # /healthz counts the metadata age from the last verified refresh
    assert not (k.sync.state_dir / "downloads").exists()  # the half file is gone
    # The repository comes back at the same address: the next sync completes.
    with RepoServer(fleet.tmp / "repo", port=fleet.server.port):
        r = k.sync.run()
    assert r.result == "ok" and k.active() == "2", r.to_json()
