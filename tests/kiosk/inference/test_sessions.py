"""Session settings reach the engines as configured, change only scheduling (never the result beyond float
reduction order), and the preview lane gets sessions of its own."""
from __future__ import annotations

import numpy as np
import onnxruntime as ort
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kiosk.bundle.archive import open_bundle
from kiosk.bundle.signature import load_trusted_keys
from kiosk.contract.graph import feeds
from kiosk.contract.sketch import network_input, object_mask, rasterize
from kiosk.inference.backends import open_graph
from kiosk.inference.engine import LoadedBundle
from kiosk.inference.sessions import EXECUTION_MODES, OPENVINO_HINTS, SessionSettings
from tests.kiosk.bundle_factory import conv_graph, make_bundle


@pytest.fixture(scope="module")
def conv_bundle(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sessions")
    path, trusted = make_bundle(tmp, graph=conv_graph)
    return open_bundle(path, load_trusted_keys(trusted), workdir=tmp / "w")


def _x(size=256):
    s = rasterize([[(30, 30), (220, 40), (200, 220), (40, 200), (30, 30)]], (size, size))
    return network_input(s, object_mask(s))


def test_ort_options_carry_every_setting():
    s = SessionSettings(threads=1, mem_arena=False, mem_pattern=False, execution_mode="parallel", spinning=True)
    o = s.ort_options()
    assert o.intra_op_num_threads == 1 and not o.enable_cpu_mem_arena and not o.enable_mem_pattern
    assert o.execution_mode == ort.ExecutionMode.ORT_PARALLEL
    assert o.get_session_config_entry("session.intra_op.allow_spinning") == "1"
    d = SessionSettings().ort_options()
    assert d.enable_cpu_mem_arena and d.enable_mem_pattern and d.execution_mode == ort.ExecutionMode.ORT_SEQUENTIAL
    assert d.get_session_config_entry("session.intra_op.allow_spinning") == "0"


def test_openvino_config_names_threads_streams_and_hint():
    cfg = SessionSettings(threads=2, streams=2, hint="throughput").openvino_config()
    assert cfg == {"INFERENCE_NUM_THREADS": 2, "NUM_STREAMS": 2, "PERFORMANCE_HINT": "THROUGHPUT",
                   "INFERENCE_PRECISION_HINT": "f32"}


@pytest.mark.parametrize("kwargs, message", [
    ({"threads": 0}, "threads must be an integer from 1 to 64"),
    ({"execution_mode": "fast"}, "execution mode must be one of"),
    ({"streams": 0}, "streams must be an integer from 1 to 16"),
    ({"hint": "speed"}, "hint must be one of"),
])
def test_bad_settings_are_refused_with_one_line(kwargs, message):
    with pytest.raises(ValueError, match=message) as err:
        SessionSettings(**kwargs)
    assert "\n" not in str(err.value)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(threads=st.integers(1, 2), arena=st.booleans(), pattern=st.booleans(),
       mode=st.sampled_from(EXECUTION_MODES))
def test_ort_settings_change_scheduling_not_results(conv_bundle, threads, arena, pattern, mode):
    x = feeds(*(lambda n: (n.sketch, n.mask))(_x()))
    path = conv_bundle.graph_path("full")
    want = open_graph("onnxruntime", path, threads=1).run(["visual", "tactile"], x)
    s = SessionSettings(mem_arena=arena, mem_pattern=pattern, execution_mode=mode)
    got = open_graph("onnxruntime", path, threads=threads, settings=s).run(["visual", "tactile"], x)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, atol=1e-5)


@pytest.mark.parametrize("streams, hint", [(1, "latency"), (1, "throughput"), (2, "throughput")])
def test_openvino_streams_and_hint_keep_the_result(conv_bundle, streams, hint):
    assert hint in OPENVINO_HINTS
    x = feeds(*(lambda n: (n.sketch, n.mask))(_x()))
    path = conv_bundle.graph_path("tactile")
    want = open_graph("onnxruntime", path, threads=1).run(["tactile"], x)[0]
    got = open_graph("openvino", path, threads=2, settings=SessionSettings(streams=streams, hint=hint)).run(
        ["tactile"], x)[0]
    np.testing.assert_allclose(got, want, atol=1e-4)


def test_preview_lane_has_its_own_sessions_only_when_configured(conv_bundle):
    x = _x()
    lanes = LoadedBundle(conv_bundle, threads=2, preview_threads=1)
    a = lanes.run("visual", x, "preview").outputs["visual"]
    b = lanes.run("visual", x, "main").outputs["visual"]
    assert set(lanes._sessions) == {("visual", "preview"), ("visual", "main")}
    np.testing.assert_allclose(a, b, atol=1e-5)
    shared = LoadedBundle(conv_bundle, threads=2, preview_threads=0)
    shared.run("visual", x, "preview")
    assert set(shared._sessions) == {("visual", "main")}
    with pytest.raises(ValueError, match="lane must be one of"):
        shared.run("visual", x, "background")
