"""The reload's swap rule on its own (the daemon tests drive it with real bundles): a passed bundle replaces its
garment's, a garment no candidate loaded for goes only when every candidate loaded, and never swap to nothing."""
from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from kiosk.service.bundles import failure_reason, plan_swap

GARMENTS = st.sets(st.sampled_from("abcdef"))


@given(current=GARMENTS, passed=GARMENTS, unchanged=GARMENTS, any_failed=st.booleans())
def test_the_swap_rule(current, passed, unchanged, any_failed):
    cur = {g: f"old-{g}" for g in current}
    new = {g: f"new-{g}" for g in passed}
    seen = passed | unchanged
    serving, removed = plan_swap(cur, new, seen, any_failed)
    for g in passed:
        assert serving[g] == f"new-{g}"
    if current and not serving:
        raise AssertionError("swapped to nothing")
    if not passed and current and not (current & seen) and not any_failed:
        assert serving == cur and removed == []           # everything would go: keep serving what is served
    elif not any_failed:
        assert set(removed) == current - seen
        assert set(serving) == (current & seen) | passed
    else:
        assert removed == [] and set(serving) == current | passed   # a failed candidate might be any garment
    for g in (current & unchanged) - passed:
        assert serving[g] == f"old-{g}"


def test_the_reason_names_each_garment_or_source():
    report = {"kept": [{"garment": "coat", "reason": "probe over budget"}],
              "failed": [{"source": "config", "reason": "no store"}]}
    assert failure_reason(report) == "coat: probe over budget; config: no store"
