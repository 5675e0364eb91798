"""Anonymous usage figures: the page's events are validated strictly (nothing but counts can come in) and land in
the daemon's /metrics; the page's settings come from the kiosk config."""
from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.contract.errors import InputError
from kiosk.ops.metrics import Registry
from kiosk.service.usage import UsageMetrics, parse_usage_event
from tests.kiosk.bundle_factory import make_bundle
from tests.kiosk.daemon_fixtures import http, start_daemon


@pytest.fixture()
def daemon(tmp_path):
    path, trusted = make_bundle(tmp_path)
    d = start_daemon([path], trusted, page={"idle_timeout_s": 45, "texts": {"feel": "Fühlen"}})
    yield d
    d.stop()


def test_events_are_counted():
    reg = Registry()
    usage = UsageMetrics(reg)
    for doc in ({"event": "session"}, {"event": "touch", "mode": "draw"}, {"event": "touch", "mode": "draw"},
                {"event": "touch", "mode": "feel"}, {"event": "felt", "seconds": 4.2}, {"event": "idle_reset"}):
        usage.record(parse_usage_event(doc))
    assert usage.sessions.value() == 1 and usage.idle_resets.value() == 1
    assert usage.touches.value(mode="draw") == 2 and usage.touches.value(mode="feel") == 1
    cum, total, count = usage.felt.snapshot()
    assert count == 1 and total == pytest.approx(4.2) and dict(cum)[5.0] == 1 and dict(cum)[3.0] == 0
    text = reg.render()
    assert 'vtkiosk_touches_total{mode="feel"} 1.0' in text and "vtkiosk_sessions_total 1.0" in text


@pytest.mark.parametrize("doc, message", [
    ([], "must be a JSON object"),
    ({}, "usage event must be one of"),
    ({"event": "stroke"}, "usage event must be one of"),
    ({"event": "touch"}, "touch mode must be one of"),
    ({"event": "touch", "mode": "pinch"}, "touch mode must be one of"),
    ({"event": "touch", "mode": "feel", "x": 10, "y": 20}, "takes no field"),  # no coordinates, ever
    ({"event": "session", "client": "page-1"}, "takes no field"),  # nothing that tells shoppers apart
    ({"event": "felt"}, "felt seconds must be a number"),
    ({"event": "felt", "seconds": -1}, "felt seconds must be a number"),
    ({"event": "felt", "seconds": True}, "felt seconds must be a number"),
    ({"event": "felt", "seconds": float("nan")}, "felt seconds must be a number"),
    ({"event": "felt", "seconds": 1e9}, "felt seconds must be a number"),
    ({"event": "idle_reset", "strokes": [[[1, 2]]]}, "takes no field"),
])
def test_anything_else_is_refused_with_one_line(doc, message):
    with pytest.raises(InputError, match=message) as info:
        parse_usage_event(doc)
    assert "\n" not in str(info.value) and info.value.user_facing


json_values = st.recursive(st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=8)),
                           lambda c: st.one_of(st.lists(c, max_size=3), st.dictionaries(st.text(max_size=8), c,
                                                                                        max_size=3)), max_leaves=8)
events = st.one_of(json_values, st.fixed_dictionaries(
    {"event": st.sampled_from(["session", "touch", "felt", "idle_reset", "x"])},
    optional={"mode": st.one_of(st.sampled_from(["draw", "feel"]), json_values), "seconds": json_values}))


@settings(max_examples=300, deadline=None)
@given(events)
def test_any_document_is_one_event_or_a_clear_error(doc):
    usage = UsageMetrics(Registry())
    try:
        ev = parse_usage_event(doc)
    except InputError as exc:
        assert str(exc) and "\n" not in str(exc)
        return
    usage.record(ev)
    assert set(doc) <= {"event", "mode", "seconds"}


def test_the_page_reports_over_http_and_metrics_show_it(daemon):
    url = daemon.server.url
    for body in ({"event": "session"}, {"event": "touch", "mode": "feel"}, {"event": "felt", "seconds": 7},
                 {"event": "idle_reset"}):
        status, data, _ = http(url + "api/usage", body)
        assert status == 204 and data == b""
    status, data, _ = http(url + "api/usage", {"event": "touch", "mode": "feel", "x": 3, "y": 4})
    assert status == 400 and "takes no field" in json.loads(data)["error"]
    status, data, _ = http(url + "metrics")
    text = data.decode()
    for line in ("vtkiosk_sessions_total 1.0", 'vtkiosk_touches_total{mode="feel"} 1.0',
                 'vtkiosk_touches_total{mode="draw"} 0.0', "vtkiosk_first_feel_seconds_count 1",
                 'vtkiosk_first_feel_seconds_bucket{le="8.0"} 1', "vtkiosk_idle_resets_total 1.0"):
        assert line in text.splitlines(), line


def test_the_page_reads_its_timings_and_texts_from_the_config(daemon):
    status, data, ctype = http(daemon.server.url + "api/page")
    page = json.loads(data)
    assert status == 200 and ctype.startswith("application/json")
    assert page["idle_timeout_s"] == 45.0 and page["texts"]["feel"] == "Fühlen"
    assert page["texts"]["draw"] == "Draw" and page["auto_feel"] is True
