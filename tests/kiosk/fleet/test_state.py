"""The sync state as the daemon reads it: never synced, fresh, stale, failing, and a torn file."""
from __future__ import annotations

import pytest

from kiosk.fleet.state import STATE_FILE, fleet_check, record, register_metrics, section
from kiosk.ops.metrics import MetricError, Registry


def test_check_never_fails_and_says_how_old_the_metadata_is(tmp_path):
    path = tmp_path / STATE_FILE
    now = [1_000_000.0]
    check = fleet_check(path, stale_after_s=3600, clock=lambda: now[0])
    r = check()
    assert r.ok and "no successful sync yet" in r.detail
    record(path, {"result": "ok", "detail": "1 garment(s) up to date", "garments": [],
                  "metadata": {"timestamp_version": 7, "timestamp_expires": "1970-01-13T00:00:00+00:00",
                               "verified": True}},
           now=now[0])
    now[0] += 90
    r = check()
    assert r.ok and r.detail.startswith("metadata 1.5 min old;")
    record(path, {"result": "offline", "detail": "repository unreachable", "garments": []}, now=now[0])
    now[0] += 7200
    r = check()
    assert r.ok and "(stale)" in r.detail and "last sync offline (1 in a row): repository unreachable" in r.detail
    s = section(path, 3600, now=now[0])
    assert "verified" not in s and s["stale"] and s["consecutive_failures"] == 1 and s["timestamp_version"] == 7
    assert s["metadata_age_s"] == pytest.approx(7290)


def test_torn_state_reads_as_none_and_metrics_render_nan_not_an_error(tmp_path):
    path = tmp_path / STATE_FILE
    path.write_text('{"metadata_verified_at": 12')
    assert section(path, 60)["metadata_age_s"] is None
    reg = Registry()
    register_metrics(reg, path)
    text = reg.render()
    assert "vtkiosk_fleet_metadata_age_seconds NaN" in text
    assert 'vtkiosk_fleet_syncs_total{result="ok"} 0.0' in text
    with pytest.raises(MetricError, match="read from a function"):
        reg.get("vtkiosk_fleet_syncs_total").inc(result="ok")
