"""kiosk.ops.control: JSON lines over a real unix socket, hostile input, permissions, stale and busy sockets."""
from __future__ import annotations

import grp
import json
import os
import pwd
import socket
import stat
import shutil
import tempfile
import threading
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kiosk.ops.control import ControlError, ControlServer, NoDaemonError, send_control
from kiosk.contract.errors import KioskError


class Refused(KioskError):
    pass


def handler(req: dict) -> dict:
    op = req["op"]
    if op == "echo":
        return {"echo": req.get("payload")}
    if op == "refuse":
        raise Refused("bundle denim 2 failed its probe: keeping 1")
    if op == "crash":
        raise ZeroDivisionError("division by zero")
    if op == "not-a-dict":
        return ["x"]  # type: ignore[return-value]
    if op == "explicit":
        return {"ok": False, "error": "no such garment"}
    return {"ok": False, "error": f"unknown op {op}"}


@pytest.fixture
def server(tmp_path):
    srv = ControlServer(tmp_path / "control.sock", handler)
    srv.start()
    yield srv
    srv.stop()


def raw_exchange(path, data: bytes) -> list[dict]:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(5)
    s.connect(str(path))
    s.sendall(data)
    s.shutdown(socket.SHUT_WR)
    buf = b""
    while chunk := s.recv(65536):
        buf += chunk
    s.close()
    return [json.loads(line) for line in buf.decode().splitlines()]


def test_round_trip_and_error_replies(server):
    assert send_control(server.path, {"op": "echo", "payload": {"a": [1, "é"]}}) == \
        {"ok": True, "echo": {"a": [1, "é"]}}
    assert send_control(server.path, {"op": "refuse"}) == \
        {"ok": False, "error": "bundle denim 2 failed its probe: keeping 1"}
    r = send_control(server.path, {"op": "crash"})
    assert not r["ok"] and "internal error in crash: ZeroDivisionError" in r["error"]
    assert "not an object" in send_control(server.path, {"op": "not-a-dict"})["error"]
    assert send_control(server.path, {"op": "explicit"}) == {"ok": False, "error": "no such garment"}


def test_several_requests_on_one_connection_and_malformed_lines(server):
    replies = raw_exchange(server.path, b'{"op":"echo","payload":1}\n\nnot json\n[1,2]\n{"op": 3}\n{"x":1}\n'
                                        b'\xff\xfe\n{"op":"echo","payload":2}\n')
    assert replies[0] == {"ok": True, "echo": 1}
    assert [r["ok"] for r in replies] == [True, False, False, False, False, False, True]
    assert "not a JSON line" in replies[1]["error"]
    assert "JSON object" in replies[2]["error"]
    assert 'string "op"' in replies[3]["error"] and 'string "op"' in replies[4]["error"]
    assert replies[6] == {"ok": True, "echo": 2}


def test_an_endless_line_is_refused(server):
    replies = raw_exchange(server.path, b"{" + b" " * (70 << 10))
    assert replies == [{"ok": False, "error": "request longer than 65536 bytes"}]


json_values = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(),
                           lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(), kids, max_size=4),
                           max_leaves=12)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(payload=json_values)
def test_any_json_payload_round_trips(server, payload):
    assert send_control(server.path, {"op": "echo", "payload": payload}) == {"ok": True, "echo": payload}


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(junk=st.binary(max_size=300))
def test_arbitrary_bytes_never_break_the_server(server, junk):
    replies = raw_exchange(server.path, junk + b"\n")
    for r in replies:
        assert set(r) >= {"ok"} and (r["ok"] or r["error"])
    assert send_control(server.path, {"op": "echo", "payload": 7})["echo"] == 7


def test_concurrent_clients(server):
    results = []

    def client(i):
        results.append(send_control(server.path, {"op": "echo", "payload": i})["echo"])

    threads = [threading.Thread(target=client, args=(i,)) for i in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(results) == list(range(16))


def test_no_daemon_and_bad_requests(tmp_path):
    with pytest.raises(NoDaemonError, match="no kiosk daemon is listening"):
        send_control(tmp_path / "absent.sock", {"op": "status"})
    with pytest.raises(ControlError, match='string "op"'):
        send_control(tmp_path / "absent.sock", {"no": "op"})


def test_stale_socket_is_replaced_but_a_live_one_or_a_file_is_not(tmp_path):
    path = tmp_path / "control.sock"
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(path))
    stale.close()  # the file stays, nobody listens: a daemon that died
    with ControlServer(path, handler) as srv:
        assert send_control(path, {"op": "echo", "payload": 1})["echo"] == 1
        with pytest.raises(ControlError, match="another daemon already listens"):
            ControlServer(path, handler).start()
        assert send_control(path, {"op": "echo", "payload": 2})["echo"] == 2  # the first one is untouched
    assert not path.exists()  # stop() removes its socket
    with pytest.raises(NoDaemonError):
        send_control(path, {"op": "status"})
    other = tmp_path / "notes.txt"
    other.write_text("keep me")
    with pytest.raises(ControlError, match="not a socket"):
        ControlServer(other, handler).start()
    assert other.read_text() == "keep me"
    with pytest.raises(ControlError, match="does not exist"):
        ControlServer(tmp_path / "nope" / "c.sock", handler).start()
    with pytest.raises(ControlError, match="group 'no-such-group-xyz' does not exist"):
        ControlServer(path, handler, group="no-such-group-xyz").start()


def test_a_handler_that_outlives_the_timeout_gives_a_clear_error(tmp_path):
    gate = threading.Event()

    def slow(req):
        gate.wait(5)
        return {}

    with ControlServer(tmp_path / "c.sock", slow) as srv:
        with pytest.raises(ControlError, match="did not answer reload within 0.2 s"):
            send_control(srv.path, {"op": "reload"}, timeout_s=0.2)
        gate.set()


needs_root = pytest.mark.skipif(os.geteuid() != 0, reason="switching to another user needs root")


def _as_user(uid: int, gid: int, groups: list[int], fn) -> dict:
    """Run fn() in a forked child with the given credentials; return what it returned (or the error text)."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child
        os.close(r)
        try:
            os.setgroups(groups)
            os.setgid(gid)
            os.setuid(uid)
            out = {"reply": fn()}
        except Exception as exc:  # noqa: BLE001
            out = {"error": f"{type(exc).__name__}: {exc}"}
        os.write(w, json.dumps(out).encode())
        os._exit(0)
    os.close(w)
    data = b""
    while chunk := os.read(r, 65536):
        data += chunk
    os.close(r)
    os.waitpid(pid, 0)
    return json.loads(data)


@pytest.fixture
def open_dir():
    """A folder other users may enter (pytest's own are 0700)."""
    d = Path(tempfile.mkdtemp(prefix="vtkiosk-ctl-"))
    d.chmod(0o755)
    yield d
    shutil.rmtree(d, ignore_errors=True)


@needs_root
def test_mode_group_and_peer_credentials_restrict_the_socket(open_dir):
    nobody = pwd.getpwnam("nobody")
    group = grp.getgrgid(0).gr_name  # a group 'nobody' is not in
    path = open_dir / "control.sock"
    # a generous timeout: the forked child copies this whole test process, slow on a loaded machine
    call = lambda: send_control(path, {"op": "echo", "payload": "hi"}, timeout_s=120)  # noqa: E731
    with ControlServer(path, handler, group=group, mode=0o660):
        st_ = path.lstat()
        assert stat.S_ISSOCK(st_.st_mode) and stat.S_IMODE(st_.st_mode) == 0o660 and st_.st_gid == 0
        assert not list(open_dir.glob(".*.tmp"))
        # the file mode keeps 'nobody' out
        out = _as_user(nobody.pw_uid, nobody.pw_gid, [], call)
        assert "no permission to use the control socket" in out["error"]
        # in the group (supplementary): allowed
        out = _as_user(nobody.pw_uid, nobody.pw_gid, [0], call)
        assert out.get("reply") == {"ok": True, "echo": "hi"}, out
    # a world-writable socket still checks the peer's credentials (defence in depth)
    with ControlServer(path, handler, group=group, mode=0o666):
        out = _as_user(nobody.pw_uid, nobody.pw_gid, [], call)
        assert "reply" in out, out
        assert out["reply"]["ok"] is False and "permission denied" in out["reply"]["error"]
        out = _as_user(nobody.pw_uid, nobody.pw_gid, [0], call)
        assert out.get("reply") == {"ok": True, "echo": "hi"}, out


def test_a_refusal_sent_before_the_request_is_read_still_reaches_the_client(tmp_path, monkeypatch):
    """The daemon refuses a peer by its credentials before reading its request, then closes. A client whose send
    comes after that close gets EPIPE; it must still read the refusal waiting in its buffer, not report a broken
    pipe. The client's send is held back until the server has closed, so the order is forced, not raced."""
    import kiosk.ops.control as control

    path = tmp_path / "c.sock"
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(str(path))
    listener.listen(1)
    closed = threading.Event()

    def refuse():
        conn, _ = listener.accept()
        conn.sendall(b'{"ok":false,"error":"permission denied: uid 65534 is not in group root"}\n')
        conn.close()
        closed.set()

    t = threading.Thread(target=refuse, daemon=True)
    t.start()
    encode = control._encode

    def late_encode(request):
        assert closed.wait(10)  # the server has answered and closed before the client sends anything
        return encode(request)

    monkeypatch.setattr(control, "_encode", late_encode)
    try:
        out = send_control(path, {"op": "echo", "payload": "x" * 200_000}, timeout_s=10)
    finally:
        listener.close()
        t.join(5)
    assert out == {"ok": False, "error": "permission denied: uid 65534 is not in group root"}
