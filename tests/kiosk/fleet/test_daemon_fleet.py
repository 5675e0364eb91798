"""Fleet sync beside a real running daemon: the daemon is asked to load each new bundle and keeps serving the old
one when it refuses; /healthz shows the metadata's age and the last sync, /metrics the sync totals; an offline
repository changes none of what is served."""
from __future__ import annotations

import json

import pytest

from tests.kiosk.daemon_fixtures import http, render, start_daemon


def _daemon(fleet, kiosk, tmp_path, **inference):
    sock = tmp_path / "control.sock"
    kiosk.sync.control_socket = sock
    cfg = kiosk.sync.cfg
    return start_daemon([], fleet.trusted, store={"root": str(kiosk.store.root)}, control={"socket": str(sock)},
                        inference=inference,
                        fleet={"url": cfg.url, "root": str(cfg.root), "kiosk_id": cfg.kiosk_id,
                               "channel": cfg.channel, "state_dir": str(cfg.state_dir)})


def _serving(d) -> str:
    return d.bundles["denim-shorts"].key.split("#")[0]


@pytest.mark.slow
def test_sync_hands_bundles_to_the_daemon_and_healthz_shows_the_metadata_age(fleet, tmp_path):
    k = fleet.kiosk("k", "canary")
    fleet.publish("denim-shorts", "1")
    assert k.sync.run().result == "ok"  # provisioning: no daemon yet
    d = _daemon(fleet, k, tmp_path)
    try:
        status, body, _ = http(d.server.url + "healthz")
        h = json.loads(body)
        assert status == 200 and h["checks"]["fleet"]["ok"] and "metadata" in h["checks"]["fleet"]["detail"]
        assert h["fleet"]["last_result"] == "ok" and 0 <= h["fleet"]["metadata_age_s"] < 600
        assert h["fleet"]["stale"] is False and h["fleet"]["timestamp_expires_in_s"] > 3600

        fleet.publish("denim-shorts", "2")
        r = k.sync.run()
        assert r.garments[0].outcome == "installed" and "the daemon reloaded" in r.garments[0].detail
        assert _serving(d) == "denim-shorts@2"

        fleet.server.stop()  # the repository goes offline
        r = k.sync.run()
        assert r.result == "offline"
        status, body, _ = http(d.server.url + "healthz")
        h = json.loads(body)
        assert status == 200 and h["ok"]  # an offline repository never makes a serving kiosk unhealthy
        assert h["fleet"]["last_result"] == "offline" and h["fleet"]["consecutive_failures"] == 1
        assert "last sync offline" in h["checks"]["fleet"]["detail"]
        assert render(d)[0] == 200 and _serving(d) == "denim-shorts@2"

        metrics = http(d.server.url + "metrics")[1].decode()
        assert 'vtkiosk_fleet_syncs_total{result="ok"} 2.0' in metrics
        assert 'vtkiosk_fleet_syncs_total{result="offline"} 1.0' in metrics
        assert 'vtkiosk_fleet_bundle_outcomes_total{outcome="installed"} 2.0' in metrics
        assert "vtkiosk_fleet_sync_consecutive_failures 1.0" in metrics
        age = [line for line in metrics.splitlines() if line.startswith("vtkiosk_fleet_metadata_age_seconds ")]
        assert len(age) == 1 and 0 <= float(age[0].split()[1]) < 600
    finally:
        d.stop()


@pytest.mark.slow
def test_a_bundle_the_daemon_refuses_is_rolled_back_in_the_store(fleet, tmp_path):
    k = fleet.kiosk("k", "canary")
    fleet.publish("denim-shorts", "1")
    k.sync.run()
    # A latency budget no bundle can meet: the running daemon refuses every new one (the first is served anyway).
    d = _daemon(fleet, k, tmp_path, latency_budget_ms=0.001)
    try:
        fleet.publish("denim-shorts", "2")
        r = k.sync.run()
        g = r.garments[0]
        assert g.outcome == "rolled_back" and "latency budget" in g.detail, g.detail
        assert k.active() == "1" and _serving(d) == "denim-shorts@1"
        assert k.installed() == ["1", "2"]
        # Not retried behind the operator's back: it stays installed, inactive, until someone activates it.
        assert k.sync.run().garments[0].outcome == "installed_inactive" and k.active() == "1"
    finally:
        d.stop()
