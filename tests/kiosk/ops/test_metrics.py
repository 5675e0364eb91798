"""kiosk.ops.metrics: Prometheus text 0.0.4, checked by the reference parser (prometheus_client) as an outside oracle."""
from __future__ import annotations

import math
import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from prometheus_client.parser import text_string_to_metric_families

from kiosk.ops.metrics import DEFAULT_LATENCY_BUCKETS, MetricError, Registry


def _parse(text: str) -> dict:
    """name -> (type, documentation, [(sample name, labels, value)])."""
    return {f.name: (f.type, f.documentation, [(s.name, s.labels, s.value) for s in f.samples])
            for f in text_string_to_metric_families(text)}


def test_counter_gauge_histogram_round_trip_through_the_reference_parser():
    reg = Registry()
    frames = reg.counter("vtkiosk_frames_total", "Frames committed.", labels=("panel",))
    up = reg.gauge("vtkiosk_device_up", "1 when the haptic link is up.")
    lat = reg.histogram("vtkiosk_latency_seconds", "Stroke end to friction frame.", buckets=(0.01, 0.1, 1.0))
    frames.inc(panel="main")
    frames.inc(2, panel="main")
    frames.inc(panel="side")
    up.set(1)
    for v in (0.005, 0.01, 0.05, 0.5, 3.0):  # 0.01 sits exactly on a bound: 'le' includes it
        lat.observe(v)
    fams = _parse(reg.render())
    # the parser strips _total from counter family names
    typ, doc, samples = fams["vtkiosk_frames"]
    assert typ == "counter" and doc == "Frames committed."
    assert {(s[1]["panel"], s[2]) for s in samples} == {("main", 3.0), ("side", 1.0)}
    assert fams["vtkiosk_device_up"][2] == [("vtkiosk_device_up", {}, 1.0)]
    typ, _, samples = fams["vtkiosk_latency_seconds"]
    assert typ == "histogram"
    buckets = {s[1]["le"]: s[2] for s in samples if s[0].endswith("_bucket")}
    assert buckets == {"0.01": 2.0, "0.1": 3.0, "1.0": 4.0, "+Inf": 5.0}
    by_name = {s[0]: s[2] for s in samples if not s[0].endswith("_bucket")}
    assert by_name["vtkiosk_latency_seconds_count"] == 5.0
    assert by_name["vtkiosk_latency_seconds_sum"] == pytest.approx(3.565)


def test_unlabelled_metrics_render_zero_before_any_use_and_labelled_ones_no_series():
    reg = Registry()
    reg.counter("a_total", "a")
    reg.histogram("h_seconds", "h")
    reg.gauge("g", "g", labels=("state",))
    fams = _parse(reg.render())
    assert fams["a"][2] == [("a_total", {}, 0.0)]
    assert len([s for s in fams["h_seconds"][2] if s[0] == "h_seconds_bucket"]) == len(DEFAULT_LATENCY_BUCKETS) + 1
    assert fams["g"][2] == []


def test_gauge_function_is_read_at_render_and_a_failing_one_renders_nan():
    reg = Registry()
    g = reg.gauge("rss_bytes", "resident memory")
    box = {"v": 10.0}
    g.set_function(lambda: box["v"])
    box["v"] = 42.0
    assert _parse(reg.render())["rss_bytes"][2][0][2] == 42.0
    g.set_function(lambda: 1 / 0)
    assert math.isnan(_parse(reg.render())["rss_bytes"][2][0][2])
    g.set(3)
    assert g.value() == 3.0


@pytest.mark.parametrize("bad, match", [
    (lambda r: r.counter("9starts_with_digit", "x"), "not a valid Prometheus name"),
    (lambda r: r.counter("has-dash", "x"), "not a valid Prometheus name"),
    (lambda r: r.counter("ok", "x", labels=("bad-label",)), "cannot be a label name"),
    (lambda r: r.counter("ok", "x", labels=("__reserved",)), "cannot be a label name"),
    (lambda r: r.histogram("ok", "x", labels=("le",)), "cannot be a label name"),
    (lambda r: r.counter("ok", "x", labels=("a", "a")), "repeat"),
    (lambda r: r.histogram("ok", "x", buckets=(0.1, 0.1)), "strictly increasing"),
    (lambda r: r.histogram("ok", "x", buckets=()), "strictly increasing"),
    (lambda r: r.counter("c", "x").inc(-1), "finite amount >= 0"),
    (lambda r: r.counter("c", "x").inc(math.nan), "finite amount >= 0"),
    (lambda r: r.counter("c", "x", labels=("p",)).inc(), "takes labels"),
    (lambda r: r.counter("c", "x").inc(p="a"), "takes labels"),
    (lambda r: r.histogram("h", "x").observe(math.nan), "cannot observe NaN"),
    (lambda r: (r.counter("m", "x"), r.gauge("m", "x")), "already declared"),
    (lambda r: (r.counter("m", "x", labels=("a",)), r.counter("m", "x", labels=("b",))), "already declared"),
    (lambda r: (r.histogram("lat", "x"), r.counter("lat_count", "x")), "collides"),
    (lambda r: (r.gauge("lat_sum", "x"), r.histogram("lat", "x")), "collide"),
    (lambda r: (c := r.counter("c", "x"), c.set_function(lambda: 1.0), c.inc()), "read from a function"),
    (lambda r: (g := r.gauge("g", "x"), g.set_function(lambda: 1.0), g.inc()), "read from a function"),
])
def test_misuse_is_a_clear_error(bad, match):
    with pytest.raises(MetricError, match=match):
        bad(Registry())


def test_redeclaring_the_same_metric_returns_it():
    reg = Registry()
    a = reg.counter("x_total", "x", labels=("k",))
    assert reg.counter("x_total", "x", labels=("k",)) is a


def test_concurrent_increments_lose_nothing():
    reg = Registry()
    c = reg.counter("c_total", "c", labels=("t",))
    h = reg.histogram("h_seconds", "h")

    def work(t: int) -> None:
        for _ in range(2000):
            c.inc(t=t % 2)
            h.observe(0.003)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert c.value(t=0) + c.value(t=1) == 8000
    _, total, count = h.snapshot()
    assert count == 8000 and total == pytest.approx(24.0)


label_values = st.text(st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=30)
help_texts = st.text(st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=60)
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=150, deadline=None)
@given(values=st.lists(label_values, min_size=1, max_size=5, unique=True), help_text=help_texts,
       amounts=st.lists(st.floats(min_value=0, max_value=1e12, allow_nan=False), min_size=1, max_size=5))
def test_any_label_value_and_help_text_survive_escaping(values, help_text, amounts):
    reg = Registry()
    c = reg.counter("esc_total", help_text, labels=("v",))
    expect = {}
    for v, a in zip(values, amounts * len(values)):
        c.inc(a, v=v)
        expect[v] = expect.get(v, 0.0) + a
    typ, doc, samples = _parse(reg.render())["esc"]
    assert doc == help_text.strip() or doc == help_text  # the parser strips surrounding blanks of HELP
    got = {s[1]["v"]: s[2] for s in samples}
    assert got.keys() == expect.keys()
    for k, v in expect.items():
        assert got[k] == pytest.approx(v, rel=1e-15)


@settings(max_examples=150, deadline=None)
@given(gauge=st.one_of(finite, st.sampled_from([math.inf, -math.inf, math.nan])),
       observations=st.lists(st.floats(min_value=-1e6, max_value=1e6, allow_nan=False), max_size=40),
       buckets=st.lists(st.floats(min_value=-1e3, max_value=1e3, allow_nan=False), min_size=1, max_size=8,
                        unique=True).map(sorted))
def test_values_and_buckets_parse_back_exactly(gauge, observations, buckets):
    reg = Registry()
    reg.gauge("g", "g").set(gauge)
    h = reg.histogram("h", "h", buckets=buckets)
    for o in observations:
        h.observe(o)
    fams = _parse(reg.render())
    got = fams["g"][2][0][2]
    assert (math.isnan(got) and math.isnan(gauge)) or got == gauge
    samples = fams["h"][2]
    cum = [(s[1]["le"], s[2]) for s in samples if s[0] == "h_bucket"]
    assert [float(le) for le, _ in cum] == [*buckets, math.inf]
    for le, count in cum:
        assert count == sum(1 for o in observations if o <= float(le))
    counts = [c for _, c in cum]
    assert counts == sorted(counts)
    assert dict((s[0], s[2]) for s in samples)["h_count"] == len(observations)
