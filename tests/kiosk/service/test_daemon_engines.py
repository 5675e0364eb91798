"""The daemon on `inference.engine: auto` and `openvino`: the choice and its figures reach /healthz and /metrics,
and the chosen engine serves strokes end to end (real bundle, real HTTP, emulated device)."""
from __future__ import annotations

import json

from tests.kiosk.bundle_factory import conv_graph, make_bundle
from tests.kiosk.daemon_fixtures import http, start_daemon


def test_auto_engine_choice_is_reported_in_healthz_and_metrics(tmp_path):
    path, trusted = make_bundle(tmp_path, graph=conv_graph)
    d = start_daemon([path], trusted, inference={"engine": {"type": "auto", "auto_runs": 1}})
    try:
        code, body, _ = http(d.server.url + "healthz")
        engines = json.loads(body)["engines"]["denim-shorts"]
        choice = engines["choice"]
        assert engines["engine"] == choice["engine"] in ("onnxruntime", "openvino")
        assert {f["engine"] for f in choice["figures"]} == {"onnxruntime", "openvino"}
        assert choice["cpu"]["isa"] is not None and choice["cpu"]["model"]
        metrics = http(d.server.url + "metrics")[1].decode()
        assert f'vtkiosk_engine_selected{{engine="{choice["engine"]}",garment="denim-shorts"}} 1.0' in metrics \
            or f'vtkiosk_engine_selected{{garment="denim-shorts",engine="{choice["engine"]}"}} 1.0' in metrics
        assert 'vtkiosk_engine_bench_ms{' in metrics and 'engine="openvino"' in metrics
        assert 'vtkiosk_engine_bench_error_levels{' in metrics
    finally:
        d.stop()


def test_openvino_engine_serves_the_bundle(tmp_path):
    path, trusted = make_bundle(tmp_path, graph=conv_graph)
    d = start_daemon([path], trusted, inference={"engine": {"type": "openvino"}})
    try:
        body = json.loads(http(d.server.url + "healthz")[1])
        assert body["engines"]["denim-shorts"] == {"engine": "openvino", "choice": None}
        metrics = http(d.server.url + "metrics")[1].decode()
        assert 'engine="openvino"' in metrics
        assert d.bundles["denim-shorts"].run("full", _sketch()).outputs["tactile"].shape == (1, 2, 256, 256)
    finally:
        d.stop()


def _sketch():
    from kiosk.contract.sketch import network_input, object_mask, rasterize
    s = rasterize([[(30, 30), (220, 40), (200, 220), (40, 200), (30, 30)]], (256, 256))
    return network_input(s, object_mask(s))
