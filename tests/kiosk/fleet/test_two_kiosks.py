"""The fleet's done-when: two kiosks' stores against one loopback repository. A bundle goes to canary, reaches the
canary kiosk only, is promoted and reaches both; a downgrade and a freeze are refused with nothing lost. Then the
operator's other two levers: a staged rollout by kiosk-id bucket, and an emergency rollback by withdrawal."""
from __future__ import annotations

from datetime import datetime, timedelta, timezone

from tuf.api.metadata import Metadata

from kiosk.fleet import keys as rolekeys
from tests.kiosk.fleet.conftest import kiosk_id_in_bucket


def state(*kiosks):
    return [(k.active(), k.installed()) for k in kiosks]


def test_canary_then_promote_then_both_and_downgrade_and_freeze_refused(fleet):
    canary, stable = fleet.kiosk("store-1", "canary"), fleet.kiosk("store-2", "stable")
    fleet.publish("denim-shorts", "1")
    fleet.repo.promote("denim-shorts", "1")
    assert [k.sync.run().result for k in (canary, stable)] == ["ok", "ok"]
    assert state(canary, stable) == [("1", ["1"]), ("1", ["1"])]

    fleet.publish("denim-shorts", "2")  # canary only
    r1, r2 = canary.sync.run(), stable.sync.run()
    assert (r1.garments[0].outcome, r2.garments[0].outcome) == ("installed", "up_to_date")
    assert state(canary, stable) == [("2", ["1", "2"]), ("1", ["1"])]

    fleet.repo.promote("denim-shorts", "2")
    r1, r2 = canary.sync.run(), stable.sync.run()
    assert (r1.garments[0].outcome, r2.garments[0].outcome) == ("up_to_date", "installed")
    assert state(canary, stable) == [("2", ["1", "2"]), ("2", ["1", "2"])]
    before = state(canary, stable)

    # Downgrade: whoever holds the stable key drops 2 from stable, so the newest stable release is 1 again.
    def drop_2(targets):
        del targets.targets["stable/denim-shorts/denim-shorts-2.vtb"]

    fleet.repo._edit_channel("stable", drop_2)
    r1, r2 = canary.sync.run(), stable.sync.run()
    assert r2.result == "refused" and r2.garments[0].outcome == "refused_downgrade", r2.to_json()
    assert "older than the active 2" in r2.garments[0].detail
    assert r1.garments[0].outcome == "up_to_date"  # the canary kiosk still sees 2 on canary
    assert state(canary, stable) == before

    # Freeze: the mirror serves a timestamp that has expired, over a repository that moved on.
    fleet.publish("denim-shorts", "3")
    fleet.repo.promote("denim-shorts", "3")
    ts = Metadata.from_file(str(fleet.tmp / "repo/metadata/timestamp.json"))
    ts.signed.expires = datetime.now(timezone.utc).replace(microsecond=0) - timedelta(minutes=5)
    ts.sign(rolekeys.load(fleet.tmp / "keys", "timestamp"))
    ts.to_file(str(fleet.tmp / "repo/metadata/timestamp.json"))
    for k in (canary, stable):
        r = k.sync.run()
        assert r.result == "refused" and "timestamp.json" in r.detail and "freeze" in r.detail, r.detail
    assert state(canary, stable) == before

    # The honest repository refreshes its timestamp: both move on to 3, nothing was lost on the way.
    fleet.repo.refresh()
    assert [k.sync.run().result for k in (canary, stable)] == ["ok", "ok"]
    assert state(canary, stable) == [("3", ["1", "2", "3"]), ("3", ["1", "2", "3"])]


def test_staged_rollout_reaches_the_low_buckets_first(fleet):
    early = fleet.kiosk("early", "stable", kiosk_id=kiosk_id_in_bucket(0, 25))
    late = fleet.kiosk("late", "stable", kiosk_id=kiosk_id_in_bucket(75, 100))
    fleet.publish("denim-shorts", "1")
    fleet.repo.promote("denim-shorts", "1", rollout=50)
    r_early, r_late = early.sync.run(), late.sync.run()
    assert (early.active(), late.active()) == ("1", None)
    assert r_late.garments[0].outcome == "not_offered"
    fleet.repo.promote("denim-shorts", "1", rollout=100)
    late.sync.run()
    assert late.active() == "1"


def test_emergency_rollback_by_withdrawal(fleet):
    a, b = fleet.kiosk("a", "canary"), fleet.kiosk("b", "stable")
    for v in ("1", "2"):
        fleet.publish("denim-shorts", v)
        fleet.repo.promote("denim-shorts", v)
        for k in (a, b):
            k.sync.run()
    assert (a.active(), b.active()) == ("2", "2")
    fleet.repo.withdraw("denim-shorts", "2")
    for k in (a, b):
        r = k.sync.run()
        assert r.result == "ok" and r.garments[0].outcome == "withdrawn_rollback", r.to_json()
    assert (a.active(), b.active()) == ("1", "1")
    # A kiosk that never had 2 is not given it; a later sync does not re-install it.
    c = fleet.kiosk("c", "stable")
    c.sync.run()
    assert c.active() == "1" and c.installed() == ["1"]
    assert a.sync.run().garments[0].outcome == "up_to_date" and a.active() == "1"
    # The fix ships as a new version and everyone moves forward again.
    fleet.publish("denim-shorts", "3")
    fleet.repo.promote("denim-shorts", "3")
    for k in (a, b, c):
        k.sync.run()
    assert (a.active(), b.active(), c.active()) == ("3", "3", "3")


def test_a_withdrawn_version_with_nothing_to_go_back_to_keeps_serving(fleet):
    k = fleet.kiosk("k", "canary")
    fleet.publish("denim-shorts", "1")
    k.sync.run()
    fleet.repo.withdraw("denim-shorts", "1")
    r = k.sync.run()
    assert r.garments[0].outcome == "withdrawn_kept" and k.active() == "1"


def test_min_runtime_keeps_a_bundle_from_older_kiosks(fleet):
    k = fleet.kiosk("k", "canary")
    k.sync.runtime = "0.1.0"
    fleet.publish("denim-shorts", "1", min_runtime="0.2")
    r = k.sync.run()
    assert r.garments[0].outcome == "needs_runtime" and "needs runtime 0.2" in r.garments[0].detail
    assert k.active() is None
    k.sync.runtime = "0.2.0"
    assert k.sync.run().garments[0].outcome == "installed"
