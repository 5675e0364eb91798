"""Hostile web pages and slow clients against the real server on 127.0.0.1: DNS rebinding (a foreign Host),
cross-origin requests, non-JSON POSTs, absurd numbers, slow and too many connections."""
from __future__ import annotations

import json
import socket
import time
from http.client import HTTPConnection

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kiosk.service.server import KioskServer, Request, Response, split_host


@pytest.fixture()
def server(tmp_path):
    s = KioskServer("127.0.0.1", 0, static_dir=tmp_path, max_body_bytes=1 << 16)
    s.handled = []

    def record(req: Request) -> Response:
        s.handled.append(req.json())
        return Response.json({"recorded": True})

    s.route("POST", "/api/study/choice", record)
    s.route("GET", "/api/ping", lambda req: Response.json({"ok": True}))
    s.start()
    yield s
    s.stop()


def _call(server, method, path, body=None, headers=None):
    conn = HTTPConnection("127.0.0.1", server.port, timeout=10)
    try:
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        hdrs = {"Host": f"127.0.0.1:{server.port}", **(headers or {})}
        data = body if isinstance(body, bytes) or body is None else json.dumps(body).encode()
        if data is not None:
            hdrs.setdefault("Content-Type", "application/json")
            hdrs["Content-Length"] = str(len(data))
        for k, v in hdrs.items():
            if v is not None:
                conn.putheader(k, v)
        conn.endheaders(data)
        r = conn.getresponse()
        return r.status, json.loads(r.read() or b"{}")
    finally:
        conn.close()


CHOICE = {"token": "1-0-abc", "side": "left"}


def test_a_foreign_host_is_refused_dns_rebinding(server):
    p = server.port
    for host in ("attacker.example", f"attacker.example:{p}", f"127.0.0.1:{p + 1}", "127.0.0.1", None, "a b"):
        status, doc = _call(server, "POST", "/api/study/choice", CHOICE, {"Host": host})
        assert status == 421 and "does not serve the host" in doc["error"], (host, status, doc)
        assert _call(server, "GET", "/api/ping", headers={"Host": host})[0] == 421
    assert server.handled == []
    for host in (f"127.0.0.1:{p}", f"localhost:{p}", f"LOCALHOST:{p}", f"[::1]:{p}"):
        assert _call(server, "POST", "/api/study/choice", CHOICE, {"Host": host})[0] == 200, host
    assert len(server.handled) == 4


def test_configured_names_are_accepted(tmp_path):
    s = KioskServer("127.0.0.1", 0, static_dir=tmp_path, server_names=("kiosk-7.local",))
    s.route("GET", "/api/ping", lambda req: Response.json({"ok": True}))
    s.start()
    try:
        assert _call(s, "GET", "/api/ping", headers={"Host": f"kiosk-7.local:{s.port}"})[0] == 200
        assert _call(s, "GET", "/api/ping", headers={"Host": f"kiosk-8.local:{s.port}"})[0] == 421
    finally:
        s.stop()


def test_a_cross_origin_request_is_refused(server):
    p = server.port
    for origin in ("http://attacker.example", f"http://attacker.example:{p}", f"http://127.0.0.1:{p + 1}",
                   f"https://127.0.0.1:{p}", "null", f"http://127.0.0.1:{p}/x"):
        status, doc = _call(server, "POST", "/api/study/choice", CHOICE, {"Origin": origin})
        assert status == 403 and "not allowed" in doc["error"], (origin, status, doc)
    for site in ("cross-site", "same-site"):
        assert _call(server, "POST", "/api/study/choice", CHOICE, {"Sec-Fetch-Site": site})[0] == 403
    assert server.handled == []
    for origin in (f"http://127.0.0.1:{p}", f"http://localhost:{p}"):
        assert _call(server, "POST", "/api/study/choice", CHOICE,
                     {"Origin": origin, "Sec-Fetch-Site": "same-origin"})[0] == 200
    assert len(server.handled) == 2


def test_a_post_must_be_json(server):
    data = json.dumps(CHOICE).encode()
    for ctype in ("text/plain", "application/x-www-form-urlencoded", "multipart/form-data; boundary=x", None,
                  "application/jsonx"):
        status, doc = _call(server, "POST", "/api/study/choice", data, {"Content-Type": ctype})
        assert status == 415 and "application/json" in doc["error"], (ctype, status, doc)
    assert server.handled == []
    assert _call(server, "POST", "/api/study/choice", data,
                 {"Content-Type": "Application/JSON; charset=utf-8"})[0] == 200


@pytest.mark.parametrize("number", ["9" * 5000, "-" + "9" * 5000, "1" * 31, "1e400", "-1e999"])
def test_absurd_numbers_are_a_400_not_a_500(server, number, caplog):
    body = f'{{"token": "1-0-abc", "side": {number}}}'.encode()
    status, doc = _call(server, "POST", "/api/study/choice", body)
    assert status == 400 and "\n" not in doc["error"] and len(doc["error"]) < 200, doc
    assert not [r for r in caplog.records if r.exc_info]   # no traceback in the log


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=40))
def test_split_host_never_raises(text):
    out = split_host(text)
    assert out is None or (isinstance(out[0], str) and (out[1] is None or 0 < out[1] <= 65535))


def _trickle(port: int) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    s.sendall(b"GET /api/ping HTTP/1.1\r\nHost: 127.0.0.1\r\n")
    return s


def test_slow_clients_are_dropped_and_connections_capped(tmp_path):
    s = KioskServer("127.0.0.1", 0, static_dir=tmp_path, header_timeout_s=1.0, max_connections=4)
    s.route("GET", "/api/ping", lambda req: Response.json({"ok": True}))
    s.start()
    slow = []
    try:
        slow = [_trickle(s.port) for _ in range(4)]
        time.sleep(0.2)
        # the cap is reached: one more connection is answered 503 at once, without a thread
        extra = socket.create_connection(("127.0.0.1", s.port), timeout=5)
        head = extra.recv(4096)
        extra.close()
        assert head.startswith(b"HTTP/1.1 503") and b"too many connections" in head, head
        # the slow ones keep sending a byte now and then, yet are cut off once their header time is up
        closed_at = {}
        t0 = time.monotonic()
        while len(closed_at) < len(slow) and time.monotonic() - t0 < 8:
            for i, sock in enumerate(slow):
                if i in closed_at:
                    continue
                try:
                    sock.sendall(b"X")
                    sock.settimeout(0.05)
                    if sock.recv(1) == b"":
                        closed_at[i] = time.monotonic() - t0
                except TimeoutError:
                    pass
                except OSError:
                    closed_at[i] = time.monotonic() - t0
            time.sleep(0.1)
        assert len(closed_at) == 4, f"slow connections still open after 8 s: {sorted(set(range(4)) - set(closed_at))}"
        # and the server serves again
        assert _call(s, "GET", "/api/ping")[0] == 200
    finally:
        for sock in slow:
            sock.close()
        s.stop()
