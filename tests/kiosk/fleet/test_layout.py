"""What publisher and kiosk agree on: rollout buckets, release metadata, channel indexes (property-based where the
input comes from outside)."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.fleet.layout import (FleetError, Release, RefusedError, index_bytes, parse_index, release_from_custom,
                                rollout_bucket, target_path)

kiosk_ids = st.from_regex(r"\A[A-Za-z0-9][A-Za-z0-9._:-]{0,40}\Z")


@settings(max_examples=200, deadline=None)
@given(kiosk_ids, st.integers(0, 100), st.integers(0, 100))
def test_rollout_is_stable_and_only_grows(kid, p, q):
    b = rollout_bucket(kid)
    assert 0 <= b < 100 and rollout_bucket(kid) == b
    low, high = sorted((p, q))
    r_low = Release("stable/g/g-1.vtb", "g", "1", "stable", low)
    r_high = Release("stable/g/g-1.vtb", "g", "1", "stable", high)
    assert not r_low.reaches(kid) or r_high.reaches(kid)  # raising the percentage never drops a kiosk
    assert Release("stable/g/g-1.vtb", "g", "1", "stable", 100).reaches(kid)
    assert not Release("stable/g/g-1.vtb", "g", "1", "stable", 0).reaches(kid)


def test_rollout_spreads_kiosks_over_the_buckets():
    buckets = [rollout_bucket(f"store-{i}") for i in range(2000)]
    share = sum(b < 25 for b in buckets) / len(buckets)
    assert 0.20 < share < 0.30  # 25% rollout reaches about a quarter of the fleet


@pytest.mark.parametrize("bad", ["", "-x", "a b", "x" * 129, "é", None])
def test_kiosk_ids_are_checked(bad):
    with pytest.raises(FleetError, match="kiosk id"):
        rollout_bucket(bad)


def test_release_metadata_round_trips_and_must_match_its_path():
    r = Release(target_path("canary", "denim-shorts", "2026.11.21-1"), "denim-shorts", "2026.11.21-1", "canary", 30,
                "0.1.0", False, "2026-11-21T00:00:00+00:00")
    assert release_from_custom(r.path, r.custom()) == r
    with pytest.raises(RefusedError, match="moved to another path"):
        release_from_custom("stable/denim-shorts/denim-shorts-2026.11.21-1.vtb", r.custom())
    for broken in ({}, {"vtkiosk": {}}, {"vtkiosk": {**r.custom()["vtkiosk"], "rollout": 101}},
                   {"vtkiosk": {**r.custom()["vtkiosk"], "withdrawn": "no"}},
                   {"vtkiosk": {**r.custom()["vtkiosk"], "min_runtime": "../x"}}, None, []):
        with pytest.raises(RefusedError):
            release_from_custom(r.path, broken)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=400))
def test_index_parser_takes_any_bytes_and_refuses_in_one_line(data):
    try:
        paths = parse_index("canary", data)
    except RefusedError as exc:
        assert "\n" not in str(exc)
    else:
        assert all(p.startswith("canary/") for p in paths)


def test_index_round_trip_and_refusals():
    paths = ["canary/a/a-1.vtb", "canary/b/b-2.vtb"]
    assert parse_index("canary", index_bytes("canary", paths)) == paths
    with pytest.raises(RefusedError, match="not a bundle of channel canary"):
        parse_index("canary", index_bytes("canary", ["stable/a/a-1.vtb"]))
    with pytest.raises(RefusedError, match="index of channel canary"):
        parse_index("canary", index_bytes("stable", []))
