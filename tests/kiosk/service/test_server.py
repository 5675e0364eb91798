"""The HTTP server (real sockets on 127.0.0.1) and the render request parser (property-based)."""
from __future__ import annotations

from http.client import HTTPConnection
import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kiosk.service.api import MAX_STROKES, parse_render_request, parse_strokes
from kiosk.service.config import ConfigError
from kiosk.contract.errors import InputError, KioskError
from kiosk.service.server import KioskServer, Response
from tests.kiosk.bundle_factory import make_bundle
from tests.kiosk.daemon_fixtures import http, start_daemon


@pytest.fixture()
def server(tmp_path):
    static = tmp_path / "static"
    static.mkdir()
    (static / "index.html").write_text("<h1>kiosk</h1>")
    (static / "study.html").write_text("<h1>study</h1>")
    (static / "app.js").write_text("console.log(1)")
    s = KioskServer("127.0.0.1", 0, static_dir=static, max_body_bytes=1024)
    s.route("GET", "/api/echo", lambda req: Response.json({"path": req.path, "q": req.arg("q")}))
    s.route("POST", "/api/echo", lambda req: Response.json({"body": req.json()}))
    s.route("GET", "/api/echo/deep/", lambda req: Response.json({"deep": True}))
    s.route("GET", "/api/user-error", lambda req: (_ for _ in ()).throw(InputError("you did it wrong")))
    s.route("GET", "/api/bug", lambda req: 1 / 0)
    s.start()
    yield s
    s.stop()


def test_routes_static_and_errors(server):
    u = server.url
    status, body, ctype = http(u + "api/echo?q=1")
    assert status == 200 and json.loads(body) == {"path": "/api/echo", "q": "1"} and ctype == "application/json"
    assert json.loads(http(u + "api/echo/deep/x")[1]) == {"deep": True}  # the longest prefix wins
    assert json.loads(http(u + "api/echo/other")[1])["path"] == "/api/echo/other"
    assert http(u + "api/echoes")[0] == 404  # a prefix matches whole path segments only
    assert json.loads(http(u + "api/echo", {"a": [1, 2]})[1]) == {"body": {"a": [1, 2]}}
    assert http(u)[1] == b"<h1>kiosk</h1>" and "text/html" in http(u)[2]
    assert http(u + "study")[1] == b"<h1>study</h1>"
    assert "javascript" in http(u + "static/app.js")[2]
    assert http(u + "static/../secret")[0] == 404 and http(u + "nothing")[0] == 404
    status, body, _ = http(u + "api/user-error")
    assert status == 400 and json.loads(body) == {"error": "you did it wrong"}
    status, body, _ = http(u + "api/bug")
    assert status == 500 and "internal error" in json.loads(body)["error"]
    assert http(u + "api/echo")[0] == 200  # still serving after a handler crashed


def test_bad_bodies_are_clear_400s(server):
    u = server.url + "api/echo"
    for raw, message in ((b"{not json", "not valid JSON"), (b"\xff\xfe", "not UTF-8"), (b"", "needs a JSON body"),
                         (b'{"x": NaN}', "NaN"), (b"[" * 100000 + b"]" * 100000, "")):
        status, body, _ = http(u, raw=raw)
        assert status in (400, 413), raw[:20]
        assert message in json.loads(body)["error"]
    status, body, _ = http(u, raw=b"x" * 2000)
    assert status == 413 and "over 1024 bytes" in json.loads(body)["error"]


def test_method_not_allowed_and_keep_alive(server):
    conn = HTTPConnection("127.0.0.1", server.port, timeout=5)
    conn.request("DELETE", "/api/echo")
    r = conn.getresponse()
    assert r.status == 405 and "not allowed" in json.loads(r.read())["error"]
    sock = conn.sock
    conn.request("GET", "/api/echo?q=2")  # the same connection: HTTP/1.1 keep-alive
    r = conn.getresponse()
    assert r.status == 200 and json.loads(r.read())["q"] == "2" and conn.sock is sock
    conn.close()


def test_refuses_non_loopback_unless_allowed():
    with pytest.raises(ConfigError, match="loopback only"):
        KioskServer("0.0.0.0", 0)
    KioskServer("0.0.0.0", 0, allow_non_loopback=True)  # constructing does not bind


def test_port_in_use_is_a_clear_error(server):
    other = KioskServer("127.0.0.1", server.port)
    with pytest.raises(ConfigError, match="cannot listen"):
        other.start()


# -- the render request parser ----------------------------------------------------------------------------------------
def test_single_panel_request():
    r = parse_render_request({"garment": "g", "panel": {"x": 0, "y": 0, "w": 640, "h": 400}, "screen": [1280, 800],
                              "strokes": [[[1, 2], [3.5, 4, 0.5, 16]], []], "mode": "preview"})
    assert r.preview and r.scene.panels[0].rect == (0, 0, 640, 400) and r.scene.screen == (1280, 800)
    (s,) = r.sketches["main"].strokes
    np.testing.assert_array_equal(s, [[1, 2], [3.5, 4]])


def test_scene_request():
    r = parse_render_request({"scene": {"screen": [1280, 800], "panels": [
        {"id": "a", "rect": [0, 0, 640, 800], "bundle": "g", "visual": "reference", "tactile": "model",
         "sketch": "reference", "half": "left"}]}, "sketches": {"a": {"strokes": [], "base": True}}})
    assert not r.preview and r.scene.panels[0].half == "left" and r.sketches["a"].base


@pytest.mark.parametrize("doc, message", [
    ([], "must be a JSON object"),
    ({"garment": "g", "panel": [0, 0, 10, 10], "strokes": "abc"}, "strokes must be a list"),
    ({"garment": "g", "panel": [0, 0, 10, 10], "strokes": [[[1]]]}, r"strokes\[0\]\[0\] must be"),
    ({"garment": "g", "panel": [0, 0, 10, 10], "strokes": [[[1, True]]]}, "finite number"),
    ({"garment": "g", "panel": [0, 0, 10, 10], "strokes": [[[1, 1e300]]]}, "finite number"),
    ({"garment": "g", "panel": [0, 0, 10, 10], "strokes": [[1, 2]]}, r"strokes\[0\]\[0\]"),
    ({"garment": "g", "panel": [0, 0, 0, 10]}, "width/height"),
    ({"garment": "g", "panel": {"x": 0}}, "x, y, w, h"),
    ({"garment": "", "panel": [0, 0, 10, 10]}, "garment must be"),
    ({"garment": "g", "panel": [0, 0, 10, 10], "mode": "fast"}, "mode must be"),
    ({"garment": "g", "panel": [0, 0, 10, 10], "colour": 1}, "unknown field"),
    ({"garment": "g", "panel": [0, 0, 10, 10], "strokes": [[]] * (MAX_STROKES + 1)}, "more than"),
    ({"scene": {"screen": [10, 10], "panels": [{"id": "a", "rect": [0, 0, 5, 5], "bundle": "g",
                                                "visual": "photo"}]}}, "visual must be one of"),
    ({"scene": {"screen": [10, 10], "panels": []}}, "1 to 16 panels"),
    ({"scene": {"screen": [10, 10], "panels": [{"id": "a", "rect": [0, 0, 5, 5], "bundle": "g"}]},
      "sketches": {"b": {}}}, "unknown panel"),
])
def test_malformed_requests_say_what_is_wrong(doc, message):
    with pytest.raises(InputError, match=message):
        parse_render_request(doc)


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20), st.floats(allow_nan=False), st.text(max_size=8)),
    lambda c: st.one_of(st.lists(c, max_size=5), st.dictionaries(st.sampled_from(
        ["garment", "panel", "screen", "strokes", "base", "mode", "client", "scene", "sketches", "panels", "id",
         "rect", "bundle", "visual", "tactile", "x", "y", "w", "h"]), c, max_size=6)), max_leaves=30)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(json_values)
def test_any_json_is_a_request_or_an_input_error(doc):
    try:
        parse_render_request(doc)
    except InputError as exc:
        assert str(exc)


points = st.lists(st.one_of(st.floats(-2000, 3000), st.integers(-10, 2000)), min_size=2, max_size=4)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(points, max_size=30), max_size=6))
def test_valid_strokes_round_trip(strokes):
    out = parse_strokes(strokes)
    assert len(out) == sum(1 for s in strokes if s)
    for got, src in zip(out, [s for s in strokes if s]):
        np.testing.assert_array_equal(got, [[p[0], p[1]] for p in src])


# -- over HTTP against the daemon: malformed strokes are 400s and the kiosk keeps serving ------------------------------
@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("server-daemon")
    path, trusted = make_bundle(tmp)
    d = start_daemon([path], trusted)
    yield d
    d.stop()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                 HealthCheck.too_slow])
@given(json_values)
def test_render_endpoint_answers_400_for_garbage(daemon, doc):
    status, body, ctype = http(daemon.server.url + "api/render", raw=json.dumps(doc).encode())
    assert status in (200, 400), body[:200]
    if status == 400:
        assert ctype == "application/json" and json.loads(body)["error"]


def test_render_endpoint_errors(daemon):
    u = daemon.server.url + "api/render"
    cases = [(b"{", "not valid JSON"), (json.dumps({"garment": "coat", "panel": [0, 0, 10, 10]}).encode(),
                                        "no garment 'coat'"),
             (json.dumps({"garment": "denim-shorts", "panel": [0, 0, 100, 100],
                          "strokes": [[[0, 0], [1, "x"]]]}).encode(), "finite number")]
    for raw, message in cases:
        status, body, _ = http(u, raw=raw)
        assert status == 400 and message in json.loads(body)["error"]
    assert http(daemon.server.url + "api/ping")[0] == 200
    assert issubclass(InputError, KioskError)
